"""A simulated recording and its directory on disk: EVT3 RAW events, MP4 frames, JSON truth.

Layout of a recording directory::

    OUT/events.raw    events + sync triggers, EVT3 (capture.raw.write)
    OUT/frames.mp4    grey frames (if any), nominal fps; times in truth.json
    OUT/truth.json    ground truth (see sim.flight / sim.spinning_ball)
    OUT/session/      optional Zarr session store (capture.session) with the same data

:meth:`Recording.save` writes it, :meth:`Recording.load` reads it back.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture.events import TRIGGER_DTYPE, Track

RAW_NAME = "events.raw"
VIDEO_NAME = "frames.mp4"
TRUTH_NAME = "truth.json"
SESSION_NAME = "session"

_TRUTH_VECTORS = ("axis", "center", "velocity_px_s", "R0", "start_px", "velocity0_px_s", "hot_pixels")


def jsonable(obj):
    """``obj`` with NumPy arrays/scalars turned into lists/Python numbers (for ``json.dump``).

    Dicts (keys made ``str``), lists and tuples are converted recursively; anything else is
    returned as is.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def save_truth(path, truth: dict) -> Path:
    """Write a truth dict as indented JSON, atomically (through ``<path>.json.tmp``).

    Parameters
    ----------
    path : str or Path
        Output ``.json`` file.
    truth : dict
        Ground truth; NumPy values are converted by :func:`jsonable`.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(jsonable(truth), indent=1))
    tmp.replace(path)
    return path


def load_truth(path) -> dict:
    """Truth JSON written by :func:`save_truth` with vectors/matrices back as NumPy arrays.

    Vectors (px, px/s, unit axes), ``R0`` (3, 3), the ``track`` columns and the ``frames``
    homography (3, 3), times ``t_us`` (int64, µs) and ``t_frame_clock_s`` (s) become arrays.
    """
    truth = json.loads(Path(path).read_text())
    for k in _TRUTH_VECTORS:
        if truth.get(k) is not None:
            truth[k] = np.asarray(truth[k], float)
    if truth.get("track"):
        truth["track"] = {k: np.asarray(v) for k, v in truth["track"].items()}
    if truth.get("frames"):
        fr = truth["frames"]
        fr["frame_to_event"] = np.asarray(fr["frame_to_event"], float)
        fr["t_us"] = np.asarray(fr["t_us"], np.int64)
        fr["t_frame_clock_s"] = np.asarray(fr["t_frame_clock_s"], float)
        if isinstance(fr.get("exposure_s"), list):  # auto-exposure: one per frame
            fr["exposure_s"] = np.asarray(fr["exposure_s"], float)
    return truth


@dataclass
class Recording:
    """A simulated recording.

    Attributes
    ----------
    events : ndarray of EVENT_DTYPE, sorted by t
    triggers : ndarray of TRIGGER_DTYPE (sync-box edges; may be empty)
    width, height : int
        Event sensor size (px).
    truth : dict
        Ground truth (JSON-able through :func:`jsonable`); see :func:`sim.flight`.
    frames : ndarray of uint8, shape (T, H_f, W_f), or None
        Grey frames of the frame camera.
    frame_times_us : ndarray of int64, shape (T,), or None
        Exposure midpoints on the event clock (µs).
    """

    events: np.ndarray
    triggers: np.ndarray
    width: int
    height: int
    truth: dict
    frames: np.ndarray | None = None
    frame_times_us: np.ndarray | None = None

    def truth_track(self, visible_only: bool = True) -> Track:
        """Ground-truth ball circle as a :class:`capture.events.Track` (score 1, flight = segment, sigma 0)."""
        tr = self.truth["track"]
        keep = np.asarray(tr["visible"], bool) if visible_only else np.ones(len(tr["t_us"]), bool)
        cols = {k: np.asarray(tr[k])[keep] for k in ("t_us", "cx", "cy", "r", "vx", "vy", "flight")}
        return Track(score=np.ones(int(keep.sum()), np.float32), sigma_px=np.zeros(int(keep.sum())), **cols)

    def save(self, out_dir, *, raw: bool = True, video: bool = True, session: bool = False) -> dict:
        """Write the recording to ``out_dir`` (created; see the module docstring for the layout).

        Parameters
        ----------
        out_dir : str or Path
            Recording directory.
        raw : bool
            Write ``events.raw`` (EVT3, events and triggers).
        video : bool
            Write the frames (if any) as ``frames.mp4`` at the nominal fps (``truth["frames"]["fps"]``, Hz).
        session : bool
            Also write a Zarr session store ``session/``; it refers to ``frames.mp4`` when
            ``video``, otherwise it holds the frames itself.

        Returns
        -------
        dict
            ``{name: Path}`` of what was written: ``"raw"``, ``"video"``, ``"truth"``, ``"session"``.
        """
        # imported here: ``import sim`` stays light for simulation-only users
        from capture import raw as rawio
        from capture.gopro import write_video

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        paths = {}
        if raw:
            paths["raw"] = out / RAW_NAME
            rawio.write(paths["raw"], self.events, self.triggers if len(self.triggers) else None, format="EVT3",
                        width=self.width, height=self.height)
        has_frames = self.frames is not None and len(self.frames)
        if video and has_frames:
            paths["video"] = write_video(out / VIDEO_NAME, self.frames, self.truth["frames"]["fps"])
            _add_camera_metadata(paths["video"], self.truth["frames"], len(self.frames))
        paths["truth"] = save_truth(out / TRUTH_NAME, self.truth)
        if session:
            from capture.session import create_session

            paths["session"] = out / SESSION_NAME
            attrs = {"source": "sim", "sim_truth_file": f"../{TRUTH_NAME}"}
            with create_session(paths["session"], width=self.width, height=self.height, attrs=attrs,
                                overwrite=True) as w:
                w.append_events(self.events)
                if len(self.triggers):
                    w.append_triggers(self.triggers)
                if has_frames:
                    if video:
                        w.set_video(f"../{VIDEO_NAME}", self.frame_times_us)
                    else:
                        w.append_frames(self.frame_times_us, self.frames)
        return paths

    @classmethod
    def load(cls, out_dir) -> Recording:
        """Read back a directory written by :meth:`save`.

        Parameters
        ----------
        out_dir : str or Path
            Recording directory with ``truth.json`` and ``events.raw`` (``frames.mp4`` optional).

        Returns
        -------
        Recording
            Frames (grey, decoded from the lossy MP4) and their times (µs, from the truth) when
            the truth lists frames and ``frames.mp4`` exists, else None.

        Raises
        ------
        FileNotFoundError
            When ``out_dir`` has no ``truth.json``.
        """
        from capture import raw as rawio
        from capture.gopro import read_video

        out = Path(out_dir)
        if not (out / TRUTH_NAME).is_file():
            raise FileNotFoundError(f"{out}: no {TRUTH_NAME} (not a simulated recording)")
        truth = load_truth(out / TRUTH_NAME)
        rf = rawio.read(out / RAW_NAME)
        frames = times = None
        if truth.get("frames") and (out / VIDEO_NAME).is_file():
            frames = np.stack([img for _, _, img in read_video(out / VIDEO_NAME).frames(gray=True)])
            times = truth["frames"]["t_us"]
        trig = rf.triggers if len(rf.triggers) else np.zeros(0, TRIGGER_DTYPE)
        return cls(rf.events, trig, rf.width, rf.height, truth, frames, times)


def _add_camera_metadata(mp4_path, frames_truth: dict, n_frames: int) -> None:
    """Give the video GoPro's GPMF track: per-frame exposure (``SHUT``), frame skips (``MSKP``,
    none) and ISO, one payload per second of frames, as a HERO camera writes them."""
    from capture.gopro import gpmf
    from capture.gopro.mp4 import add_gpmf_track

    fps = float(frames_truth["fps"])
    exposure = np.broadcast_to(np.asarray(frames_truth["exposure_s"], np.float64), (n_frames,))
    per = max(int(round(fps)), 1)
    payloads = [gpmf.camera_payload(exposure[i:i + per], iso=np.full(len(exposure[i:i + per]), 100),
                                    frame_skips=np.zeros(len(exposure[i:i + per]), np.uint16))
                for i in range(0, n_frames, per)]
    add_gpmf_track(mp4_path, payloads, [min(per, n_frames - i) / fps for i in range(0, n_frames, per)])
