"""Frame-camera video in a session: attach an MP4, align it to the event clock, read frames back.

The video file stays an MP4 (copied into ``SESSION/gopro/``); the store keeps
its per-frame times already mapped onto the event camera's clock
(``frames/t_us``), the fitted clock map (attrs ``time_sync``) and the frame
camera's description (attrs ``frame_camera``).
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from capture.session import open_session, update_session

MIN_SYNC_TRIGGERS = 4
"""Fewest trigger events for the sync-box method; with fewer, activity correlation is used."""


def _event_times_sample(session, max_events: int = 5_000_000) -> np.ndarray:
    """Event times (µs) of the session, every k-th event when there are more than ``max_events``."""
    n = session.n_events
    step = max(1, n // max_events)
    return np.asarray(session.root["events"]["t"][:n:step])


def fit_time_map(session_dir, video, *, exposure_s: float | None = None, led_roi=None):
    """Fit the frame-clock -> event-clock map of ``video`` for a session.

    Uses the sync box (LED in the frames, wired to the EVK trigger input) when the
    session holds trigger events, else the cross-correlation of event activity with
    frame-difference energy.

    Returns
    -------
    time_map : calib.sync.TimeMap
    exposure_s : float
        The exposure time used (estimated by the sync-box fit when not given), s.
    """
    from calib import sync

    s = open_session(session_dir)
    triggers = s.triggers()
    if len(triggers) >= MIN_SYNC_TRIGGERS:
        brightness, _ = sync.led_brightness(video.frames(gray=True), roi=led_roi)
        try:
            return sync.fit_sync_box(brightness, video.t_s, triggers, exposure_s=exposure_s)
        except sync.SyncError:
            pass  # an LED that is not in view: fall back to activity correlation
    exposure_s = exposure_s or 1.0 / float(video.fps)
    energy = sync.frame_difference_energy(img for _, _, img in video.frames(gray=True))
    return sync.fit_activity(_event_times_sample(s), video.t_s, energy, exposure_s=exposure_s), exposure_s


def attach_video(session_dir, mp4_path, *, exposure_s: float | None = None, led_roi=None) -> str:
    """Copy a GoPro recording into the session and store its frame times on the event clock.

    Parameters
    ----------
    session_dir : path
        The session.
    mp4_path : path
        The MP4 (first chapter of a chaptered recording).
    exposure_s : float, optional
        Frame exposure time, s (default: one frame period).
    led_roi : tuple, optional
        Sync-box LED region ``(x0, y0, x1, y1)`` in frame pixels, half-open (default: found
        automatically as the most varying block of the frames).

    Returns
    -------
    str
        One line describing the fitted time map.
    """
    from calib import store
    from capture.gopro import chapter_paths, read_video

    session_dir = Path(session_dir)
    dest = session_dir / "gopro"
    dest.mkdir(exist_ok=True)
    first = None
    for p in chapter_paths(mp4_path):
        target = dest / p.name
        if p.resolve() != target.resolve():
            shutil.copy2(p, target)
        first = first or target
    video = read_video(first)
    tm, exposure_s = fit_time_map(session_dir, video, exposure_s=exposure_s, led_roi=led_roi)
    writer = update_session(session_dir)
    store.attach_video(writer, session_dir, video, tm, exposure_s=exposure_s)
    writer.set_attrs(frame_camera={"model": "GoPro", "width": video.width, "height": video.height,
                                   "fps_num": video.fps_num, "fps_den": video.fps_den,
                                   "n_frames": video.n_frames, "exposure_s": float(exposure_s)})
    writer.close()
    sigma = float(np.sqrt(max(tm.cov[0, 0], 0.0)))
    return (f"{video.n_frames} frames at {float(video.fps):.2f} fps aligned by {tm.method}: "
            f"video t=0 at event t={float(tm.to_event_us(0.0)) / 1e6:.6f} s, drift {tm.drift_ppm:+.1f} ppm, "
            f"±{sigma:.0f} µs")


def iter_session_frames(session, width: int, height: int) -> Iterator[tuple[int, np.ndarray]]:
    """Frames of a session in event-sensor geometry: ``(t_us, image)``, lazily.

    Frames come from the stored images or from the attached video. They are
    warped by the stored frame-to-event homography (attrs ``calibration``, key
    ``homography``, see ``calib.stereo.CameraPair``); without one, only frames
    already of the sensor's size are used (the same view), and none otherwise.
    """
    from capture.gopro import read_video

    frames = session.frames()
    H = (session.attrs.get("calibration") or {}).get("homography")
    H = None if H is None else np.asarray(H, np.float64).reshape(3, 3)

    def to_sensor(img):
        if H is not None:
            return cv2.warpPerspective(img, H, (width, height))
        return img if img.shape[:2] == (height, width) else None

    if frames["image"] is not None:
        source = ((int(t), img) for t, img in zip(frames["t_us"], frames["image"]))
    elif frames["video"] is not None:
        video = read_video(frames["video"])
        source = ((int(frames["t_us"][i]), img) for i, _, img in video.frames())
    else:
        return
    for t_us, img in source:
        img = to_sensor(img)
        if img is None:
            return
        yield t_us, img
