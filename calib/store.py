"""Calibration in the session store: root attributes ``time_sync`` (:class:`TimeMap`) and
``calibration`` (:class:`CameraPair`), and GoPro frame times mapped onto the event clock."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.intrinsics import Intrinsics
from calib.stereo import CameraPair
from calib.sync import TimeMap, exposure_span_s


def frame_times_us(t_frame_s, time_map: TimeMap, *, exposure_s=0.0) -> np.ndarray:
    """Event-clock times (int64 µs) of frames: the centre of each exposure
    (:func:`calib.sync.exposure_span_s`: ``t + exposure_s / 2`` for one exposure for the clip).

    Parameters
    ----------
    t_frame_s : array_like, shape (N,)
        Frame presentation times on the GoPro clock (s), e.g. ``read_video(path).t_s``.
    time_map : TimeMap
    exposure_s : float or array_like, shape (N,)
        Exposure time (s), or one per frame (auto-exposure); 0 gives the exposure start.
    """
    start, end = exposure_span_s(t_frame_s, exposure_s)
    return np.round(time_map.to_event_us(0.5 * (start + end))).astype(np.int64)


def store_calibration(writer, *, time_map: TimeMap | None = None, cameras: CameraPair | None = None) -> None:
    """Write the clock map and/or the camera pair into a session's root attributes.

    Parameters
    ----------
    writer : capture.session.SessionWriter
    time_map : TimeMap, optional
        Stored as ``attrs["time_sync"]``.
    cameras : CameraPair, optional
        Stored as ``attrs["calibration"]``.
    """
    attrs = {}
    if time_map is not None:
        attrs["time_sync"] = time_map.to_dict()
    if cameras is not None:
        attrs["calibration"] = cameras.to_dict()
    writer.set_attrs(**attrs)


def attach_video(writer, session_dir, video, time_map: TimeMap, *, exposure_s=0.0) -> np.ndarray:
    """Reference a GoPro recording from the session with its frame times on the event clock.

    Parameters
    ----------
    writer : capture.session.SessionWriter
    session_dir : str or Path
        The session directory (the video path is stored relative to it when inside it).
    video : capture.gopro.Video
        From :func:`capture.gopro.read_video` (first chapter's path is stored).
    time_map : TimeMap
    exposure_s : float or array_like, shape (N,)
        Exposure time (s), or one per frame; the stored time is the exposure centre.

    Returns
    -------
    ndarray of int64, shape (N,)
        The frame times written (µs, event clock).
    """
    t_us = frame_times_us(video.t_s, time_map, exposure_s=exposure_s)
    p = Path(video.paths[0]).resolve()
    try:
        rel = str(p.relative_to(Path(session_dir).resolve()))
    except ValueError:
        rel = str(p)
    writer.set_video(rel, t_us)
    store_calibration(writer, time_map=time_map)
    return t_us


def load_calibration(attrs: dict) -> tuple[TimeMap | None, CameraPair | None]:
    """``(TimeMap or None, CameraPair or None)`` from a session's root attributes (``Session.attrs``)."""
    tm = TimeMap.from_dict(attrs["time_sync"]) if attrs.get("time_sync") else None
    cp = CameraPair.from_dict(attrs["calibration"]) if attrs.get("calibration") else None
    return tm, cp


def event_camera(session) -> Intrinsics | None:
    """The event camera's intrinsics from a session's calibration (attrs ``calibration``, see
    ``calib.store.load_calibration``), or None when it has none.

    Raises
    ------
    ValueError
        When the calibrated camera's image size is not the session's sensor size.
    """
    cameras = load_calibration(session.attrs)[1]
    camera = None if cameras is None else cameras.event
    if camera is not None and (camera.width, camera.height) != (session.width, session.height):
        raise ValueError(f"calibration: the event camera is calibrated for {camera.width}x{camera.height} px, "
                         f"the session's sensor is {session.width}x{session.height} px")
    return camera
