"""Rerun review of a session: an ``.rrd`` file offline, or a live viewer for the recorder.

One Rerun recording per session (application id :data:`APPLICATION_ID`), on the
timeline :data:`TIMELINE` (``sensor_time``): µs on the event clock, stored as a
Rerun *duration* so that the viewer shows seconds since the sensor's time zero.

Entity layout (shared by :func:`write_rrd` and :class:`LiveReview`)::

    events/on, events/off        Points2D: events of one time slice (ON green, OFF red)
    events/sensor                Boxes2D (static): the sensor outline
    events/ball                  Ellipses2D: ball circle from the track
    events/spin_axis             Arrows2D: spin axis projected on the image, at the ball centre
    frames/image                 EncodedImage (JPEG) or VideoFrameReference into video/asset
    frames/ball                  Ellipses2D: ball circle mapped into the frame (needs calibration)
    video/asset                  AssetVideo (static): the session's MP4, when it has one
    ball3d/sphere, ball3d/axis   Ellipsoids3D (static) and Arrows3D: unit ball and spin axis
    plots/rps                    Scalars: spin rate, rev/s
    plots/axis/azimuth_deg       Scalars: axis azimuth, see :func:`axis_angles_deg`
    plots/axis/elevation_deg     Scalars: axis elevation
    plots/confidence             Scalars: spin confidence 0..1
    plots/event_rate/events_ev_s Scalars: event rate per slice (before decimation), ev/s
    plots/status/<name>          Scalars: live status numbers (drops, ...)
    log                          TextLog: notes (decimation, skipped batches, ...)

2D entities use Rerun's image coordinates, where pixel ``(0, 0)`` covers
``[0, 1) x [0, 1)``: a pixel coordinate ``u`` (pixel centre at integer values,
see conventions) is logged as ``u + PIXEL_OFFSET``.

Events are logged per time slice of ``slice_us`` with ``send_columns`` (one call
per batch of slices); a slice ``[t, t + slice_us)`` is stamped at ``t``. A slice
with more than ``max_events_per_slice`` events is decimated by a stride
``k = ceil(n / max_events_per_slice)`` (every k-th event of the slice is kept).
"""

from __future__ import annotations

import argparse
import logging
import queue
import sys
import threading
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import rerun as rr
import rerun.blueprint as rrb

from capture.events import EVENT_DTYPE, SPIN_COLUMNS, Track, concatenate
from capture.session import Session, SessionError, open_session

log = logging.getLogger(__name__)

APPLICATION_ID = "courtside-spin"
TIMELINE = "sensor_time"
PIXEL_OFFSET = 0.5
"""Added to pixel coordinates when logging 2D entities (Rerun puts pixel centres at +0.5)."""

EVENTS_ON = "events/on"
EVENTS_OFF = "events/off"
EVENTS_SENSOR = "events/sensor"
EVENTS_BALL = "events/ball"
EVENTS_SPIN_AXIS = "events/spin_axis"
FRAMES_IMAGE = "frames/image"
FRAMES_BALL = "frames/ball"
VIDEO_ASSET = "video/asset"
BALL3D = "ball3d"
BALL3D_SPHERE = "ball3d/sphere"
BALL3D_AXIS = "ball3d/axis"
PLOT_RPS = "plots/rps"
PLOT_AZIMUTH = "plots/axis/azimuth_deg"
PLOT_ELEVATION = "plots/axis/elevation_deg"
PLOT_CONFIDENCE = "plots/confidence"
PLOT_EVENT_RATE = "plots/event_rate/events_ev_s"
PLOT_STATUS = "plots/status"
TEXT_LOG = "log"

ON_COLOR = (60, 220, 90)
OFF_COLOR = (235, 70, 60)
BALL_COLOR = (255, 210, 0)
AXIS_COLOR = (80, 160, 255)

DEFAULT_SLICE_US = 2000
DEFAULT_MAX_EVENTS_PER_SLICE = 2000


class ReviewError(Exception):
    """The review cannot be written (bad argument, unusable output path, ...)."""


# -- pure helpers -------------------------------------------------------------------------------

def _time_column(t_us) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=np.asarray(t_us, dtype=np.int64).astype("timedelta64[us]"))


