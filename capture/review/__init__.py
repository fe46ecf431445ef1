"""Rerun review of a session: an ``.rrd`` file offline (:func:`write_rrd`), or a live viewer for the
recorder (:class:`LiveReview`), both with the entity layout and blueprint of :mod:`capture.review.layout`.

Modules: :mod:`~capture.review.layout` (timeline, entity paths, blueprint, pure helpers),
:mod:`~capture.review.logger` (the logger both share, :class:`ReviewStats`),
:mod:`~capture.review.offline`, :mod:`~capture.review.live`, :mod:`~capture.review.cli`
(``python -m capture.review SESSION --rrd OUT.rrd``).
"""

from capture.review.layout import (APPLICATION_ID, BALL3D, BALL3D_AXIS, BALL3D_SPHERE, DEFAULT_MAX_EVENTS_PER_SLICE,
                                   DEFAULT_SLICE_US, EVENTS_BALL, EVENTS_OFF, EVENTS_ON, EVENTS_SENSOR,
                                   EVENTS_SPIN_AXIS, FRAMES_BALL, FRAMES_IMAGE, PIXEL_OFFSET, PLOT_AZIMUTH,
                                   PLOT_CONFIDENCE, PLOT_ELEVATION, PLOT_EVENT_RATE, PLOT_RPS, PLOT_STATUS, TEXT_LOG,
                                   TIMELINE, VIDEO_ASSET, axis_angles_deg, blueprint, circle_mapping,
                                   session_recording_id)
from capture.review.live import LIVE_MODES, LiveReview
from capture.review.logger import ReviewError, ReviewStats
from capture.review.offline import write_rrd

__all__ = [
    "APPLICATION_ID", "BALL3D", "BALL3D_AXIS", "BALL3D_SPHERE", "DEFAULT_MAX_EVENTS_PER_SLICE", "DEFAULT_SLICE_US",
    "EVENTS_BALL", "EVENTS_OFF", "EVENTS_ON", "EVENTS_SENSOR", "EVENTS_SPIN_AXIS", "FRAMES_BALL", "FRAMES_IMAGE",
    "LIVE_MODES", "PIXEL_OFFSET", "PLOT_AZIMUTH", "PLOT_CONFIDENCE", "PLOT_ELEVATION", "PLOT_EVENT_RATE", "PLOT_RPS",
    "PLOT_STATUS", "TEXT_LOG", "TIMELINE", "VIDEO_ASSET", "LiveReview", "ReviewError", "ReviewStats",
    "axis_angles_deg", "blueprint", "circle_mapping", "session_recording_id", "write_rrd",
]
