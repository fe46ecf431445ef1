"""Offline review: a whole session into a Rerun ``.rrd`` file (streamed, bounded memory)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
import rerun as rr
from tqdm import tqdm

from capture.events import Track
from capture.results import session_results
from capture.review.layout import (BALL_AXIS, BALL_IMAGE, BALL_RIM, DEFAULT_MAX_BALL_EVENTS_PER_SLICE,
                                   DEFAULT_MAX_EVENTS_PER_SLICE, DEFAULT_SLICE_US, FRAMES_IMAGE, VIDEO_ASSET,
                                   blueprint, circle_mapping, session_recording_id, time_column)
from capture.review.logger import ReviewLogger, ReviewStats, check_rrd_path, open_recording
from capture.session import Session, SessionError, open_session

log = logging.getLogger(__name__)


def write_rrd(session_or_path, rrd_path, *, slice_us: int = DEFAULT_SLICE_US,
              max_events_per_slice: int = DEFAULT_MAX_EVENTS_PER_SLICE,
              max_ball_events_per_slice: int = DEFAULT_MAX_BALL_EVENTS_PER_SLICE, batch_events: int = 1 << 20,
              event_to_frame: Callable[[np.ndarray], np.ndarray] | None = None, jpeg_quality: int = 80,
              video_max_bytes: int = 2 << 30, frame_stride: int = 1, progress: bool = True,
              ball_view: Callable | None = None) -> ReviewStats:
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
        Cap on logged events per slice away from the ball; above it they are decimated by a stride.
    max_ball_events_per_slice : int
        Cap on logged events per slice on the ball (within 1.25 radii of the track's circle).
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
    ball_view : callable, optional
        ``ball_view(session, track, spin, i, flight=f)`` gives the ball close-up of spin window
        ``i`` (:func:`capture.pipeline.ball_view.ball_view`, which the pipeline passes; the review
        layer does not run spin code itself); without it the review has no close-up view.

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
    session = _open(session_or_path)
    rrd_path = check_rrd_path(rrd_path)
    frames = _frames_info(session)
    has_images = frames["image"] is not None or frames["video"] is not None
    track = Track.from_columns(session.track())
    spin = session.spin()
    _, starts, ends = track.spans()
    first = (int(starts[0]), int(ends[0])) if len(track) else None
    rec = open_recording(session_recording_id(session))
    rec.save(rrd_path)
    try:
        rec.send_blueprint(blueprint(frames=has_images, width=session.width, height=session.height, follow=False,
                                     first_flight_us=first, ball_view=ball_view is not None and len(spin["rps"]) > 0))
        rec.send_recording_name(session.path.name)
        lg = ReviewLogger(rec, slice_us=slice_us, max_events_per_slice=max_events_per_slice,
                          max_ball_events_per_slice=max_ball_events_per_slice,
                          width=session.width, height=session.height, ball_track=track)
        with tqdm(total=session.n_events, unit="ev", unit_scale=True, disable=not progress,
                  desc=f"review {session.path.name}") as bar:
            for batch in session.iter_events(batch_events):
                lg.events(batch)
                bar.update(len(batch))
            lg.flush_events()
        lg.track(track)
        lg.spin(spin, track, clear_after_flights=True)
        _log_results(lg, session, track, spin, ball_view)
        mapping = event_to_frame or circle_mapping(session.attrs)
        if frames["video"] is not None:
            _log_video(lg, frames["video"], frames["t_us"], video_max_bytes=video_max_bytes,
                       jpeg_quality=jpeg_quality, frame_stride=max(1, int(frame_stride)))
        elif frames["image"] is not None:
            for i, t in enumerate(frames["t_us"]):
                lg.frame_image(int(t), frames["image"][i], jpeg_quality)
        if has_images and mapping is None:
            width = int(session.attrs.get("frame_camera", {}).get("width") or session.width)
            lg.frames_note("no ball circle: cameras not calibrated", at_px=(width / 2, 24.0))
            lg.text("GoPro view: no ball circle, the session has no calibration between the event camera and the "
                    "GoPro (calib.store_calibration)", t_us=0, note=False)
        if has_images and mapping is not None and len(frames["t_us"]) and len(track):
            lg.frame_circles(frames["t_us"], track, mapping)
        rec.flush()
    finally:
        rec.disconnect()
    for note in lg.stats.notes:
        log.info("%s: %s", rrd_path.name, note)
    return lg.stats


def _log_results(lg: ReviewLogger, session: Session, track: Track, spin: dict, ball_view: Callable | None) -> None:
    """The flight table, the simulated truth of a demo session, and (with ``ball_view``) a ball
    close-up per spin window."""
    try:
        flights, windows = session_results(session)
    except ValueError as exc:  # not analysed, or a calibration for another sensor
        lg.text(f"no flight table: {exc}", level="WARN")
        return
    lg.flights(flights)
    demo = session.attrs.get("demo")
    if isinstance(demo, dict) and "truth_rps" in demo and "truth_axis" in demo and len(track):
        lg.truth(float(demo["truth_rps"]), demo["truth_axis"], track)
    if ball_view is None:
        return
    t_mid = (np.asarray(spin["t_start_us"], np.int64) + np.asarray(spin["t_end_us"], np.int64)) // 2
    for i in range(len(t_mid)):
        if windows["flight"][i] < 0:
            continue
        view = ball_view(session, track, spin, i, flight=int(windows["flight"][i]))
        if view is not None:
            lg.ball_view(int(t_mid[i]), view, trusted=bool(windows["trusted"][i]))
    if len(track):
        lg.clear_after_flights(track, [BALL_IMAGE, BALL_RIM, BALL_AXIS])


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


def _log_video(lg: ReviewLogger, video: str, t_us: np.ndarray, *, video_max_bytes: int,
               jpeg_quality: int, frame_stride: int) -> None:
    """Reference the session's MP4 (embedded) per frame at ``t_us`` (µs, shape (N,)); fall back to
    decoded JPEG frames when it is larger than ``video_max_bytes`` or Rerun cannot read it."""
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
            lg.rec.send_columns(FRAMES_IMAGE, indexes=[time_column(t_us[:n])],
                                columns=rr.VideoFrameReference.columns_nanos(video_ts_ns[:n]))
            lg.rec.log(FRAMES_IMAGE, rr.VideoFrameReference.from_fields(video_reference=VIDEO_ASSET), static=True)
            lg.stats.n_frames += n
            return
    else:
        reason = f"it is larger than {video_max_bytes} bytes"
    import cv2  # only to decode a video that Rerun does not embed

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
