"""The period of a spinning ball's image, from the events' autocorrelation in time.

A ball turning at a steady rate looks the same again after each full turn (whatever its
axis, lens or texture): the events at a point of its image repeat with the rotation's
period.  The events are counted in a coarse grid on the (moving) disc, one count per
cell, polarity and time bin; the autocorrelation in time of every such count, summed
over cells, peaks at the period and its multiples.  Where a window spans a few turns this
measures the rate to a fraction of a percent, independently of the contrast the warp
scores: a sparse texture (seams, one logo) that the warp's search misses over many turns
still repeats.  A texture with a symmetry about the spin axis repeats after a fraction of a
turn (half a turn for a two-fold one): :func:`turn_speeds` gives the speeds a period allows.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft

from spin import _kernels
from spin.objective import BallEvents


def image_period(ev: BallEvents, velocity_px_s, *, min_period_s: float, n_cells: int = 12,
                 n_bins: int = 512, max_bins: int = 4096, min_turns: float = 2.2, min_peak: float = 0.15,
                 min_prominence: float = 0.1) -> tuple[float, float] | None:
    """The period (s) over which the ball's image repeats and the height of its peak (0..1), or None.

    Parameters
    ----------
    ev : BallEvents
        Time-sorted ball events.
    velocity_px_s : (2,)
        The ball centre's velocity (px/s), which the grid follows.
    min_period_s : float
        Shortest period looked for (s).
    n_cells : int
        Cells across the disc's diameter (``n_cells`` x ``n_cells``, times two polarities).
    n_bins, max_bins : int
        Time bins over the window: at least ``n_bins``, more (up to ``max_bins``) where a bin would
        otherwise span more than a sixth of ``min_period_s``.
    min_turns : float
        The window must hold at least this many periods.
    min_peak, min_prominence : float
        The normalised autocorrelation (1 at lag 0) must reach ``min_peak`` at the period and rise
        by ``min_prominence`` above its lowest value at shorter lags; of such peaks the one taken is the
        first within 70 % of the highest (the others are its multiples).  A period whose double lies
        inside the window must show a peak there too, at least half as high.
    """
    if not min_period_s > 0:
        raise ValueError(f"min_period_s must be positive, not {min_period_s}")
    if len(ev) < 2:
        return None
    span_s = float(ev.s_s[-1] - ev.s_s[0])
    if span_s < min_turns * min_period_s:
        return None
    # bins at most a sixth of the shortest period, up to ``max_bins``
    n_bins = int(np.clip(6 * span_s / min_period_s, n_bins, max_bins))
    bin_s = span_s / n_bins
    lo, hi = max(3, int(min_period_s / bin_s)), int(n_bins / min_turns)
    if hi <= lo + 1:
        return None
    a = _autocorrelation(ev, velocity_px_s, n_cells, n_bins)
    inner = a[lo:hi]
    peaks = np.flatnonzero((inner > a[lo - 1:hi - 1]) & (inner >= a[lo + 1:hi + 1]) & (inner > min_peak)) + lo
    # a repeat rises above the trough after lag 0; a wiggle on the slow fall from lag 0 (a slow spin's
    # image changes little from bin to bin) does not
    trough = np.minimum.accumulate(a[1:hi])  # trough[j - 2]: the lowest of a[1:j]
    peaks = peaks[a[peaks] - trough[peaks - 2] >= min_prominence]
    if not len(peaks):
        return None
    k = int(peaks[np.argmax(a[peaks] >= 0.7 * a[peaks].max())])
    # a texture with a symmetry about the axis can repeat at a third or a half of that, below the
    # shortest period looked for: the fundamental is the shortest such repeat
    for m in (3, 2):
        j = _local_peak(a, k / m)
        if j is not None and j >= 6 and a[j] >= 0.7 * a[k] and a[j] > min_peak:
            k = j
            break
    if a[k] - a[1:k].min() < min_prominence:
        return None
    lag = _peak(a, k)
    double = int(round(2 * lag))
    if double + 1 < len(a) and a[double - 1:double + 2].max() < 0.5 * a[k]:
        return None
    # the peaks at 2, 4, 8, ... periods (as far as the window holds them) locate it ever more finely
    m = 2
    while m * lag + 3 < n_bins / 2:
        j = _local_peak(a, m * lag)
        if j is None or a[j] < 0.5 * a[k]:
            break
        lag = _peak(a, j) / m
        m *= 2
    return float(lag * bin_s), float(a[k])


FLIGHT_INNER = 0.85
"""Share of the radius inside which a flight's events count: the silhouette's edge fires as the
ball moves whatever it turns, and in a whole flight it drowns a sparse texture's repeat."""
FLIGHT_MAX_BINS = 8192
FLIGHT_MAX_EVENTS = 400_000