def axis_angles_deg(axis) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (degrees) of unit spin axes in the camera frame (X right, Y down, Z forward).

    ``azimuth = atan2(x, z)``: 0 along +Z (away from the camera), +90 along +X (right).
    ``elevation = asin(-y)``: +90 pointing up (-Y), -90 pointing down.

    Parameters
    ----------
    axis : array_like, shape (N, 3)

    Returns
    -------
    azimuth_deg, elevation_deg : ndarray of float64, shape (N,)
    """
    a = np.asarray(axis, dtype=np.float64).reshape(-1, 3)
    norm = np.linalg.norm(a, axis=1)
    a = a / np.where(norm > 0, norm, 1.0)[:, None]
    return np.degrees(np.arctan2(a[:, 0], a[:, 2])), np.degrees(np.arcsin(np.clip(-a[:, 1], -1.0, 1.0)))


def circle_at(track: Track, t_us) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ball circle at times ``t_us`` (µs) by linear interpolation inside each flight's span.

    Returns
    -------
    cx, cy, r : ndarray of float64, shape (N,)
        Circle in pixels (NaN where invalid).
    valid : ndarray of bool, shape (N,)
        True where ``t_us`` lies within a flight's first and last track update.
    """
    t = np.asarray(t_us, dtype=np.float64).reshape(-1)
    out = np.full((3, len(t)), np.nan)
    valid = np.zeros(len(t), dtype=bool)
    for flight in track.flight_ids() if len(track) else ():
        rows = track.select(track.flight == flight)
        ft = rows.t_us.astype(np.float64)
        m = (t >= ft[0]) & (t <= ft[-1]) & ~valid
        for k, col in enumerate((rows.cx, rows.cy, rows.r)):
            out[k, m] = np.interp(t[m], ft, col)
        valid |= m
    return out[0], out[1], out[2], valid


def circle_mapping(attrs: Mapping) -> Callable[[np.ndarray], np.ndarray] | None:
    """Event-sensor circles -> frame circles, ``(N, 3) -> (N, 3)`` px, from the session's calibration.

    Uses ``attrs["calibration"]`` (a :class:`calib.stereo.CameraPair` dict: stereo model
    or homography). Returns None when the session has no calibration.
    """
    from calib.stereo import CameraPair

    calib = attrs.get("calibration")
    if not isinstance(calib, Mapping):
        return None
    pair = CameraPair.from_dict(calib)
    if pair.homography is None and pair.extrinsics is None:
        return None
    return pair.event_to_frame


