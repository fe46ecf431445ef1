"""Public entry points: one estimate from events and a circle, or one per track window."""

from __future__ import annotations

import threading
from collections.abc import Iterable
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from threadpoolctl import ThreadpoolController

from spin import lens, pixel_lag
from spin.fast import FAST_EVENTS, NARROW_SEARCH, estimate_fast
from spin.objective import BallEvents, IweGeometry, contrast
from spin.paper import PAPER_EVENTS, estimate_paper
from spin.search import coarse_search, distinct_candidates


WARM_GAP_US = 50_000  # longest gap between windows of a flight across which an estimate seeds the next
# The circle's uncertainty (``circle_sigma_px``, 1 sigma) in the spin's: the rate (%) and the axis (deg) move this
# much per % of the radius that the circle's radius or centre is off.  On the spin benchmark's dense textures (seeds
# 0-1, started from the truth) the radius 2 % off moved the rate 1.0 % at the median, 1.75 % at the 90th percentile,
# and the centre 3 % of the radius off moved the axis 1.7 deg at the median, 3 deg at the 90th.  Through the tracker
# (simulated volleyball and soccer flights, r 10-36 px, seeds 1-2) the rate came out 1.2-4.6 % low, 1.4-1.8 times
# the radius's +0.3 px bias in %: 1.5 left 2 of 576 windows trusted and wrong (1.2: 4; none: 30)
CIRCLE_RATE_PER_PCT, CIRCLE_AXIS_DEG_PER_PCT = 1.5, 0.8
# ... and a window is trusted in full while the circle alone gives the rate at most this 1 sigma (%), not at all from
# the second (2 sigma of it would reach the 5 % that trust stands for)
CIRCLE_TRUST_FULL_PCT, CIRCLE_TRUST_ZERO_PCT = 1.5, 2.5


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
        IWE variance at the estimate (method-specific scale; before the rate's lag correction).
    converged : bool
        Whether the optimiser met its convergence test.
    confidence : float
        0..1; low when the contrast barely beats no rotation, when a distinct rival
        solution (other axis or aliased omega) is almost as good, when the window
        covers little rotation, when little of the ball's rim fires, when the
        events come in bursts (a strobe: aliased spins align them equally well), or when
        the ball's circle is known too roughly (``circle_sigma_px``: :func:`with_circle_sigma`).
    method : str
        ``"fast"`` or ``"paper"``.
    axis_sigma_deg, rps_sigma_pct : float
        Uncertainty (1 sigma) of the axis (deg) and of the rate (% of ``rps``), from the
        spread of the estimates on the two halves of the events and, for the rate, the trails the
        sensor's lag leaves behind the ball's texture (``spin.fast.estimate_fast``,
        :mod:`spin.pixel_lag`); a rate of one turn per period of the image (:mod:`spin.period`,
        windows of several turns) has no lag term and a lower floor; for a ball whose image drifts
        faster than its rim turns, how far the answer was moved to the contrast's peak without blur
        (``spin.fast.BLUR_SHIFT_FROM_DRIFT``); with the circle's uncertainty given, its share too
        (:func:`with_circle_sigma`); NaN for ``method="paper"``.
    rps_lag_pct : float
        The part of ``rps_sigma_pct`` from the sensor's lag (% of ``rps``, 1 sigma, in quadrature
        with the rest): a bias that the windows of a flight share, so averaging them does not
        shrink it; NaN for ``method="paper"``.
    flight : int
        Flight number (:class:`capture.events.Track`) of the window the events came from; -1 when
        they came from no track.
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
    rps_lag_pct: float = float("nan")
    flight: int = -1


_BLAS_LOCK = threading.Lock()
_blas_users = 0  # estimates running (in any thread) while BLAS is held at one thread
_blas_limiter = None


@contextmanager
def _one_blas_thread():
    """BLAS held at one thread while any estimate runs, in whichever thread (the setting is the whole
    process's: the first estimate to start sets it, the last to end gives the threads back).  An estimate's
    matrix products are small, and BLAS's other threads only spin: on 2 cores an estimate took 79 ms of the
    process's CPU against 40 ms on one thread, and the second core from whatever else ran there.  The BLAS
    libraries are those loaded at the first estimate (NumPy's)."""
    global _blas_users, _blas_limiter
    with _BLAS_LOCK:
        if _blas_users == 0:
            _blas_limiter = _blas().limit(limits=1, user_api="blas")
        _blas_users += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _blas_users -= 1
            if _blas_users == 0:
                _blas_limiter.restore_original_limits()


