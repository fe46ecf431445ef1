"""Compiled per-event loop of the rim fit (Numba): the outermost events of each angular sector.

:func:`detect.event_detector.fit_circle` needs, in each sector around the current centre, the
``k``-th and the ``depth``-th outermost event. Sorting all events by (sector, squared radius)
for that took most of a fit; here one pass keeps each sector's ``depth`` outermost.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np


@numba.njit(nogil=True, cache=True, boundscheck=False)
def sector_tops(x, y, cx, cy, n_sectors, k, depth):
    """Per angular sector around ``(cx, cy)``: its events, and its ``k``-th and ``depth``-th outermost.

    Sector of an event: ``floor((atan2(y - cy, x - cx) + pi) n_sectors / 2 pi) mod n_sectors``.

    Parameters
    ----------
    x, y : (N,) float64 event positions, px.
    k, depth : ranks from outside (1 = the outermost), ``k <= depth``.

    Returns
    -------
    counts : (n_sectors,) int64 events per sector.
    kth : (n_sectors,) int64 index of the ``k``-th outermost event (-1 where fewer).
    kth_rho2, deep_rho2 : (n_sectors,) float64 squared distances of the ``k``-th and the
        ``depth``-th outermost (NaN where fewer). Of equal distances the earlier event ranks outer.
    """
    counts = np.zeros(n_sectors, np.int64)
    top_rho2 = np.full((n_sectors, depth), -1.0)   # descending
    top_idx = np.full((n_sectors, depth), -1, np.int64)
    per_rad = n_sectors / (2.0 * math.pi)
    for i in range(len(x)):
        dx = x[i] - cx
        dy = y[i] - cy
        r2 = dx * dx + dy * dy
        s = np.int64((math.atan2(dy, dx) + math.pi) * per_rad) % n_sectors
        counts[s] += 1
        if r2 <= top_rho2[s, depth - 1]:
            continue
        j = depth - 1
        while j > 0 and top_rho2[s, j - 1] < r2:
            top_rho2[s, j] = top_rho2[s, j - 1]
            top_idx[s, j] = top_idx[s, j - 1]
            j -= 1
        top_rho2[s, j] = r2
        top_idx[s, j] = i
    kth = np.full(n_sectors, -1, np.int64)
    kth_rho2 = np.full(n_sectors, np.nan)
    deep_rho2 = np.full(n_sectors, np.nan)
    for s in range(n_sectors):
        if counts[s] >= k:
            kth[s] = top_idx[s, k - 1]
            kth_rho2[s] = top_rho2[s, k - 1]
        if counts[s] >= depth:
            deep_rho2[s] = top_rho2[s, depth - 1]
    return counts, kth, kth_rho2, deep_rho2


@functools.cache
def load() -> None:
    """Load the compiled loop now (from the cache: about 0.5 s once per process, holding the GIL),
    not in the first fit: a tracker made before a recording streams pays it before the stream.
    Once per process (a second thread asking meanwhile waits on Numba's lock)."""
    sector_tops(np.zeros(1), np.zeros(1), 0.0, 0.0, 12, 1, 2)
