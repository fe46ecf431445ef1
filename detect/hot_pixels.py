"""Hot-pixel detection from a decaying per-pixel event count.

A hot pixel fires all the time while its neighbours stay quiet; a ball or a
player passing over a pixel makes its neighbours fire too. Counts are
accumulated per time block (``count = decay * count + block_count``) and a pixel
is hot when its count is at least ``min_count`` and ``ratio`` times the mean of
its 8 neighbours.
"""

from __future__ import annotations

import numpy as np

from detect._kernels import hot_update

# the counts are kept divided by the decay so far (one multiplication per update, not one per pixel),
# and brought back to scale once that divisor would pass this
_RESCALE_BELOW = 1e-6


class HotPixelMap:
    """Running hot-pixel mask of a ``width`` x ``height`` sensor.

    Parameters
    ----------
    width, height : int
        Sensor size, px.
    decay : float
        Factor applied to the accumulated counts at each update (0..1).
    min_count : float
        Least accumulated count for a hot pixel.
    ratio : float
        Least ratio of a hot pixel's count to its neighbours' mean count.
    """

    def __init__(self, width: int, height: int, *, decay: float = 0.9, min_count: float = 6.0,
                 ratio: float = 8.0):
        self.width, self.height = int(width), int(height)
        self.decay, self.min_count, self.ratio = float(decay), float(min_count), float(ratio)
        if not 0.0 <= self.decay <= 1.0:
            raise ValueError(f"decay must be within [0, 1], got {decay}")
        if not self.min_count > 0.0:
            raise ValueError(f"min_count must be > 0, got {min_count}")
        self._stored = np.zeros(self.height * self.width)  # counts / _gain
        self._gain = 1.0
        self.hot = np.zeros(self.height * self.width, bool)
        self._cand = np.zeros(0, np.int64)  # pixels at min_count or more at the last update
        self._mark = np.zeros(self.height * self.width, np.int64)  # the update that last listed each
        self._stamp = 0

    def update(self, pixel: np.ndarray) -> None:
        """Add one block's events (flat pixel indices ``y * width + x``) and refresh the mask."""
        self._gain *= self.decay
        if self._gain < _RESCALE_BELOW:
            self._stored *= self._gain
            self._gain = 1.0
        self._stamp += 1
        self._cand = hot_update(self._stored, self._gain, np.asarray(pixel), self._cand, self._mark, self._stamp,
                                self.hot, self.width, self.height, self.min_count, self.ratio)
