"""Camera calibration and event-camera / frame-camera alignment in space and time.

- :mod:`calib.intrinsics`: checkerboard / ChArUco intrinsics, event-count images of a blinking pattern.
- :mod:`calib.stereo`: stereo extrinsics, plane homography, :class:`CameraPair` mapping ball circles.
- :mod:`calib.sync`: :class:`TimeMap` (event clock <- GoPro clock) from a sync box or activity.
- :mod:`calib.store`: both in the session's root attributes; GoPro frame times on the event clock.
"""

from calib.intrinsics import (
    CalibrationError, Intrinsics, accumulate_events, calibrate_charuco, calibrate_checkerboard,
    calibrate_from_points, charuco_board, checkerboard_points, find_checkerboard,
)
from calib.stereo import (
    CameraPair, Extrinsics, calibrate_stereo, fit_homography, map_circles_homography, map_circles_stereo,
)
from calib.store import attach_video, frame_times_us, load_calibration, store_calibration
from calib.sync import SyncError, TimeMap, fit_activity, fit_sync_box

__all__ = [
    "Intrinsics", "Extrinsics", "CameraPair", "TimeMap", "CalibrationError", "SyncError",
    "checkerboard_points", "find_checkerboard", "calibrate_from_points", "calibrate_checkerboard",
    "charuco_board", "calibrate_charuco", "accumulate_events", "calibrate_stereo", "fit_homography",
    "map_circles_homography", "map_circles_stereo", "fit_sync_box", "fit_activity",
    "frame_times_us", "store_calibration", "attach_video", "load_calibration",
]