@lru_cache(maxsize=1)
def _blas() -> ThreadpoolController:
    """The BLAS libraries loaded, found once (their list takes milliseconds to make; a limit on it 6 us)."""
    return ThreadpoolController()


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


def _check_circle(center, radius_px, sensor_size) -> tuple[float, float, float]:
    """``(cx, cy, r)`` as floats, or :class:`SpinInputError` for a bad circle or one off the sensor."""
    cx, cy = (float(c) for c in np.reshape(np.asarray(center, dtype=np.float64), 2))
    r = float(radius_px)
    if not (np.isfinite(cx) and np.isfinite(cy) and np.isfinite(r)) or r <= 2.0:
        raise SpinInputError(f"circle: centre ({cx}, {cy}) and radius {r} px must be finite with radius > 2 px")
    w, h = sensor_size if sensor_size is not None else (65536, 65536)
    if cx + r < 0 or cy + r < 0 or cx - r > w - 1 or cy - r > h - 1:
        raise SpinInputError(f"circle: centre ({cx:.1f}, {cy:.1f}) radius {r:.1f} px lies outside the sensor "
                             f"{w}x{h}")
    return cx, cy, r


def _check_camera(camera, events, sensor_size) -> None:
    """:class:`SpinInputError` unless ``camera`` is a usable pinhole camera of the events' sensor."""
    k = np.asarray(getattr(camera, "K", None), dtype=np.float64)
    dist = np.ravel(np.asarray(getattr(camera, "dist", ()), dtype=np.float64))
    if k.shape != (3, 3) or not np.isfinite(k).all() or not np.isfinite(dist).all():
        raise SpinInputError("camera: K must be a finite 3x3 matrix and dist finite")
    if k[0, 0] <= 0 or k[1, 1] <= 0 or np.linalg.cond(k) > 1e12:
        raise SpinInputError(f"camera: K {k.tolist()} is not invertible with positive focal lengths")
    if len(dist) not in (0, 4, 5, 8, 12, 14):
        raise SpinInputError(f"camera: {len(dist)} distortion coefficients (OpenCV takes 4, 5, 8, 12 or 14)")
    size = (int(camera.width), int(camera.height))
    if min(size) <= 0:
        raise SpinInputError(f"camera: size {size[0]}x{size[1]} px must be positive")
    if sensor_size is not None and tuple(int(v) for v in sensor_size) != size:
        raise SpinInputError(f"camera: size {size[0]}x{size[1]} px differs from the sensor size "
                             f"{sensor_size[0]}x{sensor_size[1]}")
    if len(events) and (int(events["x"].max()) >= size[0] or int(events["y"].max()) >= size[1]):
        raise SpinInputError(f"camera: events reach pixel ({int(events['x'].max())}, {int(events['y'].max())}), "
                             f"outside the camera's {size[0]}x{size[1]} px")


