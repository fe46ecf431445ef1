"""Public entry points: one estimate from events and a circle, or one per track window."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from spin.fast import FAST_EVENTS, estimate_fast
from spin.objective import BallEvents, IweGeometry, contrast
from spin.paper import PAPER_EVENTS, estimate_paper
from spin.search import coarse_search, distinct_candidates


WARM_GAP_US = 50_000  # longest gap between windows of a flight across which an estimate seeds the next


class SpinInputError(ValueError):
    """The events or the circle cannot give a spin estimate (too few events, empty circle, ...)."""


@dataclass(frozen=True)
class SpinEstimate:
    """One spin estimate (conventions: ``docs/conventions.md``).

    Attributes
    ----------
    axis : ndarray (3,)
        Unit spin axis, camera frame (X right, Y down, Z forward), right-hand rule with ``omega >= 0``.
    omega_rad_s : float
        Angular speed, rad/s, >= 0.
    rps : float
        Revolutions per second, ``omega / (2 pi)``.
    velocity_px_s : ndarray (2,)
        Image velocity of the ball centre, px/s.
    t_start_us, t_end_us : int
        Time span of the events used, µs (end exclusive).
    n_events : int
        Number of events used.
    contrast : float
        IWE variance at the estimate (method-specific scale).
    converged : bool
        Whether the optimiser met its convergence test.
    confidence : float
        0..1; low when the contrast barely beats no rotation, when a distinct rival
        solution (other axis or aliased omega) is almost as good, when the window
        covers little rotation, when little of the ball's rim fires, or when the
        events come in bursts (a strobe: aliased spins align them equally well).
    method : str
        ``"fast"`` or ``"paper"``.
    axis_sigma_deg, rps_sigma_pct : float
        Uncertainty (1 sigma) of the axis (deg) and of the rate (% of ``rps``), from the
        spread of the estimates on the two halves of the events (``spin.fast.estimate_fast``);
        NaN for ``method="paper"``.
    """

    axis: np.ndarray
    omega_rad_s: float
    rps: float
    velocity_px_s: np.ndarray
    t_start_us: int
    t_end_us: int
    n_events: int
    contrast: float
    converged: bool
    confidence: float
    method: str
    axis_sigma_deg: float = float("nan")
    rps_sigma_pct: float = float("nan")


def _check_events(events) -> np.ndarray:
    names = getattr(getattr(events, "dtype", None), "names", None) or ()
    missing = [f for f in ("t", "x", "y", "p") if f not in names]
    if missing:
        raise SpinInputError(f"events: need a structured array with fields t, x, y, p (missing {missing})")
    return events


_JITTER_REACH_PX = float(np.sqrt(0.5))  # farthest a dithered event moves


@lru_cache(maxsize=1)
def _jitter_table(n: int = 1 << 16) -> np.ndarray:
    """Fixed uniform offsets in [-0.5, 0.5) px, float32 (2, n), read-only."""
    table = np.random.default_rng(0).random((2, n), dtype=np.float32)
    table -= np.float32(0.5)
    table.flags.writeable = False
    return table


def _jitter_px(n: int) -> np.ndarray:
    """The first ``n`` (2, n) offsets of :func:`_jitter_table`, repeated past its end."""
    table = _jitter_table()
    return table[:, :n] if n <= table.shape[1] else np.tile(table, (1, -(-n // table.shape[1])))[:, :n]


def prepare(events, center, radius_px: float, *, t0_us=None, velocity_px_s=(0.0, 0.0), rim_fraction: float = 1.0,
            max_events: int | None = None, min_events: int = 200, sensor_size=None,
            dither: bool = False, thin_to: int | None = None) -> tuple[BallEvents, np.ndarray]:
    """Select the events inside the moving circle and express them for warping.

    Returns the :class:`BallEvents` (float32; ``t_ref`` at the middle of the
    selected events) and the selected events' times (int64 µs, (N,)).  Raises
    :class:`SpinInputError` naming the problem.

    With ``dither``, each event's position is spread uniformly over its pixel (a fixed
    pseudo-random draw, so results repeat): events sit on the integer pixel lattice,
    and an IWE of sharp, bilinearly voted events scores warps that keep slow-moving
    events on that lattice higher than it should, which pulls the estimate (by several
    degrees for axes near the image plane on windows of a few degrees' rotation).

    With ``thin_to``, more events inside the circle (after ``max_events``) keep every k-th
    (the fewest k leaving at most ``thin_to``).
    """
    events = _check_events(events)
    cx, cy = (float(c) for c in center)
    r = float(radius_px)
    if not (np.isfinite(cx) and np.isfinite(cy) and np.isfinite(r)) or r <= 2.0:
        raise SpinInputError(f"circle: centre ({cx}, {cy}) and radius {r} px must be finite with radius > 2 px")
    w, h = sensor_size if sensor_size is not None else (65536, 65536)
    if cx + r < 0 or cy + r < 0 or cx - r > w - 1 or cy - r > h - 1:
        raise SpinInputError(f"circle: centre ({cx:.1f}, {cy:.1f}) radius {r:.1f} px lies outside the sensor "
                             f"{w}x{h}")
    if len(events) == 0:
        raise SpinInputError("events: empty array")
    if thin_to is not None and thin_to < 1:
        raise SpinInputError(f"thin_to: {thin_to} must be at least 1")
    t_us = np.ascontiguousarray(events["t"])  # one pass over the records; the rest reads plain arrays
    if (t_us[1:] < t_us[:-1]).any():
        order = np.argsort(t_us, kind="stable")
        events, t_us = events[order], t_us[order]
    t0 = int(t_us[0]) if t0_us is None else int(t0_us)
    f32 = np.float32
    vx, vy = (f32(c) for c in velocity_px_s)
    # float32 throughout: exact to the microsecond for windows up to 16 s after t0
    s = (t_us - t0).astype(f32)
    s *= f32(1e-6)
    x = events["x"].astype(f32)
    x -= f32(cx)
    y = events["y"].astype(f32)
    y -= f32(cy)
    dx = x - vx * s
    dy = y - vy * s
    dx *= dx
    dy *= dy
    dx += dy
    # dithered events may move by up to sqrt(0.5) px: select them so that they stay on the ball
    rim = min(rim_fraction * r, r - _JITTER_REACH_PX) if dither else rim_fraction * r
    idx = np.flatnonzero(dx <= f32(rim * rim))
    if len(idx) == 0:
        raise SpinInputError(f"circle: no events inside the circle centre ({cx:.1f}, {cy:.1f}) radius {r:.1f} px")
    if max_events is not None:
        idx = idx[:max_events]
    if len(idx) < min_events:
        raise SpinInputError(f"events: only {len(idx)} events inside the circle, need at least {min_events}")
    if thin_to is not None and len(idx) > thin_to:
        idx = idx[::-(-len(idx) // thin_to)]
    s = s[idx]
    x = x[idx]
    y = y[idx]
    if dither:
        jitter = _jitter_px(len(idx))
        x += jitter[0]
        y += jitter[1]
    # gathers from plain arrays (a structured-array gather costs as much as all the rest)
    ball = BallEvents(x, y, s, f32(0.5) * (s[0] + s[-1]) - s,
                      2 * events["p"][idx].astype(f32) - 1, r)
    return ball, t_us[idx]


def velocity_from_centroids(events, center, radius_px: float, *, t0_us=None, n_slices: int = 8,
                            iterations: int = 3) -> np.ndarray:
    """Rough image velocity (px/s) of a ball from the drift of its events' centroid.

    Used when no tracker prior is given: events within ``1.5 r`` of the moving
    centre are split into ``n_slices`` time slices; a line fitted to the slice
    centroids gives ``v``; repeated ``iterations`` times with the updated centre
    motion and a tighter circle.
    """
    t = events["t"]
    t0 = int(t[0]) if t0_us is None else int(t0_us)
    s = (t - t0).astype(np.float64) * 1e-6
    x = events["x"].astype(np.float64)
    y = events["y"].astype(np.float64)
    v = np.zeros(2)
    for k in range(iterations):
        reach = radius_px * (1.5 if k == 0 else 1.1)
        keep = (x - center[0] - v[0] * s) ** 2 + (y - center[1] - v[1] * s) ** 2 <= reach * reach
        if keep.sum() < 2 * n_slices:
            break
        slices = np.array_split(np.flatnonzero(keep), n_slices)
        ts = np.array([s[i].mean() for i in slices])
        if np.ptp(ts) <= 0:
            break
        cx = np.array([x[i].mean() for i in slices])
        cy = np.array([y[i].mean() for i in slices])
        v = np.array([np.polyfit(ts, cx, 1)[0], np.polyfit(ts, cy, 1)[0]])
    return v


def estimate_spin(events, center, radius, *, t0_us=None, velocity=None, method: str = "fast",
                  sensor_size=None, min_events: int = 200, **opts) -> SpinEstimate:
    """Estimate the ball's spin from its events by contrast maximisation.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Time-sorted events (others are ignored: only those inside the moving circle are used).
    center : (float, float)
        Ball centre in px at ``t0_us``.
    radius : float
        Ball radius in px.
    t0_us : int, optional
        Time of ``center``, µs; default the first event's time.
    velocity : (float, float), optional
        Prior image velocity of the centre, px/s (from the tracker).  Without it a
        rough one comes from the drift of the events' centroid
        (:func:`velocity_from_centroids`) and is refined; confidence is then lower
        for spin axes in the image plane on short windows.
    method : {"fast", "paper"}
        ``"fast"`` (default): coarse search + coarse-to-fine BFGS (:mod:`spin.fast`).
        ``"paper"``: the seed paper's joint Adam ascent (:mod:`spin.paper`).
    sensor_size : (int, int), optional
        ``(width, height)`` to check the circle against.
    min_events : int
        Fewest events inside the circle accepted.
    **opts
        Passed to :func:`spin.fast.estimate_fast` or :func:`spin.paper.estimate_paper`
        (``paper`` also takes ``max_events``, default 50,000, and ``init_w_rad_s``; ``fast``
        takes ``thin_to``, default ``spin.fast.FAST_EVENTS`` = 24,000: more events inside the
        circle are thinned evenly to at most that many).

    Raises
    ------
    SpinInputError
        Bad events, circle outside the sensor, no or too few events inside the circle.
    """
    if method not in ("fast", "paper"):
        raise SpinInputError(f"method: {method!r} is not 'fast' or 'paper'")
    known = velocity is not None
    if velocity is None:
        _check_events(events)
        v0 = velocity_from_centroids(events, center, radius, t0_us=t0_us) if len(events) else np.zeros(2)
    else:
        v0 = np.asarray(velocity, dtype=np.float64).reshape(2)
    if method == "fast":
        ev, t_sel = prepare(events, center, radius, t0_us=t0_us, velocity_px_s=v0, rim_fraction=0.95,
                          max_events=opts.pop("max_events", None), min_events=min_events, sensor_size=sensor_size,
                          dither=True, thin_to=opts.pop("thin_to", FAST_EVENTS))
        res = estimate_fast(ev, v0, velocity_known=known, **opts)
        w, v, value, converged, confidence = res.w_rad_s, res.v_px_s, res.contrast, res.converged, res.confidence
        sigmas = {"axis_sigma_deg": res.axis_sigma_deg, "rps_sigma_pct": res.rps_sigma_pct}
    else:
        ev, t_sel = prepare(events, center, radius, t0_us=t0_us, velocity_px_s=v0, rim_fraction=1.0,
                          max_events=opts.pop("max_events", PAPER_EVENTS), min_events=min_events,
                          sensor_size=sensor_size)
        w0 = opts.pop("init_w_rad_s", None)
        if w0 is None:
            omegas, dirs, scores = coarse_search(ev, v0, omega_min_rad_s=2 * np.pi * 3.0,
                                                 omega_max_rad_s=2 * np.pi * 1500.0)
            w0 = distinct_candidates(omegas, dirs, scores, 1)[0]
        res = estimate_paper(ev, w0, v0, **opts)
        w, v, value, converged = res.w_rad_s, res.v_px_s, res.contrast, res.converged
        # the paper gives no quality figure: use the contrast gain over no rotation
        still = contrast(ev, np.zeros(3), v, IweGeometry(ev.radius_px), gradient=False)
        confidence = float(np.clip((1.0 - still / max(value, 1e-30)) / 0.3, 0.0, 1.0))
        sigmas = {}
    omega = float(np.linalg.norm(w))
    axis = w / omega if omega > 0 else np.array([0.0, 0.0, 1.0])
    return SpinEstimate(axis=axis, omega_rad_s=omega, rps=omega / (2 * np.pi), velocity_px_s=np.asarray(v),
                        t_start_us=int(t_sel[0]), t_end_us=int(t_sel[-1]) + 1, n_events=len(t_sel),
                        contrast=float(value), converged=bool(converged), confidence=float(confidence),
                        method=method, **sigmas)


def estimate_windows(windows: Iterable, *, method: str = "fast", skip_errors: bool = True,
                     warm_start: bool = True, **opts) -> list[SpinEstimate]:
    """One estimate per :class:`detect.track.SpinWindow` (centre at the window start, the track's velocity).

    Windows whose events cannot give an estimate (:class:`SpinInputError`) are
    skipped when ``skip_errors`` (default), else the error propagates.  With
    ``warm_start`` (fast method), a window that follows a trusted estimate (confidence
    >= 0.5) of the same flight within ``WARM_GAP_US`` starts from it: it joins the
    candidates and the coarse search keeps to speeds within a factor 2.2 of it
    (``spin.fast.estimate_fast``'s ``prior_w_rad_s``); spin barely changes in flight.
    """
    out = []
    previous = None  # (flight, window end µs, estimate) of the last estimate
    for win in windows:
        kw = dict(opts)
        if (method == "fast" and warm_start and previous is not None and previous[0] == win.flight
                and 0 <= win.t_start_us - previous[1] <= WARM_GAP_US and previous[2].confidence >= 0.5):
            kw.setdefault("prior_w_rad_s", previous[2].axis * previous[2].omega_rad_s)
        try:
            est = estimate_spin(win.events, win.center, win.radius_px, t0_us=win.t_start_us,
                                velocity=win.velocity_px_s, method=method, **kw)
        except SpinInputError:
            if not skip_errors:
                raise
            continue
        out.append(est)
        previous = (win.flight, win.t_end_us, est)
    return out
