"""Automatic ball detection and tracking from events and frames.

``track_ball(events, width=..., height=...)`` tracks a whole recording;
``BallTracker`` does the same on a live stream; ``detect.track`` holds the
:class:`~detect.track.Track` contract and the cutting into spin windows.
"""

from detect.track import SpinWindow, Track, spin_windows
from detect.tracker import BallTracker, track_ball

__all__ = ["BallTracker", "SpinWindow", "Track", "spin_windows", "track_ball"]