def _map_circles(event_to_frame, cx, cy, r) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map circles (px) through a circle mapping ``(N, 3) -> (N, 3)``."""
    out = np.asarray(event_to_frame(np.c_[cx, cy, r]), dtype=np.float64).reshape(-1, 3)
    return out[:, 0], out[:, 1], out[:, 2]


def spin_columns(spin) -> dict[str, np.ndarray]:
    """Spin columns (:data:`capture.events.SPIN_COLUMNS`) from a mapping of columns, one estimate or a list.

    An estimate is any object with the attributes ``t_start_us``, ``t_end_us``, ``axis``,
    ``omega_rad_s``, ``rps`` and ``confidence`` (``velocity_px_s`` optional).
    """
    if isinstance(spin, Mapping):
        cols = {k: np.asarray(spin[k]) for k in SPIN_COLUMNS if k in spin}
    else:
        items = [spin] if hasattr(spin, "axis") else list(spin)
        if not items:
            return {k: np.zeros((0, *shape), dtype) for k, (dtype, shape) in SPIN_COLUMNS.items()}
        cols = {k: np.asarray([getattr(s, k) for s in items]) for k in SPIN_COLUMNS
                if all(hasattr(s, k) for s in items)}
    missing = [k for k in ("t_start_us", "t_end_us", "axis", "rps") if k not in cols]
    if missing:
        raise ReviewError(f"spin estimates lack the columns {missing}")
    n = len(cols["t_start_us"])
    cols.setdefault("confidence", np.full(n, np.nan, np.float32))
    cols["axis"] = np.asarray(cols["axis"], dtype=np.float64).reshape(n, 3)
    return cols


def _as_track(track) -> Track:
    if isinstance(track, Track):
        return track
    if isinstance(track, Mapping):
        return Track.from_columns(track)
    return Track.from_columns(track)


def session_recording_id(session: Session) -> str:
    """Stable Rerun recording id of a session (from its resolved path and creation time)."""
    key = f"{session.path.resolve()}|{session.attrs.get('created_utc', '')}"
    return str(uuid.uuid5(uuid.NAMESPACE_URL, key))


def blueprint(*, frames: bool = True, width: int | None = None, height: int | None = None,
              status: bool = False) -> rrb.Blueprint:
    """The review layout: events, GoPro frames, 3D spin axis on top; time series below.

    Parameters
    ----------
    frames : bool
        Include the GoPro frames view.
    width, height : int, optional
        Sensor size in pixels, to frame the events view.
    status : bool
        Include live status numbers (drops, ...) with the event rate.
    """
    bounds = (rrb.VisualBounds2D(x_range=[0, width], y_range=[0, height])
              if width and height else None)
    top = [rrb.Spatial2DView(origin="events", name="Events", visual_bounds=bounds)]
    if frames:
        top.append(rrb.Spatial2DView(origin="frames", name="GoPro"))
    top.append(rrb.Spatial3DView(origin=BALL3D, name="Spin axis"))
    rate_contents = ["+ /plots/event_rate/**"] + (["+ /plots/status/**"] if status else [])
    bottom = [
        rrb.TimeSeriesView(origin=PLOT_RPS, name="Spin rate (rps)"),
        rrb.TimeSeriesView(origin="plots/axis", name="Axis angles (deg)"),
        rrb.TimeSeriesView(origin=PLOT_CONFIDENCE, name="Confidence"),
        rrb.TimeSeriesView(origin="plots", contents=rate_contents,
                           name="Event rate (ev/s)" + (" and status" if status else "")),
        rrb.TextLogView(origin=TEXT_LOG, name="Log"),
    ]
    return rrb.Blueprint(rrb.Vertical(rrb.Horizontal(*top), rrb.Horizontal(*bottom), row_shares=[3, 2]),
                         rrb.TimePanel(timeline=TIMELINE), collapse_panels=False)


# -- the logger shared by the offline writer and the live viewer --------------------------------

@dataclass
class ReviewStats:
    """What was logged. Counts of events are before/after decimation."""

    n_events: int = 0
    n_events_logged: int = 0
    n_slices: int = 0
    n_slices_decimated: int = 0
    n_track_rows: int = 0
    n_spin_rows: int = 0
    n_frames: int = 0
    notes: list[str] = field(default_factory=list)


class _Logger:
    """Logs session content into one RecordingStream with the module's entity layout."""

    def __init__(self, rec: rr.RecordingStream, *, slice_us: int, max_events_per_slice: int,
                 width: int | None = None, height: int | None = None):
        if slice_us <= 0:
            raise ReviewError(f"slice_us must be > 0, got {slice_us}")
        if max_events_per_slice <= 0:
            raise ReviewError(f"max_events_per_slice must be > 0, got {max_events_per_slice}")
        self.rec = rec
        self.slice_us = int(slice_us)
        self.cap = int(max_events_per_slice)
        self.stats = ReviewStats()
        self._carry = np.zeros(0, EVENT_DTYPE)
        self._last_sid: int | None = None
        self._t_now = 0
        self._decimation_noted = False
        self._log_static(width, height)

    def _log_static(self, width, height) -> None:
        rec = self.rec
        rec.log(EVENTS_ON, rr.Points2D.from_fields(colors=[ON_COLOR], radii=[0.5]), static=True)
        rec.log(EVENTS_OFF, rr.Points2D.from_fields(colors=[OFF_COLOR], radii=[0.5]), static=True)
        if width and height:
            rec.log(EVENTS_SENSOR, rr.Boxes2D(mins=[0, 0], sizes=[width, height], colors=[(120, 120, 120)]),
                    static=True)
        for path in (EVENTS_BALL, FRAMES_BALL):
            rec.log(path, rr.Ellipses2D.from_fields(colors=[BALL_COLOR], line_radii=[1.0]), static=True)
        rec.log(EVENTS_SPIN_AXIS, rr.Arrows2D.from_fields(colors=[AXIS_COLOR]), static=True)
        rec.log(BALL3D, rr.ViewCoordinates.RDF, static=True)
        rec.log(BALL3D_SPHERE, rr.Ellipsoids3D(half_sizes=[[1.0, 1.0, 1.0]], colors=[BALL_COLOR],
                                               fill_mode="majorwireframe"), static=True)
        rec.log(BALL3D_AXIS, rr.Arrows3D.from_fields(colors=[AXIS_COLOR], radii=[0.03]), static=True)
        for path, name in ((PLOT_RPS, "rps"), (PLOT_AZIMUTH, "azimuth (deg)"),
                           (PLOT_ELEVATION, "elevation (deg)"), (PLOT_CONFIDENCE, "confidence"),
                           (PLOT_EVENT_RATE, "events (ev/s)")):
            rec.log(path, rr.SeriesLines(names=name), static=True)

    # events ----------------------------------------------------------------------------------
    def events(self, events: np.ndarray) -> None:
        """Queue events; every slice that the batch completes is logged."""
        if len(events) == 0:
            return
        self.stats.n_events += len(events)
        self._t_now = max(self._t_now, int(events["t"][-1]))
        ev = concatenate([self._carry, events]) if len(self._carry) else events
        last_start = int(ev["t"][-1]) // self.slice_us * self.slice_us
        cut = int(np.searchsorted(ev["t"], last_start, side="left"))
        self._carry = ev[cut:].copy()
        self._emit(ev[:cut])

    def flush_events(self) -> None:
        """Log the incomplete last slice."""
        carry, self._carry = self._carry, np.zeros(0, EVENT_DTYPE)
        self._emit(carry)
        if self.stats.n_slices_decimated and not self._decimation_noted:
            self._decimation_noted = True
            self.text(f"events decimated: {self.stats.n_slices_decimated} of {self.stats.n_slices} slices "
                      f"had more than {self.cap} events; {self.stats.n_events_logged} of "
                      f"{self.stats.n_events} events logged", level="WARN")

    def _emit(self, ev: np.ndarray) -> None:
        """Log whole slices: one ``send_columns`` per polarity plus one for the event rate.

        A row is logged per non-empty slice and per first empty slice after one
        (an empty row, which clears the points; rate 0).
        """
        if len(ev) == 0:
            return
        S = self.slice_us
        t = ev["t"]
        s0, s1 = int(t[0]) // S, int(t[-1]) // S
        edges = np.searchsorted(t, np.arange(s0, s1 + 2, dtype=np.int64) * S, side="left")
        counts = np.diff(edges)
        stride = np.maximum(1, -(-counts // self.cap))
        n_kept = -(-counts // stride)
        if np.all(stride == 1):
            kept = ev
        else:
            first = np.cumsum(n_kept) - n_kept
            idx = (np.repeat(edges[:-1], n_kept)
                   + (np.arange(n_kept.sum()) - np.repeat(first, n_kept)) * np.repeat(stride, n_kept))
            kept = ev[idx]
        kept_slice = np.repeat(np.arange(len(counts)), n_kept)
        nonempty = counts > 0
        rows = nonempty.copy()
        rows[1:] |= nonempty[:-1]
        gap_before = self._last_sid is not None and s0 > self._last_sid + 1
        row_t = np.r_[[(self._last_sid + 1) * S] if gap_before else [], np.arange(s0, s1 + 1)[rows] * S]
        pad = np.zeros(int(gap_before), np.int64)
        index = [_time_column(row_t)]
        xy = np.empty((len(kept), 2), dtype=np.float32)
        xy[:, 0] = kept["x"]
        xy[:, 1] = kept["y"]
        xy += PIXEL_OFFSET
        on = kept["p"] != 0
        for path, mask in ((EVENTS_ON, on), (EVENTS_OFF, ~on)):
            lengths = np.r_[pad, np.bincount(kept_slice[mask], minlength=len(counts))[rows]]
            self.rec.send_columns(path, indexes=index,
                                  columns=rr.Points2D.columns(positions=xy[mask]).partition(lengths))
        rate = np.r_[pad, counts[rows]] / (S * 1e-6)
        self.rec.send_columns(PLOT_EVENT_RATE, indexes=index, columns=rr.Scalars.columns(scalars=rate))
        self._last_sid = s1
        self.stats.n_slices += int(np.count_nonzero(nonempty))
        self.stats.n_slices_decimated += int(np.count_nonzero(stride > 1))
        self.stats.n_events_logged += len(kept)

    # track and spin --------------------------------------------------------------------------
    def track(self, track: Track, *, clear_after_flights: bool = True) -> None:
        """Ball circle per track row.

        With ``clear_after_flights`` (offline, where flights are complete) the circle is
        cleared ``max(slice_us, 2 * median track step)`` after each flight's last row,
        unless the track has a row before then.
        """
        if len(track) == 0:
            return
        c = np.c_[track.cx, track.cy] + PIXEL_OFFSET
        self.rec.send_columns(EVENTS_BALL, indexes=[_time_column(track.t_us)],
                              columns=rr.Ellipses2D.columns(centers=c, half_sizes=np.c_[track.r, track.r]))
        self.stats.n_track_rows += len(track)
        if not clear_after_flights:
            return
        step = np.diff(track.t_us)
        delay = max(self.slice_us, 2 * int(np.median(step)) if len(step) else 0)
        ends = np.array([track.t_us[track.flight == f][-1] for f in track.flight_ids()], np.int64)
        after = np.searchsorted(track.t_us, ends, side="right")
        next_t = np.r_[track.t_us, np.iinfo(np.int64).max][after]
        clear_t = (ends + delay)[next_t > ends + delay]
        if len(clear_t):
            self.rec.send_columns(EVENTS_BALL, indexes=[_time_column(clear_t)],
                                  columns=rr.Ellipses2D.columns(half_sizes=np.zeros((0, 2)))
                                  .partition(np.zeros(len(clear_t), np.int64)))

    def spin(self, cols: Mapping[str, np.ndarray], track: Track | None = None) -> None:
        """Spin estimates at their window centre: time series, 3D axis arrow, 2D projected axis."""
        n = len(cols["t_start_us"])
        if n == 0:
            return
        t = (np.asarray(cols["t_start_us"], np.int64) + np.asarray(cols["t_end_us"], np.int64)) // 2
        axis = cols["axis"]
        rps = np.asarray(cols["rps"], np.float64)
        az, el = axis_angles_deg(axis)
        index = [_time_column(t)]
        for path, values in ((PLOT_RPS, rps), (PLOT_AZIMUTH, az), (PLOT_ELEVATION, el),
                             (PLOT_CONFIDENCE, np.asarray(cols["confidence"], np.float64))):
            self.rec.send_columns(path, indexes=index, columns=rr.Scalars.columns(scalars=values))
        labels = [f"{v:.1f} rps" for v in rps]
        self.rec.send_columns(BALL3D_AXIS, indexes=index,
                              columns=rr.Arrows3D.columns(origins=-1.6 * axis, vectors=3.2 * axis, labels=labels))
        if track is not None and len(track):
            cx, cy, r, valid = circle_at(track, t)
            arrows = rr.Arrows2D.columns(origins=(np.c_[cx, cy] + PIXEL_OFFSET)[valid],
                                         vectors=(axis[:, :2] * r[:, None])[valid])
            self.rec.send_columns(EVENTS_SPIN_AXIS, indexes=index, columns=arrows.partition(valid.astype(np.int64)))
        self.stats.n_spin_rows += n

    # frames ----------------------------------------------------------------------------------
    def frame_image(self, t_us: int, image: np.ndarray, jpeg_quality: int) -> None:
        """One GoPro frame (H, W) or (H, W, 3) RGB uint8, JPEG-compressed."""
        self.rec.set_time(TIMELINE, duration=np.timedelta64(int(t_us), "us"))
        self.rec.log(FRAMES_IMAGE, rr.Image(np.ascontiguousarray(image)).compress(jpeg_quality=jpeg_quality))
        self.stats.n_frames += 1

    def frame_circles(self, t_us, track: Track, event_to_frame) -> None:
        """Track circle at frame times, mapped into the frame; empty where the track has no ball."""
        t_us = np.asarray(t_us, np.int64)
        cx, cy, r, valid = circle_at(track, t_us)
        if not valid.any():
            return
        fx, fy, fr = _map_circles(event_to_frame, cx[valid], cy[valid], r[valid])
        cols = rr.Ellipses2D.columns(centers=np.c_[fx, fy] + PIXEL_OFFSET, half_sizes=np.c_[fr, fr])
        self.rec.send_columns(FRAMES_BALL, indexes=[_time_column(t_us)], columns=cols.partition(valid.astype(np.int64)))

    # status and notes --------------------------------------------------------------------------
    def status(self, t_us: int, numbers: Mapping[str, float]) -> None:
        for name, value in numbers.items():
            if value is not None:
                self.rec.send_columns(f"{PLOT_STATUS}/{name}", indexes=[_time_column([t_us])],
                                      columns=rr.Scalars.columns(scalars=[float(value)]))

    def text(self, message: str, level: str = "INFO", t_us: int | None = None) -> None:
        """A note in the log, at ``t_us`` (default: the latest event time seen)."""
        self.stats.notes.append(message)
        t = self._t_now if t_us is None else int(t_us)
        self.rec.send_columns(TEXT_LOG, indexes=[_time_column([t])],
                              columns=rr.TextLog.columns(text=[message], level=[level]))


# -- offline: a whole session into an .rrd --------------------------------------------------------

def _recording(recording_id: str | None) -> rr.RecordingStream:
    """A recording that only uses :data:`TIMELINE` (no log_time / log_tick)."""
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    rec.set_log_time_enabled(False)
    rec.set_log_tick_enabled(False)
    return rec


def _open(session_or_path) -> Session:
    if isinstance(session_or_path, Session):
        return session_or_path
    if session_or_path is None:
        raise SessionError("no session given")
    return open_session(session_or_path)


def _frames_info(session: Session) -> dict:
    """Like ``Session.frames()`` but with ``image`` as the lazy on-disk array (frames read one by one)."""
    if "frames" not in session.root:
        return {"t_us": np.zeros(0, np.int64), "image": None, "video": None}
    group = session.root["frames"]
    n = int(group.attrs.get("n_committed", 0))
    video = group.attrs.get("video")
    return {"t_us": group["t_us"][:n] if "t_us" in group else np.zeros(0, np.int64),
            "image": group["image"] if "image" in group and n else None,
            "video": str(session.path / video) if video else None}


def _check_rrd_path(rrd_path) -> Path:
    path = Path(rrd_path)
    if path.is_dir():
        raise ReviewError(f"{path}: is a directory, expected an .rrd file path")
    if not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    return path


def _log_video(lg: _Logger, session: Session, video: str, t_us: np.ndarray, *, video_max_bytes: int,
               jpeg_quality: int, frame_stride: int) -> None:
    """Reference the session's MP4 (embedded) per frame; fall back to decoded JPEG frames."""
    path = Path(video)
    if not path.is_file():
        lg.text(f"frames: video {path} not found; frames not shown", level="WARN")
        return
    reason = None
    if path.stat().st_size <= video_max_bytes:
        try:
            asset = rr.AssetVideo(path=path)
            video_ts_ns = asset.read_frame_timestamps_nanos()
        except Exception as exc:  # rerun raises several types for unreadable videos
            reason = f"rerun cannot read it ({exc})"
        else:
            n = min(len(video_ts_ns), len(t_us))
            lg.rec.log(VIDEO_ASSET, asset, static=True)
            lg.rec.send_columns(FRAMES_IMAGE, indexes=[_time_column(t_us[:n])],
                                columns=rr.VideoFrameReference.columns_nanos(video_ts_ns[:n]))
            lg.rec.log(FRAMES_IMAGE, rr.VideoFrameReference.from_fields(video_reference=VIDEO_ASSET), static=True)
            lg.stats.n_frames += n
            return
    else:
        reason = f"it is larger than {video_max_bytes} bytes"
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        lg.text(f"frames: cannot open video {path}; frames not shown", level="WARN")
        return
    lg.text(f"frames: {path.name} not embedded ({reason}); logging every {frame_stride}. frame as JPEG")
    try:
        for i in range(len(t_us)):
            ok, bgr = cap.read()
            if not ok:
                break
            if i % frame_stride == 0:
                lg.frame_image(int(t_us[i]), cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), jpeg_quality)
    finally:
        cap.release()


def write_rrd(session_or_path, rrd_path, *, slice_us: int = DEFAULT_SLICE_US,
              max_events_per_slice: int = DEFAULT_MAX_EVENTS_PER_SLICE, batch_events: int = 1 << 20,
              event_to_frame: Callable[[np.ndarray], np.ndarray] | None = None, jpeg_quality: int = 80,
              video_max_bytes: int = 2 << 30, frame_stride: int = 1, progress: bool = True) -> ReviewStats:
    """Write a session's review as a Rerun ``.rrd`` file (streamed, bounded memory).

    Parameters
    ----------
    session_or_path : Session or str or Path
        The session (or its directory).
    rrd_path : str or Path
        Output file (overwritten; parent folders are created).
    slice_us : int
        Event slice length, µs.
    max_events_per_slice : int
        Cap on logged events per slice; above it a slice is decimated by a stride.
    batch_events : int
        Events read from the store per step (bounds memory).
    event_to_frame : callable, optional
        Maps event-sensor circles (N, 3) to frame circles (N, 3), px, to draw the ball on
        the frames; default: from the session's ``calibration`` (:func:`circle_mapping`).
    jpeg_quality : int
        JPEG quality of logged frame images.
    video_max_bytes : int
        The session's MP4 is embedded (frames referenced by timestamp) up to this size;
        larger (or unreadable by Rerun) videos are decoded and logged as JPEG frames.
    frame_stride : int
        When frames are logged as images from a video, log every ``frame_stride``-th.
    progress : bool
        Show a tqdm progress bar over the events.

    Returns
    -------
    ReviewStats
        Counts of what was logged (events before/after decimation, slices, rows, frames).

    Raises
    ------
    capture.session.SessionError
        The path is not a readable session.
    ReviewError
        Bad arguments or output path.
    """
    from tqdm import tqdm

    session = _open(session_or_path)
    rrd_path = _check_rrd_path(rrd_path)
    frames = _frames_info(session)
    has_images = frames["image"] is not None or frames["video"] is not None
    rec = _recording(session_recording_id(session))
    rec.save(rrd_path)
    try:
        rec.send_blueprint(blueprint(frames=has_images, width=session.width, height=session.height))
        rec.send_recording_name(session.path.name)
        lg = _Logger(rec, slice_us=slice_us, max_events_per_slice=max_events_per_slice,
                     width=session.width, height=session.height)
        with tqdm(total=session.n_events, unit="ev", unit_scale=True, disable=not progress,
                  desc=f"review {session.path.name}") as bar:
            for batch in session.iter_events(batch_events):
                lg.events(batch)
                bar.update(len(batch))
            lg.flush_events()
        track = Track.from_columns(session.track())
        lg.track(track)
        lg.spin(session.spin(), track)
        mapping = event_to_frame or circle_mapping(session.attrs)
        if frames["video"] is not None:
            _log_video(lg, session, frames["video"], frames["t_us"], video_max_bytes=video_max_bytes,
                       jpeg_quality=jpeg_quality, frame_stride=max(1, int(frame_stride)))
        elif frames["image"] is not None:
            for i, t in enumerate(frames["t_us"]):
                lg.frame_image(int(t), frames["image"][i], jpeg_quality)
        if has_images and mapping is not None and len(frames["t_us"]) and len(track):
            lg.frame_circles(frames["t_us"], track, mapping)
        rec.flush()
    finally:
        rec.disconnect()
    for note in lg.stats.notes:
        log.info("%s: %s", rrd_path.name, note)
    return lg.stats


# -- live: the recorder's viewer ----------------------------------------------------------------

LIVE_MODES = ("spawn", "serve", "none", "rrd")


class LiveReview:
    """Live Rerun logging for the recorder; never blocks the caller.

    Calls only put work on a bounded queue (``put_nowait``); a background thread
    slices, decimates and logs it. When the queue is full the item is skipped and
    counted (:attr:`skipped`), and a note is logged. Mode ``"none"`` does nothing.

    Parameters
    ----------
    mode : {"spawn", "serve", "none", "rrd"}
        ``spawn`` a local viewer, ``serve`` over gRPC (see :attr:`url`), write ``rrd_path``, or nothing.
    rrd_path : str or Path, optional
        Output for mode ``"rrd"``.
    width, height : int, optional
        Sensor size in pixels.
    recording_id : str, optional
        Rerun recording id (e.g. :func:`session_recording_id` of the session being recorded).
    name : str, optional
        Recording name shown in the viewer.
    frames : bool
        Show the GoPro frames view.
    slice_us, max_events_per_slice : int
        Event slicing and per-slice cap (see module docstring); keep the cap low live.
    max_queue : int
        Items waiting for the logging thread before new ones are skipped.
    event_to_frame : callable, optional
        Event-sensor circles (N, 3) -> frame circles (N, 3), px, for the circle on frames.
    grpc_port : int, optional
        Port for ``serve`` / ``spawn``.
    """

    def __init__(self, mode: str = "none", *, rrd_path=None, width: int | None = None,
                 height: int | None = None, recording_id: str | None = None, name: str | None = None,
                 frames: bool = True, slice_us: int = DEFAULT_SLICE_US, max_events_per_slice: int = 1000,
                 max_queue: int = 64, event_to_frame=None, jpeg_quality: int = 70,
                 grpc_port: int | None = None):
        if mode not in LIVE_MODES:
            raise ReviewError(f"viewer mode must be one of {LIVE_MODES}, got {mode!r}")
        if mode == "rrd" and rrd_path is None:
            raise ReviewError("viewer mode 'rrd' needs rrd_path")
        self.mode = mode
        self.url: str | None = None
        self.skipped: dict[str, int] = {}
        self.error: BaseException | None = None
        self._event_to_frame = event_to_frame
        self._jpeg_quality = jpeg_quality
        self._closed = mode == "none"
        if self._closed:
            return
        rec = _recording(recording_id)
        bp = blueprint(frames=frames, width=width, height=height, status=True)
        if mode == "rrd":
            rec.save(_check_rrd_path(rrd_path))
        else:
            try:
                if mode == "spawn":
                    rec.spawn(port=grpc_port or 9876, default_blueprint=bp)
                else:
                    self.url = rec.serve_grpc(grpc_port=grpc_port, default_blueprint=bp)
            except Exception as exc:  # rerun raises several types (missing viewer, port in use)
                raise ReviewError(f"cannot start the Rerun viewer (mode {mode!r}): {exc}") from exc
        rec.send_blueprint(bp)
        if name:
            rec.send_recording_name(name)
        self._rec = rec
        self._logger = _Logger(rec, slice_us=slice_us, max_events_per_slice=max_events_per_slice,
                               width=width, height=height)
        self._track = Track.empty()
        self._queue: queue.Queue = queue.Queue(maxsize=max_queue)
        self._thread = threading.Thread(target=self._run, name="live-review", daemon=True)
        self._thread.start()

    @property
    def stats(self) -> ReviewStats | None:
        """What the logging thread has logged so far (None in mode ``"none"``)."""
        return None if self.mode == "none" else self._logger.stats

    # caller side: cheap, never blocking -----------------------------------------------------------
    def _put(self, kind: str, payload) -> None:
        if self._closed:
            return
        try:
            self._queue.put_nowait((kind, payload))
        except queue.Full:
            self.skipped[kind] = self.skipped.get(kind, 0) + 1

    def log_events(self, events: np.ndarray) -> None:
        """An event batch (EVENT_DTYPE, time-ordered; not modified by the caller afterwards)."""
        if len(events):
            self._put("events", events)

    def log_track(self, track) -> None:
        """New track rows (:class:`detect.track.Track` or a mapping of the track columns)."""
        self._put("track", track)

    def log_spin(self, spin) -> None:
        """Spin estimate(s): one estimate, a list, or a mapping of spin columns."""
        self._put("spin", spin)

    def log_frame(self, t_us: int, image: np.ndarray | None = None) -> None:
        """A GoPro frame at ``t_us`` (µs, event clock); ``image`` (H, W[, 3]) RGB uint8."""
        self._put("frame", (int(t_us), image))

    def log_status(self, t_us: int, **numbers: float) -> None:
        """Status numbers at ``t_us``, e.g. ``event_rate_ev_s=..., drops=...`` (plotted under plots/status)."""
        self._put("status", (int(t_us), numbers))

    def log_message(self, text: str, level: str = "INFO") -> None:
        """A note in the viewer's log."""
        self._put("text", (text, level))

    def close(self, timeout_s: float = 10.0) -> None:
        """Log what is queued, flush and close the sink (waits at most ``timeout_s`` for the thread)."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(("stop", None))
        self._thread.join(timeout_s)
        self._rec.flush()
        self._rec.disconnect()

    def __enter__(self) -> LiveReview:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # logging thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        lg = self._logger
        noted = 0
        while True:
            kind, payload = self._queue.get()
            try:
                if kind == "stop":
                    lg.flush_events()
                    if self.skipped:
                        lg.text(f"live review skipped (queue full): {self.skipped}", level="WARN")
                    return
                n_skipped = sum(self.skipped.values())
                if n_skipped > noted:
                    noted = n_skipped
                    lg.text(f"live review behind: skipped so far {self.skipped}", level="WARN")
                self._handle(kind, payload)
            except Exception as exc:  # never let a viewer problem reach the recorder
                if self.error is None:
                    self.error = exc
                    log.warning("live review: %s: %s", type(exc).__name__, exc)

    def _handle(self, kind: str, payload) -> None:
        lg = self._logger
        if kind == "events":
            lg.events(payload)
        elif kind == "track":
            rows = _as_track(payload)
            lg.track(rows, clear_after_flights=False)
            both = Track.concat([self._track, rows])
            self._track = both.select(slice(-4096, None))
        elif kind == "spin":
            lg.spin(spin_columns(payload), self._track)
        elif kind == "frame":
            t_us, image = payload
            if image is not None:
                lg.frame_image(t_us, image, self._jpeg_quality)
            if self._event_to_frame is not None and len(self._track):
                lg.frame_circles([t_us], self._track, self._event_to_frame)
        elif kind == "status":
            lg.status(*payload)
        elif kind == "text":
            lg.text(*payload)


# -- command line -------------------------------------------------------------------------------

def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m capture.review",
                                     description="Write a session's Rerun review (.rrd).")
    parser.add_argument("session", help="session directory")
    parser.add_argument("--rrd", required=True, help="output .rrd file")
    parser.add_argument("--slice-us", type=int, default=DEFAULT_SLICE_US, help="event slice length, µs")
    parser.add_argument("--max-events-per-slice", type=int, default=DEFAULT_MAX_EVENTS_PER_SLICE,
                        help="decimate slices above this many events")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        stats = write_rrd(args.session, args.rrd, slice_us=args.slice_us,
                          max_events_per_slice=args.max_events_per_slice, progress=not args.no_progress)
    except (SessionError, ReviewError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"{args.rrd}: {stats.n_events_logged} of {stats.n_events} events in {stats.n_slices} slices "
          f"({stats.n_slices_decimated} decimated), {stats.n_track_rows} track rows, "
          f"{stats.n_spin_rows} spin estimates, {stats.n_frames} frames")
    return 0


if __name__ == "__main__":
    sys.exit(main())
