"""Hot-pixel detection from a decaying per-pixel event count.

A hot pixel fires all the time while its neighbours stay quiet; a ball or a
player passing over a pixel makes its neighbours fire too. Counts are
accumulated per time block (``count = decay * count + block_count``) and a pixel
is hot when its count is at least ``min_count`` and ``ratio`` times the mean of
its 8 neighbours.
"""

from __future__ import annotations

import numpy as np


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
        self.counts = np.zeros((self.height, self.width), np.float32)
        self.hot = np.zeros(self.height * self.width, bool)
        self._cand = np.zeros(0, np.int64)

    def update(self, pixel: np.ndarray) -> None:
        """Add one block's events (flat pixel indices ``y * width + x``) and refresh the mask."""
        flat = self.counts.reshape(-1)
        flat *= self.decay
        flat += np.bincount(pixel, minlength=flat.size)
        self.hot[self._cand] = False
        # only pixels busy enough can be hot: test their 8 neighbours sparsely
        cand = np.flatnonzero(flat >= self.min_count)
        self._cand = cand
        if len(cand) == 0:
            return
        cy, cx = np.divmod(cand, self.width)
        nb = np.zeros(len(cand), np.float32)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    yy, xx = cy + dy, cx + dx
                    ok = (yy >= 0) & (yy < self.height) & (xx >= 0) & (xx < self.width)
                    nb[ok] += flat[yy[ok] * self.width + xx[ok]]
        self.hot[cand[flat[cand] >= self.ratio * nb / 8.0]] = True

    def keep(self, pixel: np.ndarray) -> np.ndarray:
        """Mask of events (flat pixel indices) not on a hot pixel."""
        return ~self.hot[pixel]
