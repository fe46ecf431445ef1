"""Hot-pixel detection from a decaying per-pixel event count.

A hot pixel fires all the time while its neighbours stay quiet; a ball or a
player passing over a pixel makes its neighbours fire too. Counts are
accumulated per time block (``count = decay * count + block_count``) and a pixel
is hot when its count is at least ``min_count`` and ``ratio`` times the mean of
its 8 neighbours.
"""

from __future__ import annotations

import cv2
import numpy as np


class HotPixelMap:
    """Running hot-pixel mask of a ``width`` x ``height`` sensor.

    Parameters
    ----------
    width, height : int
        Sensor size, px.
    decay : float
        Factor applied to the accumulated counts at each block (0..1).
    min_count : float
        Least accumulated count for a hot pixel.
    ratio : float
        Least ratio of a hot pixel's count to its neighbours' mean count.
    """

    def __init__(self, width: int, height: int, *, decay: float = 0.9, min_count: float = 6.0,
                 ratio: float = 8.0):
        self.width, self.height = int(width), int(height)
        self.decay, self.min_count, self.ratio = float(decay), float(min_count), float(ratio)
        self.counts = np.zeros((self.height, self.width), np.float32)
        self.hot = np.zeros(self.height * self.width, bool)

    def update(self, x: np.ndarray, y: np.ndarray) -> None:
        """Add one block's events (pixel columns ``x``, rows ``y``) and refresh the mask."""
        idx = y.astype(np.int64) * self.width + x.astype(np.int64)
        block = np.bincount(idx, minlength=self.width * self.height).astype(np.float32)
        self.counts *= self.decay
        self.counts += block.reshape(self.height, self.width)
        nb = cv2.boxFilter(self.counts, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        nb_mean = (nb - self.counts) / 8.0
        self.hot = ((self.counts >= self.min_count) & (self.counts >= self.ratio * nb_mean)).reshape(-1)

    def keep(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Mask of events not on a hot pixel."""
        return ~self.hot[y.astype(np.int64) * self.width + x.astype(np.int64)]
