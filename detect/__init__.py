"""Automatic ball detection and tracking from events and frames.

``track_ball(events, width=..., height=...)`` tracks a whole recording;
``BallTracker`` does the same on a live stream; both give a :class:`capture.events.Track`,
which :func:`spin_windows` cuts into the spin estimator's windows.
"""

from detect.track import SpinWindow, spin_windows
from detect.tracker import BallTracker, DetectInputError, track_ball

__all__ = ["BallTracker", "DetectInputError", "SpinWindow", "spin_windows", "track_ball"]
