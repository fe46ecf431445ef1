"""The cutting of events into spin windows along a ball track.

Detection produces a :class:`capture.events.Track`; spin estimation consumes the
:class:`SpinWindow` objects cut along it here.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from capture.events import Track, time_slice
from detect._kernels import near_track


@dataclass(frozen=True)
class SpinWindow:
    """Events of one ball over one time window, with the track's prior.

    Attributes
    ----------
    t_start_us, t_end_us : int
        Window ``[t_start_us, t_end_us)``, µs.
    events : ndarray of EVENT_DTYPE
        Events inside the moving circle (plus margin) during the window.
    center : (float, float)
        Ball centre in pixels at ``t_start_us``.
    radius_px : float
        Ball radius in pixels.
    velocity_px_s : (float, float)
        Image velocity of the centre, px/s.
    flight : int
        Flight number of the track rows the window came from.
    sigma_px : float
        Uncertainty (1 sigma, px) of ``center`` and ``radius_px``: that of the track row at
        ``t_start_us``, else the larger of the two rows around it (:attr:`capture.events.Track.sigma_px`);
        NaN where not known.
    """

    t_start_us: int
    t_end_us: int
    events: np.ndarray
    center: tuple[float, float]
    radius_px: float
    velocity_px_s: tuple[float, float]
    flight: int
    sigma_px: float = math.nan


def _sigma_at(rows: Track, t_us: int) -> float:
    """The ``sigma_px`` of a flight's ``rows`` that :meth:`Track.at` takes at ``t_us``: the rows at
    ``t_us`` if there are any, else the larger of the last row before it and the first after it (the
    nearest one outside the flight's span), px; NaN where none is known."""
    j0, j1 = int(np.searchsorted(rows.t_us, t_us, side="left")), int(np.searchsorted(rows.t_us, t_us, side="right"))
    near = rows.sigma_px[j0:j1] if j1 > j0 else rows.sigma_px[max(j0 - 1, 0):j0 + 1]
    return float(np.nanmax(near)) if np.isfinite(near).any() else math.nan


def window_starts_us(track: Track, step_us: int) -> dict[int, np.ndarray]:
    """Default spin-window start times per flight: every ``step_us`` from the flight's first row, µs."""
    out = {}
    for flight in track.flight_ids():
        t = track.t_us[track.flight == flight]
        out[int(flight)] = np.arange(int(t[0]), int(t[-1]) + 1, step_us, dtype=np.int64)
    return out


def events_near(t_us: np.ndarray, x: np.ndarray, y: np.ndarray, track: Track, reach_px: np.ndarray,
                longest_us: int) -> np.ndarray:
    """Indices of the events ``(t_us, x, y)`` (time-sorted µs, pixel coordinates; columns of an event
    array, any strides) near a track.

    An event counts when it lies within ``reach_px[i]`` px of the circle centre of ``track``'s last
    row ``i`` at or before it, moved along that row's velocity, and is less than ``longest_us`` after
    the last row; events before the first row do not. One compiled pass
    (:func:`detect._kernels.near_track`).

    Parameters
    ----------
    t_us, x, y : ndarray, shape (N,)
    track : Track
        The rows of one flight, time-sorted (M >= 1).
    reach_px : ndarray of float, shape (M,)
    longest_us : int

    Returns
    -------
    ndarray of int64, shape (K,), increasing.
    """
    t_row = track.t_us
    ends = np.append(t_row[1:], t_row[-1] + longest_us)  # an event may fall in a gap between rows
    return near_track(t_us, x, y, t_row, ends, track.cx, track.cy, track.vx, track.vy,
                      np.asarray(reach_px, np.float64))


def _inside(events: np.ndarray, t0_us: int, cx: float, cy: float, vx: float, vy: float,
            radius_px: float) -> np.ndarray:
    """Indices of ``events`` within ``radius_px`` of the centre ``(cx, cy)`` at ``t0_us`` moving
    at ``(vx, vy)`` px/s."""
    dt_s = (events["t"] - t0_us) * 1e-6
    dx = events["x"] - (cx + vx * dt_s)
    dy = events["y"] - (cy + vy * dt_s)
    return np.flatnonzero(dx * dx + dy * dy <= radius_px ** 2)


def spin_windows(events: np.ndarray, track: Track, *, window_us: int = 2000, step_us: int | None = None,
                 min_events: int = 2000, max_events: int | None = None, max_window_us: int | None = None,
                 margin_px: float = 1.0, starts_us: dict[int, np.ndarray] | None = None
                 ) -> Iterator[SpinWindow]:
    """Cut ``events`` into spin windows along ``track``.

    Each flight is covered by windows starting every ``step_us`` (default:
    ``window_us``, no overlap). A window keeps the events whose distance to the
    moving centre ``c(t) = c0 + v (t - t0)`` is at most ``r + margin_px``. A window
    lasts ``window_us``; when it holds fewer than ``min_events`` such events and
    ``max_window_us`` is given, it is lengthened (up to ``max_window_us``) until it
    holds ``min_events`` — short windows where the ball fires many events, longer
    ones where it fires few. Windows that still hold fewer than ``min_events`` are
    skipped; at most ``max_events`` (the first ones) are kept.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Time-sorted events.
    track : Track
        The ball track.
    starts_us : dict, optional
        Window start times (µs) per flight number, instead of every ``step_us``
        (see :func:`window_starts_us`); lets a flight be split into independent parts.
    """
    step_us = window_us if step_us is None else step_us
    longest = max(window_us, max_window_us or window_us)
    starts_us = window_starts_us(track, step_us) if starts_us is None else starts_us
    for flight, starts in starts_us.items():
        rows = track.select(track.flight == flight)  # (for the windows' circle sigma)
        for t0 in np.asarray(starts, np.int64).tolist():
            cx, cy, r, vx, vy = track.at(t0, flight=int(flight))
            circle = (t0, cx, cy, vx, vy, r + margin_px)
            # the common case first: enough ball events within window_us (then the longer span
            # cannot change the window)
            win = time_slice(events, t0, t0 + window_us)
            inside = _inside(win, *circle) if len(win) >= min_events else np.zeros(0, np.int64)
            t1 = t0 + window_us
            if len(inside) >= min_events:
                n_short = len(inside)
            else:
                win = time_slice(events, t0, t0 + longest)
                if len(win) < min_events:
                    continue
                inside = _inside(win, *circle)
                if len(inside) < min_events:
                    continue
                n_short = int(np.searchsorted(win["t"][inside], t1))
                if n_short < min_events:  # lengthen up to the min_events-th ball event
                    t1 = int(win["t"][inside[min_events - 1]]) + 1
                    n_short = int(np.searchsorted(win["t"][inside], t1))
            kept = np.take(win, inside[:n_short if max_events is None else min(n_short, max_events)])
            yield SpinWindow(t0, t1, kept, (cx, cy), r, (vx, vy), int(flight), _sigma_at(rows, t0))
