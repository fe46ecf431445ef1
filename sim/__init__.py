"""Synthetic spinning-ball simulator with ground truth.

Entry points:

- :func:`spinning_ball` - one spinning (optionally drifting) ball: ``(events, truth)``.
- :class:`SensorModel`, :data:`SENSOR_PRESETS` - the event pixel (``sensor=`` of
  :func:`spinning_ball` and :func:`flight`): ``"ideal"`` (plain ESIM) or ``"realistic"``
  (DVS bandwidth, leak and shot noise, refractory period, readout jitter).
- :func:`flight` - a ballistic flight across the sensor with background, noise, hot
  pixels, distractors, optional frames and sync triggers: a :class:`Recording`.
- :class:`Recording` - events, triggers, frames and truth; ``Recording.save(out_dir)`` /
  ``Recording.load(out_dir)`` write and read a recording directory.
- :func:`rally` - the quick flight preset used by the built-in demo.
- ``python -m sim.dataset --preset paper OUT`` - datasets on disk.
"""

from .balls import spinning_ball
from .esim import SENSOR_PRESETS, SensorModel
from .flight import flight, rally
from .frames import SyncBox
from .recording import Recording

__all__ = ["spinning_ball", "flight", "rally", "Recording", "SyncBox", "SensorModel", "SENSOR_PRESETS"]
