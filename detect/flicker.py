"""Software anti-flicker for the tracker: events of pixels that fire again one light period
later, at the same phase.

A light on 50 / 60 Hz mains flickers at 100 / 120 Hz, and every pixel it lights fires at the
same few phases of each period (on the way up and on the way down), whatever its brightness. An
event is flagged when its pixel fired within one phase bin (1/32 of the period: 312 µs at 100 Hz)
of the same phase one period earlier (:class:`FlickerFilter`, for a stream) or earlier or later
(:func:`flicker_mask`, for a whole recording, which needs no warm-up period).

A ball crossing a pixel rarely fires it again at the same phase one period later; a ball spinning
in place at a multiple of the light's frequency divided by its texture's repeats does, and would be
filtered too: use this only where lights flicker and the sensor's own anti-flicker filter
(``capture.evk.Camera.set_anti_flicker``) was off. :func:`find_flicker_hz` tells whether lights
flicker at 100 or 120 Hz, from the events themselves.
"""

from __future__ import annotations

import numpy as np

PHASE_BINS = 32
"""Bins per light period in which the phases of a pixel's events are compared."""


class FlickerFilter:
    """Flags the events of a stream whose pixel fired at the same phase one period earlier.

    An event in phase bin ``a`` (counted from t = 0) is flagged when its pixel fired in bin
    ``a - 32``, ``a - 33`` or ``a - 31``. Per pixel and phase bin it keeps the last period in
    which the pixel fired there (as 1 + the period mod 65535; 0: never), ``width * height * 64``
    bytes; a period's events are written when it ends, with the two neighbours that cross a
    period's edge kept apart, so that the answer does not depend on how the stream is cut into
    calls.

    Parameters
    ----------
    width, height : int
        Sensor size, px.
    freq_hz : float
        The light's flicker frequency, Hz (twice the mains frequency: 100 or 120).
    """

    def __init__(self, width: int, height: int, freq_hz: float):
        try:
            freq = float(freq_hz)
        except (TypeError, ValueError):
            raise ValueError(f"flicker frequency must be a number of Hz, got {freq_hz!r}") from None
        if not (np.isfinite(freq) and freq > 0):
            raise ValueError(f"flicker frequency must be positive and finite, got {freq_hz}")
        self.width, self.height, self.freq_hz = int(width), int(height), freq
        self._bins_per_us = PHASE_BINS * freq / 1e6
        n = self.width * self.height
        self._seen = np.zeros((n, PHASE_BINS), np.uint16)
        self._last_before = np.zeros(n, np.uint16)  # bin 31's stamp before its latest (two periods back)
        self._first_bin = np.zeros(n, np.uint16)  # the period whose bin 0 the pixel last fired in
        self._period: int | None = None  # the period being read; its own events are written after it
        self._held: list[tuple[np.ndarray, np.ndarray]] = []  # (pixels, absolute bins) of that period
        self._last_t: float | None = None
        self.n_flagged = 0
        """Events flagged so far."""

    def flags(self, t_us: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Which of these events (time-sorted, after those of earlier calls) are flicker.

        Parameters
        ----------
        t_us, x, y : ndarray, shape (N,)
            Event times (µs) and pixel coordinates inside the sensor.

        Returns
        -------
        ndarray of bool, shape (N,)

        Raises
        ------
        ValueError
            Times out of order, or coordinates outside the sensor.
        """
        t = np.asarray(t_us, np.float64)
        if not len(t):
            return np.zeros(0, bool)
        x, y = np.asarray(x, np.int64), np.asarray(y, np.int64)
        if (self._last_t is not None and t[0] < self._last_t) or (len(t) > 1 and bool((t[1:] < t[:-1]).any())):
            raise ValueError("flicker filter: events out of time order")
        if x.min() < 0 or y.min() < 0 or x.max() >= self.width or y.max() >= self.height:
            raise ValueError(f"flicker filter: events outside the {self.width}x{self.height} sensor")
        self._last_t = float(t[-1])
        absolute = np.floor(t * self._bins_per_us).astype(np.int64)  # phase bins since t = 0
        pixel = y * self.width + x
        period = absolute // PHASE_BINS
        out = np.zeros(len(t), bool)
        cuts = np.r_[0, np.flatnonzero(np.diff(period)) + 1, len(t)]
        for s, e in zip(cuts[:-1], cuts[1:]):
            p_now = int(period[s])
            if p_now != self._period:
                self._commit()
                self._period = p_now
            out[s:e] = self._read(pixel[s:e], absolute[s:e] % PHASE_BINS, p_now)
            self._held.append((pixel[s:e], absolute[s:e]))
        self.n_flagged += int(out.sum())
        return out

    def _read(self, p: np.ndarray, r: np.ndarray, period: int) -> np.ndarray:
        """Flags of one period's events (pixels ``p``, phase bins ``r``), against what was
        written before: bins ``a - 32`` and, across the period's edges, ``a - 33`` (bin 0: bin
        31 two periods back) and ``a - 31`` (bin 31: this period's bin 0)."""
        before, two_back, now = _stamp(period - 1), _stamp(period - 2), _stamp(period)
        first = r == 0
        self._first_bin[p[first]] = now  # earlier in time than any bin-31 event of the period
        hit = self._seen[p, r] == before
        hit |= np.where(first, (self._seen[p, PHASE_BINS - 1] == two_back) | (self._last_before[p] == two_back),
                        self._seen[p, r - 1] == before)
        last = r == PHASE_BINS - 1
        hit |= np.where(last, self._first_bin[p] == now, self._seen[p, np.minimum(r + 1, PHASE_BINS - 1)] == before)
        return hit

    def _commit(self) -> None:
        """Write the held period's events (the next period compares with them)."""
        if not self._held:
            return
        p = np.concatenate([h[0] for h in self._held])
        a = np.concatenate([h[1] for h in self._held])
        r = a % PHASE_BINS
        last = p[r == PHASE_BINS - 1]
        self._last_before[last] = self._seen[last, PHASE_BINS - 1]  # all read before any is written
        self._seen[p, r] = _stamp(a // PHASE_BINS)
        self._held = []


def flicker_mask(events: np.ndarray, width: int, height: int, freq_hz: float,
                 chunk: int = 1 << 20) -> np.ndarray:
    """Flicker events of a whole recording: those whose pixel fired at the same phase one light
    period earlier or later (see the module docstring).

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Time-sorted events inside a ``width`` x ``height`` sensor.
    freq_hz : float
        The light's flicker frequency, Hz.
    chunk : int
        Events filtered at a time (bounds the temporary memory; the answer does not depend on it).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    n = len(events)
    out = np.zeros(n, bool)
    ahead = FlickerFilter(width, height, freq_hz)
    for s in range(0, n, chunk):
        e = events[s:s + chunk]
        out[s:s + chunk] = ahead.flags(e["t"], e["x"], e["y"])
    behind = FlickerFilter(width, height, freq_hz)
    for s in range(n, 0, -chunk):
        e = events[max(s - chunk, 0):s][::-1]
        out[max(s - chunk, 0):s] |= behind.flags(-e["t"].astype(np.float64), e["x"], e["y"])[::-1]
    return out


MAINS_FLICKER_HZ = (100.0, 120.0)
"""The light flicker of 50 and 60 Hz mains."""

_CONTROL_HZ = (87.0, 137.0)
"""Frequencies no mains light flickers at (nor at a harmonic of): the chance level of the test."""

FLICKER_SAMPLE_US = 300_000
"""Events of this long a span (from the first) that :func:`find_flicker_hz` looks at, µs ..."""

FLICKER_SAMPLE_EVENTS = 2_000_000
"""... and at most this many of them (50 ms at 40 Mev/s: five periods) ..."""

FLICKER_TEST_EVENTS = 250_000
"""... of which the events of every k-th pixel are tested, k as small as keeps at most about this
many (each pixel's events are tested whole or not at all)."""

MIN_FLICKER_SHARE = 0.15
"""Least share of the events that fire again one period later (within ``_MATCH_US``) for a scene
to flicker; it must also be ``MIN_FLICKER_RATIO`` times the share at the control frequencies (on the
detection benchmark's scenes: 3.0-4.1 times under a 100 Hz light over a quarter of the view, at most
1.0 times without one, where the share itself reaches 0.21)."""

MIN_FLICKER_RATIO = 2.0

MIN_FLICKER_PIXELS = 0.005
"""Least share of the sensor's pixels that flicker (a light, not one small object)."""

_MATCH_US = 250.0
"""How close (µs) an event must come to one period after one of its pixel's events."""


def find_flicker_hz(events: np.ndarray, width: int, height: int,
                    candidates=MAINS_FLICKER_HZ) -> float | None:
    """The frequency (Hz, one of ``candidates``) at which lights flicker in these events, or None.

    In the first :data:`FLICKER_SAMPLE_US` of events (at most :data:`FLICKER_SAMPLE_EVENTS`; those of
    a scattered subset of the pixels, :data:`FLICKER_TEST_EVENTS`), the share of events whose pixel fired one
    period ``1 / f`` earlier (to within 250 µs; of the events at least the longest period after the
    first) is measured at each candidate ``f`` and at two
    control frequencies no light flickers at. A candidate wins when its share is at least
    :data:`MIN_FLICKER_SHARE`, :data:`MIN_FLICKER_RATIO` times the controls', and spread over at
    least :data:`MIN_FLICKER_PIXELS` of the sensor (flickering light, not a ball spinning in place at
    the same rate: that still passes where it fills the sensor's view); the one with the largest share.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Time-sorted events inside a ``width`` x ``height`` sensor.

    Returns
    -------
    float or None
    """
    if not len(events):
        return None
    t = events["t"]
    n = min(int(np.searchsorted(t, int(t[0]) + FLICKER_SAMPLE_US, side="left")), FLICKER_SAMPLE_EVENTS)
    t = t[:n].astype(np.int64)
    pixel = events["y"][:n].astype(np.int64) * int(width) + events["x"][:n]
    every = -(-n // FLICKER_TEST_EVENTS)  # test one pixel in this many (scattered by a hash)
    if every > 1:
        keep = ((pixel * 2654435761) % (1 << 32) >> 16) % every == 0  # (the hash's high bits: mixed)
        pixel, t = pixel[keep], t[keep]
        if not len(t):
            return None
    key = pixel * (1 << 40) + (t - int(t[0]))  # (pixel, time) in one sortable number
    key.sort()

    def matched(freq_hz: float) -> np.ndarray:
        """Which events (in ``key`` order) have an event of their pixel one period earlier."""
        want = key - int(round(1e6 / freq_hz))
        j = np.searchsorted(key, want)  # the first event at or after the wanted time (of any pixel)
        hit = np.zeros(len(key), bool)
        for k in (j - 1, j):  # the events either side of it: same pixel, close in time
            ok = (k >= 0) & (k < len(key))
            near = key[np.clip(k, 0, len(key) - 1)]
            hit |= ok & (np.abs(near - want) <= _MATCH_US)  # (a different pixel is 2^40 µs away)
        return hit

    # only events at least the longest period after the sample's start can match at every frequency
    counted = (key & ((1 << 40) - 1)) >= int(round(1e6 / min(*_CONTROL_HZ, *candidates)))
    if not counted.any():
        return None
    chance = max(float(matched(c)[counted].mean()) for c in _CONTROL_HZ)
    best, best_share = None, 0.0
    for freq in candidates:
        hit = matched(float(freq)) & counted
        share = float(hit.sum() / counted.sum())
        pixels = len(np.unique(key[hit] >> 40))
        if (share >= MIN_FLICKER_SHARE and share >= MIN_FLICKER_RATIO * chance
                and pixels * every >= MIN_FLICKER_PIXELS * width * height and share > best_share):
            best, best_share = float(freq), share
    return best


def _stamp(period) -> np.ndarray:
    """A period as stored: 1 + period mod 65535 (0 stays free for "never")."""
    return (np.asarray(period) % 65535 + 1).astype(np.uint16)