def _keep(idx: np.ndarray, max_events: int | None, min_events: int, thin_to: int | None,
          circle: tuple[float, float, float]) -> np.ndarray:
    """The selected events ``idx`` (time order) after ``max_events`` and ``thin_to``, checked for ``min_events``."""
    if len(idx) == 0:
        raise SpinInputError("circle: no events inside the circle centre ({:.1f}, {:.1f}) radius {:.1f} px"
                             .format(*circle))
    if max_events is not None:
        idx = idx[:max_events]
    if len(idx) < min_events:
        raise SpinInputError(f"events: only {len(idx)} events inside the circle, need at least {min_events}")
    if thin_to is not None and len(idx) > thin_to:
        idx = idx[::-(-len(idx) // thin_to)]
    return idx


def prepare(events, center, radius_px: float, *, t0_us=None, velocity_px_s=(0.0, 0.0), rim_fraction: float = 1.0,
            max_events: int | None = None, min_events: int = 200, sensor_size=None,
            dither: bool = False, thin_to: int | None = None,
            view: lens.BallView | None = None) -> tuple[BallEvents, np.ndarray]:
    """Select the events inside the moving circle and express them for warping.

    Returns the :class:`BallEvents` (float32; ``t_ref`` at the middle of the
    selected events) and the selected events' times (int64 µs, (N,)).  Raises
    :class:`SpinInputError` naming the problem.

    Without ``view`` (orthographic camera), the events' coordinates are pixels relative to
    ``center`` and the radius is ``radius_px``.  With a :class:`spin.lens.BallView` (the ball
    as a calibrated camera sees it, see :func:`spin.lens.ball_view`), they are the ball-frame
    coordinates of :func:`spin.lens.ball_coordinates` (ball units, the ball's centre moving
    with ``velocity_px_s`` in the image; give the estimator a zero velocity) and the radius is
    ``view.radius``; the events kept are those whose rays meet the ball within
    ``rim_fraction`` of the silhouette's radius in ball coordinates.

    With ``dither``, each event's position is spread uniformly over its pixel (a fixed
    pseudo-random draw, so results repeat): events sit on the integer pixel lattice,
    and an IWE of sharp, bilinearly voted events scores warps that keep slow-moving
    events on that lattice higher than it should, which pulls the estimate (by several
    degrees for axes near the image plane on windows of a few degrees' rotation).

    With ``thin_to``, more events inside the circle (after ``max_events``) keep every k-th
    (the fewest k leaving at most ``thin_to``).
    """
    events = _check_events(events)
    cx, cy, r = _check_circle(center, radius_px, sensor_size)
    if len(events) == 0:
        raise SpinInputError("events: empty array")
    if thin_to is not None and thin_to < 1:
        raise SpinInputError(f"thin_to: {thin_to} must be at least 1")
    t_us = np.ascontiguousarray(events["t"])  # one pass over the records; the rest reads plain arrays
    if (t_us[1:] < t_us[:-1]).any():
        order = np.argsort(t_us, kind="stable")
        events, t_us = events[order], t_us[order]
    t0 = int(t_us[0]) if t0_us is None else int(t0_us)
    if view is not None:
        return _prepare_view(events, t_us, t0, (cx, cy, r), view, velocity_px_s, rim_fraction, max_events,
                             min_events, dither, thin_to)
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
    idx = _keep(np.flatnonzero(dx <= f32(rim * rim)), max_events, min_events, thin_to, (cx, cy, r))
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


def _prepare_view(events, t_us, t0: int, circle: tuple[float, float, float], view: lens.BallView,
                  velocity_px_s, rim_fraction: float, max_events, min_events: int, dither: bool,
                  thin_to) -> tuple[BallEvents, np.ndarray]:
    """:func:`prepare` for a ball seen through a camera (``view``): events in ball coordinates.

    Events within the silhouette's reach (``view.reach_px`` plus a dithered event's reach) of
    the moving circle's centre are candidates; with ``dither`` each is spread over its pixel
    before it is mapped, and those mapped within ``rim_fraction`` of the silhouette are kept.
    """
    cx, cy, _ = circle
    vx, vy = (float(c) for c in velocity_px_s)
    s = (t_us - t0) * 1e-6
    x = events["x"].astype(np.float64)  # plain arrays: gathers from the records cost more than the rest
    y = events["y"].astype(np.float64)
    dx = x - (cx + vx * s)
    dy = y - (cy + vy * s)
    reach = view.reach_px + _JITTER_REACH_PX
    near = np.flatnonzero(dx * dx + dy * dy <= reach * reach)
    uv = np.empty((len(near), 2))
    uv[:, 0] = x[near]
    uv[:, 1] = y[near]
    if dither:
        uv += _jitter_px(len(near)).T
    xy, hit = lens.ball_coordinates(view, uv, s[near], (vx, vy))
    rim = rim_fraction * view.rim_radius
    pos = _keep(np.flatnonzero(hit & (xy[0] * xy[0] + xy[1] * xy[1] <= rim * rim)), max_events, min_events,
                thin_to, circle)
    idx = near[pos]
    f32 = np.float32
    s = (t_us[idx] - t0).astype(f32)
    s *= f32(1e-6)
    ball = BallEvents(xy[0, pos].astype(f32), xy[1, pos].astype(f32), s, f32(0.5) * (s[0] + s[-1]) - s,
                      2 * events["p"][idx].astype(f32) - 1, view.radius)
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


def with_circle_sigma(est: SpinEstimate, radius_px: float, circle_sigma_px: float | None) -> SpinEstimate:
    """``est`` with the uncertainty of the ball's circle (``circle_sigma_px``, 1 sigma, px, of its centre
    and radius; None or NaN: not known, ``est`` as it is) in its own.

    A radius that is off by some % of itself lifts the events onto a sphere of the wrong size, which
    moves the rate by about as many %; a centre off by some % of the radius tilts the axis. These
    shares (:data:`CIRCLE_RATE_PER_PCT`, :data:`CIRCLE_AXIS_DEG_PER_PCT` per % of the radius) are added
    in quadrature to ``rps_sigma_pct`` and ``axis_sigma_deg``, and the confidence falls to none as the
    circle's share of the rate's sigma grows from :data:`CIRCLE_TRUST_FULL_PCT` to
    :data:`CIRCLE_TRUST_ZERO_PCT`: a window whose circle alone may put the rate 5 % off is not
    trusted however sharp its image.
    """
    if circle_sigma_px is None or not np.isfinite(circle_sigma_px):
        return est
    rel_pct = 100.0 * float(circle_sigma_px) / float(radius_px)
    rate_pct, axis_deg = CIRCLE_RATE_PER_PCT * rel_pct, CIRCLE_AXIS_DEG_PER_PCT * rel_pct
    trust = float(np.clip((CIRCLE_TRUST_ZERO_PCT - rate_pct) / (CIRCLE_TRUST_ZERO_PCT - CIRCLE_TRUST_FULL_PCT),
                          0.0, 1.0))
    return replace(est, confidence=est.confidence * trust, axis_sigma_deg=float(np.hypot(est.axis_sigma_deg, axis_deg)),
                   rps_sigma_pct=float(np.hypot(est.rps_sigma_pct, rate_pct)))


def estimate_spin(events, center, radius, *, t0_us=None, velocity=None, method: str = "fast",
                  sensor_size=None, min_events: int = 200, camera=None, circle: str = "detected",
                  circle_sigma_px: float | None = None, **opts) -> SpinEstimate:
    """Estimate the ball's spin from its events by contrast maximisation.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Time-sorted events (others are ignored: only those inside the moving circle are used).
    center : (float, float)
        Centre of the ball's circle in the image at ``t0_us``, px.
    radius : float
        Radius of the ball's circle, px.  Without ``camera`` the image is taken as an
        orthographic view of the ball, whose silhouette is this circle.  With ``camera``, see
        ``circle``.
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
        ``(width, height)`` to check the circle against (default: the camera's size, if any).
    min_events : int
        Fewest events inside the circle accepted.
    camera : calib.Intrinsics, optional
        The event camera's intrinsics (pinhole ``K`` and OpenCV distortion ``dist``, px): the
        ball is then seen in perspective, through the distorting lens (:mod:`spin.lens`),
        which matters for balls off the optical axis.  ``None``: orthographic camera.
    circle : {"detected", "projected"}
        With ``camera``, what ``(center, radius)`` is.  ``"detected"`` (default): the circle
        fitted to the ball's silhouette in the (distorted) image, as the detector and the
        track report it; off the optical axis the silhouette is an ellipse, and the circle is
        turned into the ball's viewing cone (:func:`spin.lens.viewing_cone`).
        ``"projected"``: ``center`` is the image of the ball's centre and
        ``radius = f tan(alpha)`` (``f`` the camera's mean focal length in px, ``alpha`` the
        ball's angular radius), as ``sim`` reports its pinhole truth.
    circle_sigma_px : float, optional
        Uncertainty (1 sigma, px) of ``center`` and ``radius`` (the track's ``sigma_px``): taken into
        the estimate's uncertainty and confidence (:func:`with_circle_sigma`). None or NaN: the circle
        is taken as exact.
    **opts
        Passed to :func:`spin.fast.estimate_fast` or :func:`spin.paper.estimate_paper`
        (``paper`` also takes ``max_events``, default 50,000, and ``init_w_rad_s``; ``fast``
        takes ``thin_to``, default ``spin.fast.FAST_EVENTS`` = 24,000: more events inside the
        circle are thinned evenly to at most that many).  Angular velocities among them
        (``prior_w_rad_s``, ``init_w_rad_s``) are in the camera frame.

    Returns
    -------
    SpinEstimate
        Axis in the camera frame; ``velocity_px_s`` is the image velocity of the circle's centre.

    Raises
    ------
    SpinInputError
        Bad events, non-finite numbers, circle outside the sensor, no or too few events inside
        the circle, a camera whose ``K`` is not invertible or whose size does not match the
        events or ``sensor_size``.

    Notes
    -----
    While any estimate runs, the process's BLAS is held at one thread (its setting is the whole
    process's; it is given back when the last estimate ends): the estimate's matrix products are small,
    and more BLAS threads only spin on the other cores.
    """
    if method not in ("fast", "paper"):
        raise SpinInputError(f"method: {method!r} is not 'fast' or 'paper'")
    if t0_us is not None and not np.isfinite(t0_us):
        raise SpinInputError(f"t0_us: {t0_us} is not finite")
    known = velocity is not None
    if velocity is None:
        _check_events(events)
        v0 = velocity_from_centroids(events, center, radius, t0_us=t0_us) if len(events) else np.zeros(2)
    else:
        v0 = np.asarray(velocity, dtype=np.float64).reshape(2)
        if not np.isfinite(v0).all():
            raise SpinInputError(f"velocity: ({v0[0]}, {v0[1]}) px/s is not finite")
    view = None
    v_fit = v0  # the velocity the estimator starts from: px/s, or ball units/s with a camera
    if camera is not None:
        _check_camera(camera, _check_events(events), sensor_size)
        sensor_size = (int(camera.width), int(camera.height))
        if circle not in lens.CIRCLES:
            raise SpinInputError(f"circle: {circle!r} is not one of {lens.CIRCLES}")
        try:
            view = lens.ball_view(camera, _check_circle(center, radius, sensor_size)[:2], float(radius), circle)
        except ValueError as exc:
            raise SpinInputError(str(exc)) from None
        v_fit = np.zeros(2)  # the ball's centre follows v0 in ball coordinates
        for name in ("prior_w_rad_s", "init_w_rad_s"):
            if opts.get(name) is not None:
                opts[name] = view.to_ball(opts[name])
    with _one_blas_thread():
        w, v, value, converged, confidence, sigmas, t_sel = _estimate(events, center, radius, t0_us, v0, v_fit, known,
                                                                      method, sensor_size, min_events, view, opts)
    if view is not None:
        w = view.to_camera(w)
        v = v0 + view.to_px_s(v)
    omega = float(np.linalg.norm(w))
    axis = w / omega if omega > 0 else np.array([0.0, 0.0, 1.0])
    est = SpinEstimate(axis=axis, omega_rad_s=omega, rps=omega / (2 * np.pi), velocity_px_s=np.asarray(v),
                       t_start_us=int(t_sel[0]), t_end_us=int(t_sel[-1]) + 1, n_events=len(t_sel),
                       contrast=float(value), converged=bool(converged), confidence=float(confidence),
                       method=method, **sigmas)
    return with_circle_sigma(est, radius, circle_sigma_px)


def _estimate(events, center, radius, t0_us, v0, v_fit, known: bool, method: str, sensor_size, min_events: int,
              view, opts: dict):
    """The estimate of :func:`estimate_spin` once its inputs are checked: ``(w, v, contrast, converged,
    confidence, sigmas, t_sel)`` in the estimator's frame (the ball's with a ``view``)."""
    if method == "fast":
        ev, t_sel = prepare(events, center, radius, t0_us=t0_us, velocity_px_s=v0, rim_fraction=0.95,
                          max_events=opts.pop("max_events", None), min_events=min_events, sensor_size=sensor_size,
                          dither=True, thin_to=opts.pop("thin_to", FAST_EVENTS), view=view)
        pairs = pixel_lag.bursts(events, center, radius, t0_us=int(events["t"].min()) if t0_us is None else t0_us,
                                 velocity_px_s=v0, view=view)
        res = estimate_fast(ev, v_fit, velocity_known=known, bursts=pairs,
                            drift_radii_s=float(np.hypot(*v0)) / float(radius), **opts)
        w, v, value, converged, confidence = res.w_rad_s, res.v_px_s, res.contrast, res.converged, res.confidence
        sigmas = {"axis_sigma_deg": res.axis_sigma_deg, "rps_sigma_pct": res.rps_sigma_pct,
                  "rps_lag_pct": res.rps_lag_pct}
    else:
        ev, t_sel = prepare(events, center, radius, t0_us=t0_us, velocity_px_s=v0, rim_fraction=1.0,
                          max_events=opts.pop("max_events", PAPER_EVENTS), min_events=min_events,
                          sensor_size=sensor_size, view=view)
        w0 = opts.pop("init_w_rad_s", None)
        if w0 is None:
            omegas, dirs, scores = coarse_search(ev, v_fit, omega_min_rad_s=2 * np.pi * 3.0,
                                                 omega_max_rad_s=2 * np.pi * 1500.0)
            w0 = distinct_candidates(omegas, dirs, scores, 1)[0]
        res = estimate_paper(ev, w0, v_fit, **opts)
        w, v, value, converged = res.w_rad_s, res.v_px_s, res.contrast, res.converged
        # the paper gives no quality figure: use the contrast gain over no rotation
        still = contrast(ev, np.zeros(3), v, IweGeometry(ev.radius_px), gradient=False)
        confidence = float(np.clip((1.0 - still / max(value, 1e-30)) / 0.3, 0.0, 1.0))
        sigmas = {}
    return w, v, value, converged, confidence, sigmas, t_sel


def estimate_windows(windows: Iterable, *, method: str = "fast", skip_errors: bool = True,
                     warm_start: bool = True, camera=None, circle: str = "detected",
                     **opts) -> list[SpinEstimate]:
    """One estimate per :class:`detect.track.SpinWindow` (centre at the window start, the track's velocity).

    Windows whose events cannot give an estimate (:class:`SpinInputError`) are
    skipped when ``skip_errors`` (default), else the error propagates.  With
    ``warm_start`` (fast method), a window that follows a trusted estimate (confidence
    >= 0.5) of the same flight within ``WARM_GAP_US`` starts from it: it joins the
    candidates, the coarse search keeps to speeds within a factor 2.2 of it
    (``spin.fast.estimate_fast``'s ``prior_w_rad_s``) and the search takes fewer starts
    (``spin.fast.NARROW_SEARCH``); spin barely changes in flight.
    ``camera`` (``calib.Intrinsics`` of the event camera, or ``None``: orthographic) and
    ``circle`` (the track's circles are the detector's: ``"detected"``) go to
    :func:`estimate_spin`, as do the other options. Each window's ``sigma_px`` (the track's circle
    uncertainty) goes into its estimate (:func:`with_circle_sigma`); whether an estimate seeds the
    next window is decided on its confidence before that (the circle does not make it a worse start).
    """
    if "circle_sigma_px" in opts:
        raise TypeError("estimate_windows takes each window's circle sigma from the window (SpinWindow.sigma_px), "
                        "not circle_sigma_px")
    out = []
    previous = None  # (flight, window end µs, estimate) of the last estimate
    for win in windows:
        kw = dict(opts)
        if (method == "fast" and warm_start and previous is not None and previous[0] == win.flight
                and 0 <= win.t_start_us - previous[1] <= WARM_GAP_US and previous[2].confidence >= 0.5):
            kw.setdefault("prior_w_rad_s", previous[2].axis * previous[2].omega_rad_s)
            for name, value in NARROW_SEARCH.items():  # the prior is a start: the narrow search suffices
                kw.setdefault(name, value)
        try:
            est = estimate_spin(win.events, win.center, win.radius_px, t0_us=win.t_start_us,
                                velocity=win.velocity_px_s, method=method, camera=camera, circle=circle, **kw)
        except SpinInputError:
            if not skip_errors:
                raise
            continue
        previous = (win.flight, win.t_end_us, est)
        sigma = getattr(win, "sigma_px", None)
        out.append(replace(with_circle_sigma(est, win.radius_px, sigma), flight=int(win.flight)))
    return out