def flight_period(t_us, x_px, y_px, p, cx_px, cy_px, r_px, *, max_rps: float = 1200.0,
                  inner: float = FLIGHT_INNER, max_events: int = FLIGHT_MAX_EVENTS) -> tuple[float, float, float] | None:
    """The period over which a ball's image repeats through a flight, for any texture.

    Each event is placed on the disc of the track at its own time (so the ball may fall, curve,
    approach or recede: coordinates are scaled by the radius at that time), and
    :func:`image_period` looks for the repeat.  A flight spans many turns, so the period is
    found where a window's own search fails on a sparse texture; the rate of one turn per
    period (or a fold of it, see :func:`turn_speeds`) follows.

    Parameters
    ----------
    t_us, x_px, y_px, p : ndarray (N,)
        Time-sorted events (µs, px, polarity 0/1) of the flight.
    cx_px, cy_px, r_px : ndarray (N,)
        The ball's circle at each event's time (px), e.g. the track interpolated.
    max_rps : float
        Fastest spin looked for (rev/s): the shortest period is half a turn at it.
    inner : float
        Only events within ``inner`` times the radius count (:data:`FLIGHT_INNER`).
    max_events : int
        More such events are thinned evenly to this many (the repeat shows in far fewer).

    Returns
    -------
    (period_s, peak, span_s) or None
        The period (s), the height of its autocorrelation peak (0..1) and the span of the events
        it was measured on (s); None where the image shows no repeat.
    """
    t_us = np.asarray(t_us, np.int64)
    dx = np.asarray(x_px, np.float64) - cx_px
    dy = np.asarray(y_px, np.float64) - cy_px
    r = np.asarray(r_px, np.float64)
    keep = np.flatnonzero(dx * dx + dy * dy <= (inner * r) ** 2)
    keep = keep[::-(-len(keep) // max_events)] if len(keep) > max_events else keep
    if len(keep) < 2:
        return None
    r_ref = float(np.median(r[keep]))
    scale = r_ref / r[keep]
    s = ((t_us[keep] - t_us[keep[0]]) * 1e-6)
    weight = np.where(np.asarray(p)[keep] > 0, 1.0, -1.0)
    ev = BallEvents((dx[keep] * scale).astype(np.float32), (dy[keep] * scale).astype(np.float32), s,
                    np.zeros_like(s), weight, r_ref)
    min_period_s = 0.5 / max_rps
    found = image_period(ev, (0.0, 0.0), min_period_s=min_period_s, max_bins=FLIGHT_MAX_BINS)
    if found is None:
        return None
    return found[0], found[1], float(s[-1])


def on_track_disc(t_us, x_px, y_px, track_t_us, track_cx_px, track_cy_px, track_r_px,
                  inner: float = FLIGHT_INNER) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The events within ``inner`` times the radius of a track's circle at each event's own time.

    Parameters
    ----------
    t_us, x_px, y_px : ndarray (N,)
        Time-sorted events (µs, px).
    track_t_us, track_cx_px, track_cy_px, track_r_px : ndarray (M,), M >= 1
        Time-sorted circles (µs, px), interpolated linearly between rows (held beyond the ends).
    inner : float
        Share of the radius (:data:`FLIGHT_INNER`).

    Returns
    -------
    idx : ndarray of int64 (K,)
        The events' indices, increasing.
    cx_px, cy_px, r_px : ndarray (K,)
        Their circles, as :func:`flight_period` takes them.

    One compiled pass over events and rows (:func:`spin._kernels.on_track_disc`).
    """
    t_us, x_px, y_px = np.asarray(t_us), np.asarray(x_px), np.asarray(y_px)
    if t_us.dtype != np.int64:
        t_us = t_us.astype(np.int64)
    if x_px.dtype != np.uint16 or y_px.dtype != np.uint16:  # (events' columns go in as they are)
        x_px, y_px = x_px.astype(np.float64), y_px.astype(np.float64)
    return _kernels.on_track_disc(t_us, x_px, y_px, np.ascontiguousarray(track_t_us, np.int64),
                                  *(np.ascontiguousarray(a, np.float64) for a in (track_cx_px, track_cy_px, track_r_px)),
                                  float(inner))


def _local_peak(a: np.ndarray, lag: float) -> int | None:
    """The local maximum of ``a`` within a bin of ``lag`` (bins), or None."""
    j = int(round(lag))
    if j < 2 or j + 2 >= len(a):
        return None
    j += int(np.argmax(a[j - 1:j + 2])) - 1
    return j if a[j] >= a[j - 1] and a[j] >= a[j + 1] else None


def _peak(a: np.ndarray, k: int) -> float:
    """Lag (bins, fractional) of the parabola through ``a`` at ``k - 1, k, k + 1``."""
    curvature = float(a[k - 1]) - 2.0 * float(a[k]) + float(a[k + 1])
    return k + (float(np.clip(0.5 * float(a[k - 1] - a[k + 1]) / curvature, -0.5, 0.5)) if curvature < 0 else 0.0)


def turn_speeds(period_s: float, folds=(1, 2)) -> np.ndarray:
    """Angular speeds (rad/s) a ball whose image repeats every ``period_s`` (s) may turn at.

    The period is one turn, or ``1/k`` of one for a texture with a ``k``-fold symmetry about the
    axis: ``2 pi / (k period_s)`` for ``k`` in ``folds``.
    """
    return 2 * math.pi / (period_s * np.asarray(folds, dtype=np.float64))


def _autocorrelation(ev: BallEvents, velocity_px_s, n_cells: int, n_bins: int) -> np.ndarray:
    """Normalised autocorrelation (1 at lag 0) of the grid counts' deviations from their means, (n_bins,)."""
    s = ev.s_s - ev.s_s[0]
    vx, vy = (s.dtype.type(c) for c in velocity_px_s)
    scale = n_cells / (2.0 * ev.radius_px)
    cx = np.clip(((ev.x_px - vx * ev.s_s + ev.radius_px) * scale).astype(np.intp), 0, n_cells - 1)
    cy = np.clip(((ev.y_px - vy * ev.s_s + ev.radius_px) * scale).astype(np.intp), 0, n_cells - 1)
    t_bin = np.minimum((s * (n_bins / float(s[-1]))).astype(np.intp), n_bins - 1)
    index = ((cy * n_cells + cx) * 2 + (ev.weight > 0)) * n_bins + t_bin
    counts = np.bincount(index, minlength=2 * n_cells * n_cells * n_bins).reshape(-1, n_bins)
    counts = counts[counts.any(axis=1)].astype(np.float32)
    counts -= counts.mean(axis=1, keepdims=True)
    spectrum = scipy.fft.rfft(counts, n=2 * n_bins, axis=1)  # in float32 (4x NumPy's on a flight's 288 x 16384)
    power = (spectrum.real ** 2 + spectrum.imag ** 2).sum(axis=0, dtype=np.float64)
    a = scipy.fft.irfft(power, n=2 * n_bins)[:n_bins]
    a *= n_bins / (n_bins - np.arange(n_bins))  # each lag's sum over fewer pairs
    return a / max(a[0], 1e-30)
