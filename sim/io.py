"""Simulated recordings on disk: EVT3 RAW events, MP4 frames, JSON truth, optional session store.

Layout of a recording directory::

    OUT/events.raw    events + sync triggers, EVT3 (capture.raw.write)
    OUT/frames.mp4    grey frames (if any), nominal fps; times in truth.json
    OUT/truth.json    ground truth (see sim.flight / sim.spinning_ball)
    OUT/session/      optional Zarr session store (capture.session) with the same data
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from capture.events import TRIGGER_DTYPE


def jsonable(obj):
    """``obj`` with NumPy arrays/scalars turned into lists/Python numbers (for ``json.dump``)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def write_video(path, frames: np.ndarray, fps: float) -> Path:
    """Write grey frames (T, H, W) uint8 as an MP4 (mp4v) at ``fps``."""
    import cv2

    path = Path(path)
    t, h, w = frames.shape
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h), True)
    if not writer.isOpened():
        raise OSError(f"{path}: OpenCV cannot open an MP4 writer")
    try:
        for f in frames:
            writer.write(np.repeat(f[:, :, None], 3, axis=2))
    finally:
        writer.release()
    return path


def read_video(path) -> np.ndarray:
    """Grey frames (T, H, W) uint8 of a video file."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise OSError(f"{path}: OpenCV cannot open this video")
    out = []
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                break
            out.append(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    finally:
        cap.release()
    return np.stack(out) if out else np.zeros((0, 0, 0), np.uint8)


def save_recording(rec, out_dir, *, raw: bool = True, video: bool = True, session: bool = False) -> dict:
    """Write a :class:`sim.Recording` to ``out_dir`` (created); returns ``{name: path}``."""
    from capture import raw as rawio

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    if raw:
        paths["raw"] = out / "events.raw"
        rawio.write(paths["raw"], rec.events, rec.triggers if len(rec.triggers) else None, format="EVT3",
                    width=rec.width, height=rec.height)
    has_frames = rec.frames is not None and len(rec.frames)
    if video and has_frames:
        paths["video"] = write_video(out / "frames.mp4", rec.frames, rec.truth["frames"]["fps"])
    paths["truth"] = out / "truth.json"
    tmp = paths["truth"].with_suffix(".json.tmp")
    tmp.write_text(json.dumps(jsonable(rec.truth), indent=1))
    tmp.replace(paths["truth"])
    if session:
        from capture.session import create_session

        paths["session"] = out / "session"
        attrs = {"source": "sim", "sim_truth_file": "../truth.json"}
        with create_session(paths["session"], width=rec.width, height=rec.height, attrs=attrs,
                            overwrite=True) as w:
            w.append_events(rec.events)
            if len(rec.triggers):
                w.append_triggers(rec.triggers)
            if has_frames:
                if video:
                    w.set_video("../frames.mp4", rec.frame_times_us)
                else:
                    w.append_frames(rec.frame_times_us, rec.frames)
    return paths


def load_truth(path) -> dict:
    """Truth JSON with vectors/matrices back as NumPy arrays."""
    truth = json.loads(Path(path).read_text())
    for k in ("axis", "center", "velocity_px_s", "R0", "start_px", "velocity0_px_s", "hot_pixels"):
        if truth.get(k) is not None:
            truth[k] = np.asarray(truth[k], float)
    if truth.get("track"):
        truth["track"] = {k: np.asarray(v) for k, v in truth["track"].items()}
    if truth.get("frames"):
        fr = truth["frames"]
        fr["frame_to_event"] = np.asarray(fr["frame_to_event"], float)
        fr["t_us"] = np.asarray(fr["t_us"], np.int64)
        fr["t_frame_clock_s"] = np.asarray(fr["t_frame_clock_s"], float)
    return truth


def load_recording(out_dir):
    """Read back a directory written by :func:`save_recording` as a :class:`sim.Recording`."""
    from capture import raw as rawio

    from .flight import Recording

    out = Path(out_dir)
    if not (out / "truth.json").is_file():
        raise FileNotFoundError(f"{out}: no truth.json (not a simulated recording)")
    truth = load_truth(out / "truth.json")
    rf = rawio.read(out / "events.raw")
    frames = times = None
    if truth.get("frames") and (out / "frames.mp4").is_file():
        frames = read_video(out / "frames.mp4")
        times = truth["frames"]["t_us"]
    trig = rf.triggers if len(rf.triggers) else np.zeros(0, TRIGGER_DTYPE)
    return Recording(rf.events, trig, rf.width, rf.height, truth, frames, times)
