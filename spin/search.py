"""Global initialisation: coarse search over spin axis directions and angular speed.

For each angular speed on a log grid, the events nearest to ``t_ref`` spanning a
fixed rotation angle ``span_rad`` are warped for every axis direction of a
Fibonacci sphere grid at once (exact rotation, broadcast over events x directions)
into small stacked IWEs; their variances form a score table over (omega, axis).
Limiting the rotation angle makes the grid spacing needed independent of omega.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from spin import _kernels
from spin.objective import BallEvents, IweGeometry, blur


@lru_cache(maxsize=8)
def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` nearly uniform unit vectors, shape (n, 3) (read-only: one array shared between calls)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    rho = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    grid = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    grid.flags.writeable = False
    return grid


def _span_bounds(ev: BallEvents, half_span_s):
    """Index range(s) ``[lo, hi)`` of the time-sorted events with ``|tau| <= half_span_s``."""
    t_ref = ev.s_s[0] + ev.tau_s[0]
    h = np.asarray(half_span_s, dtype=ev.s_s.dtype)
    return np.searchsorted(ev.s_s, t_ref - h, side="left"), np.searchsorted(ev.s_s, t_ref + h, side="right")


def _span_rows(ev: BallEvents, omegas_rad_s, span_rad: float, n_events: int) -> np.ndarray:
    """Indices (M, n) of :func:`events_for_span`'s events for each of the speeds ``omegas_rad_s`` (M,)."""
    lo, hi = _span_bounds(ev, 0.5 * span_rad / np.maximum(np.asarray(omegas_rad_s, dtype=np.float64), 1e-9))
    n_all = len(ev)
    n = min(n_events, n_all)
    k = np.arange(n)
    mid = int(np.searchsorted(ev.s_s, ev.s_s[0] + ev.tau_s[0]))
    block = min(max(mid - n_events // 2, 0), max(n_all - n_events, 0)) + k
    # evenly spread over [lo, hi - 1], both ends included (exact integer arithmetic)
    spread = lo[:, None] + (k * (hi - 1 - lo)[:, None]) // max(n - 1, 1)
    return np.where((hi - lo > n_events)[:, None], spread, block)


def events_for_span(ev: BallEvents, omega_rad_s: float, span_rad: float, n_events: int) -> BallEvents:
    """At most ``n_events`` events around ``t_ref`` covering about ``span_rad`` of rotation.

    ``ev`` must be time-sorted.  Takes the events with ``|tau| <= span/(2 omega)``
    (a contiguous block), evenly subsampled to ``n_events``; where that span holds
    fewer, the block of ``n_events`` centred on ``t_ref``.
    """
    return ev.take(_span_rows(ev, [omega_rad_s], span_rad, n_events)[0])


def _lift_rows(ev: BallEvents, index: np.ndarray, velocity_px_s, dtype=np.float32):
    """Lifted points (N, R, 3), ``tau`` and weights (N, R) of the events ``index`` (R, N)."""
    x, y, s = (a[index].T for a in (ev.x_px, ev.y_px, ev.s_s))
    vx, vy = (s.dtype.type(c) for c in velocity_px_s)
    pts = np.empty((*x.shape, 3), dtype=dtype)
    dx = np.subtract(x, vx * s, out=pts[..., 0])
    dy = np.subtract(y, vy * s, out=pts[..., 1])
    r2 = ev.radius_px * ev.radius_px
    np.negative(np.sqrt(np.maximum(r2 - dx * dx - dy * dy, 0.01 * r2)), out=pts[..., 2])
    return pts, ev.tau_s[index].T.astype(dtype), ev.weight[index].T.astype(np.float32)


def direction_matrix(directions: np.ndarray, geometry: IweGeometry) -> np.ndarray:
    """Matrix (10, C (D + 1)), float32, that takes an event's features ``(sin(phi) p, (1 - cos(phi)) p, p,
    1)`` to its IWE coordinates u, v (and z with ``geometry.hemispheres``: C = 3) turned about each of
    ``directions`` (D, 3) and without rotation (the last column), scaled to IWE pixels and offset to the
    raster, with the half pixel that makes truncation round.

    ``q = p + sin(phi) n x p + (1 - cos(phi)) (n (n . p) - p)`` is linear in those features.
    """
    n = np.asarray(directions, dtype=np.float64)
    d = len(n)
    zero = np.zeros_like(n[:, 0])
    cross = (np.stack([zero, -n[:, 2], n[:, 1]]), np.stack([n[:, 2], zero, -n[:, 0]]),
             np.stack([-n[:, 1], n[:, 0], zero]))
    eye = np.eye(3)
    comps = (0, 1, 2) if geometry.hemispheres else (0, 1)
    mats = np.zeros((10, len(comps), d + 1))
    for i, k in enumerate(comps):
        mats[0:3, i, :d] = cross[k]
        mats[3:6, i, :d] = n.T * n[:, k][None, :] - eye[:, k:k + 1]
        mats[6 + k, i, :] = 1.0
    mats[:9] *= geometry.scale
    mats[9, :2] = geometry.radius_px * geometry.scale + geometry.pad + 0.5
    return mats.reshape(10, -1).astype(np.float32)


def score_rows(pts: np.ndarray, tau_s: np.ndarray, weight: np.ndarray, omegas_rad_s: np.ndarray,
               matrix: np.ndarray, geometry: IweGeometry) -> np.ndarray:
    """IWE variance for angular velocities ``omega_r * direction_d`` and for no rotation; returns (R, D + 1).

    Row ``r`` (speed ``omegas_rad_s[r]``) uses the lifted events ``pts[:, r]`` ((N, R, 3), times
    ``tau_s`` (N, R), weights (N, R)); ``matrix`` is :func:`direction_matrix` of the D directions.
    Exact rotation of events x rows x directions as one matrix product, nearest-pixel voting into
    small IWEs side by side (:func:`spin._kernels.vote_nearest`; enough at this resolution: the blur
    does the rest); the last column is the variance without rotation.
    """
    dt = np.float32
    phi = tau_s * np.asarray(omegas_rad_s, dtype=dt)[None, :]  # (N, R)
    n_ev, r = phi.shape
    feat = np.empty((n_ev, r, 10), dtype=dt)
    np.multiply(np.sin(phi)[:, :, None], pts, out=feat[:, :, 0:3])
    np.multiply((1 - np.cos(phi))[:, :, None], pts, out=feat[:, :, 3:6])
    feat[:, :, 6:9] = pts
    feat[:, :, 9] = 1.0
    comps = 3 if geometry.hemispheres else 2
    q = np.matmul(feat.reshape(n_ev * r, 10), matrix).reshape(n_ev, r, comps, -1)
    images = r * q.shape[3]
    h, width = geometry.shape
    # the IWEs side by side in one raster (the blur then runs along long rows: 3x faster than IWEs
    # stacked on top of each other); their margins keep neighbours apart
    img = _kernels.vote_nearest(q, np.ascontiguousarray(weight), geometry.hemispheres, geometry.size, h, width)
    img = blur(img, geometry.sigma, geometry.truncate)
    n_px = h * width
    ones = np.ones(h, dtype=np.float32)
    mean = (ones @ img).reshape(images, width).sum(axis=1) / n_px  # column sums as one product; float32: ample
    np.multiply(img, img, out=img)
    var = (ones @ img).reshape(images, width).sum(axis=1) / n_px - mean * mean
    return var.reshape(r, -1)


def coarse_search(ev: BallEvents, velocity_px_s, *, omega_min_rad_s: float, omega_max_rad_s: float,
                  omega_ratio: float = 1.6, n_directions: int = 40, span_rad: float = 0.6,
                  n_events: int = 200, iwe_radius_px: float = 10.0, sigma: float = 1.0,
                  truncate: float = 2.0, hemispheres: bool = False, rows_per_call: int = 8,
                  min_rotation_rad: float = 0.1, extra_omegas_rad_s=()):
    """Score table over the (omega, direction) grid (``ev`` time-sorted).

    Speeds that turn the ball by less than ``min_rotation_rad`` over the whole window
    are left out but for the fastest of them (they cannot be told apart from it).
    ``extra_omegas_rad_s`` (rad/s) are scored too, as the last rows.

    Row ``omega`` uses ``n_events`` events spanning ``span_rad`` of rotation about ``t_ref``
    (:func:`events_for_span`).

    Returns
    -------
    omegas : ndarray (M,) rad/s
    directions : ndarray (D, 3)
    scores : ndarray (M, D)
        IWE variance divided by the variance without rotation for the same events
        (comparable across rows, which may use different events).
    """
    n_omega = int(np.ceil(np.log(omega_max_rad_s / omega_min_rad_s) / np.log(omega_ratio))) + 1
    omegas = omega_min_rad_s * omega_ratio ** np.arange(n_omega)
    window_s = max(float(ev.tau_s[0] - ev.tau_s[-1]), 1e-9)
    omegas = omegas[max(0, int(np.searchsorted(omegas * window_s, min_rotation_rad)) - 1):]
    omegas = np.concatenate([omegas, np.asarray(extra_omegas_rad_s, dtype=np.float64)])
    n_omega = len(omegas)
    directions = fibonacci_sphere(n_directions)
    geometry = IweGeometry(ev.radius_px, min(1.0, iwe_radius_px / ev.radius_px), sigma, hemispheres, truncate,
                           margin_px=0)
    index = _span_rows(ev, omegas, span_rad, n_events)  # (M, n)
    pts, tau, weight = _lift_rows(ev, index, velocity_px_s)
    matrix = direction_matrix(directions, geometry)
    scores = np.empty((n_omega, n_directions))
    for k in range(0, n_omega, rows_per_call):  # a few rows at a time: the arrays stay in cache
        part = slice(k, min(k + rows_per_call, n_omega))
        raw = score_rows(pts[:, part], tau[:, part], weight[:, part], omegas[part], matrix, geometry)
        scores[part] = raw[:, :-1] / np.maximum(raw[:, -1:], 1e-30)
    return omegas, directions, scores


def distinct_candidates(omegas, directions, scores, n_candidates: int, *, min_angle_deg: float = 30.0,
                        min_ratio: float = 1.3) -> list[np.ndarray]:
    """Best grid points as angular-velocity vectors (rad/s), mutually distinct.

    Two candidates are distinct when their axes differ by more than ``min_angle_deg``
    or their speeds by more than a factor ``min_ratio``.
    """
    order = np.argsort(scores, axis=None)[::-1]
    picked: list[np.ndarray] = []
    cos_min = np.cos(np.radians(min_angle_deg))
    for flat in order:
        i, j = np.unravel_index(flat, scores.shape)
        om, d = omegas[i], directions[j]
        if all(np.dot(d, p / np.linalg.norm(p)) < cos_min
               or max(om, np.linalg.norm(p)) / min(om, np.linalg.norm(p)) > min_ratio for p in picked):
            picked.append(om * d)
            if len(picked) == n_candidates:
                break
    return picked
