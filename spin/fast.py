"""The fast spin estimator: global coarse search, then coarse-to-fine BFGS.

1. Coarse search (:mod:`spin.search`) over axis directions x log-spaced omega on a
   few hundred events per omega spanning a fixed rotation angle, small IWEs.
2. The best mutually distinct grid points take a few BFGS steps together
   (:mod:`spin.refine`) on a small IWE; the best is then refined over growing rotation
   spans and finer IWEs, ending on the whole window at full resolution, each level
   starting from the previous level's inverse-Hessian estimate; the runner-up is
   refined along with it on the second-last level and takes over if it scores higher
   there.  The velocity stays at the prior unless the window covers enough
   rotation to separate spin from translation.
3. Confidence: the contrast gain over no rotation, the contrast margin of the winner
   over the best distinct rival (another axis or speed, e.g. an aliased omega of a
   symmetric texture or the mirrored axis) on the second-last level's events, the
   agreement of the IWEs of two halves of the events (structure rather than
   over-fitted noise), the motion the window covers (pixels travelled at the ball's
   equator), how much of the ball's rim fires at all (a ball partly outside the
   sensor or hidden) and how evenly the events fill the window in time (bursts leave
   aliased spins possible).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spin.objective import BallEvents, IweGeometry, contrast, iwe_parts, lift_moving
from spin.refine import maximise
from spin.search import coarse_search, distinct_candidates, events_for_span

# the fast method thins a window's ball events to at most this many (its finest level uses 8,000)
FAST_EVENTS = 24_000
# (rotation span rad, IWE radius px, blur sigma IWE px, events, BFGS iterations, relative contrast
# change that ends them); the first level screens the coarse candidates (a few steps each, all
# together), the last uses the whole window and gives its blur in ball pixels.  The IWE scale is
# capped at ``max_scale``.
LEVELS = ((2.0, 12.0, 1.2, 500, 2, 1e-4), (6.0, 40.0, 1.0, 2500, 6, 3e-4), (np.inf, 100.0, 0.55, 8000, 6, 1e-6))


@dataclass(frozen=True)
class FastResult:
    w_rad_s: np.ndarray
    v_px_s: np.ndarray
    contrast: float
    converged: bool
    confidence: float
    runner_up_w_rad_s: np.ndarray | None
    agreement: float
    margin: float
    coverage_px: float
    disc_fill: float
    time_fill: float


def _same(w1, w2, angle_deg=5.0, ratio=1.03) -> bool:
    w1, w2 = np.asarray(w1, dtype=np.float64), np.asarray(w2, dtype=np.float64)
    o1, o2 = math.sqrt(w1 @ w1), math.sqrt(w2 @ w2)
    if min(o1, o2) <= 0:
        return o1 == o2
    return (w1 @ w2) / (o1 * o2) > math.cos(math.radians(angle_deg)) and max(o1, o2) / min(o1, o2) < ratio


def _same_solution(w1, w2) -> bool:
    """Whether two angular velocities are one solution (within 10 deg and 10 %), not rivals."""
    return _same(w1, w2, 10.0, 1.1)


def _half_agreement(ev: BallEvents, w, v, geometry: IweGeometry) -> float:
    """Correlation of the IWEs of the even and the odd events (-1..1).

    High when both halves show the same aligned texture; near 0 for events without
    consistent structure (noise), where a maximum is only over-fitting.
    """
    a, b = (image.ravel() for image in iwe_parts(ev, w, v, geometry, 2))
    a = a - a.mean()
    b = b - b.mean()
    return float(np.dot(a, b) / max(np.sqrt(np.dot(a, a) * np.dot(b, b)), 1e-30))


def _disc_fill(ev: BallEvents, velocity_px_s, n_sectors: int = 16, max_events: int = 4000) -> float:
    """Fraction of the ball's rim sectors that fire events (0..1).

    Events between 0.4 r and the rim are binned by angle about the moving centre into
    ``n_sectors``; a sector counts when it holds at least 15 % of the mean count.  A
    ball partly outside the sensor or hidden behind something fires on one side only
    (and the edge sweeping across it is a structure the warp can align: a confident
    wrong spin), which this exposes.
    """
    ev = ev.take(slice(None, None, max(1, len(ev) // max_events)))
    vx, vy = (ev.s_s.dtype.type(c) for c in velocity_px_s)
    dx = ev.x_px - vx * ev.s_s
    dy = ev.y_px - vy * ev.s_s
    ring = dx * dx + dy * dy >= (0.4 * ev.radius_px) ** 2
    if not ring.any():
        return 0.0
    sector = ((np.arctan2(dy[ring], dx[ring]) + np.pi) * (n_sectors / (2 * np.pi))).astype(np.int64) % n_sectors
    counts = np.bincount(sector, minlength=n_sectors)
    return float(np.mean(counts >= 0.15 * counts.mean()))


def _time_fill(ev: BallEvents, n_bins: int = 64, min_bin_s: float = 2e-6, max_events: int = 8000) -> float:
    """Fraction of ``n_bins`` equal time bins of the window that hold events (0..1).

    Bins are at least ``min_bin_s`` wide (timestamps are whole microseconds).  A bin
    counts when it holds at least 10 % of the mean count.  Events bunched in time (a
    strobe or flickering light: bursts with gaps) leave the motion between bursts
    unseen, so spins that differ by a texture symmetry's turn per gap align the bursts
    equally well (aliasing); a continuous stream fills every bin.
    """
    tau = ev.tau_s[::max(1, len(ev) // max_events)]
    span = float(tau[0] - tau[-1])
    n_bins = int(min(n_bins, span / min_bin_s))
    if n_bins < 1:
        return 1.0
    bins = np.minimum(((tau[0] - tau) * (n_bins / span)).astype(np.int64), n_bins - 1)
    counts = np.bincount(bins, minlength=n_bins)
    return float(np.mean(counts >= 0.1 * counts.mean()))


def estimate_fast(ev: BallEvents, velocity_px_s, *, velocity_known: bool = True,
                  omega_min_rad_s: float = 2 * np.pi * 3.0, omega_max_rad_s: float = 2 * np.pi * 1500.0,
                  omega_ratio: float = 1.6, n_candidates: int = 3, n_directions: int = 40,
                  coarse_events: int = 450, levels=LEVELS, max_scale: float = 2.0,
                  refine_velocity: bool | None = None, hemispheres: bool = False,
                  prior_w_rad_s=None, prior_span: float = 2.2) -> FastResult:
    """Estimate ``w = omega * axis`` (rad/s) and the velocity from prepared ball events.

    Parameters
    ----------
    ev : BallEvents
    velocity_px_s : (2,)
        Velocity prior (px/s), e.g. from the tracker.
    velocity_known : bool
        Whether the prior is a measurement (else 0 was assumed).
    refine_velocity : bool or None
        Refine v on the last level; ``None``: when the window spans at least half a
        revolution (where rotation about an in-image axis no longer mimics
        translation) or no prior is known.
    prior_w_rad_s : (3,), optional
        A trusted estimate of a neighbouring window of the same flight (rad/s): it joins the
        candidates and the coarse search keeps to speeds within a factor ``prior_span`` of it
        (which still holds omega/2 and 2 omega, the aliases of symmetric textures).
    """
    v0 = np.asarray(velocity_px_s, dtype=np.float64)
    r = ev.radius_px
    prior = None if prior_w_rad_s is None else np.asarray(prior_w_rad_s, dtype=np.float64)
    if prior is not None and np.linalg.norm(prior) > 0:
        omega_prior = float(np.linalg.norm(prior))
        omega_min_rad_s = max(omega_min_rad_s, omega_prior / prior_span)
        omega_max_rad_s = max(min(omega_max_rad_s, omega_prior * prior_span), omega_min_rad_s * omega_ratio)
    else:
        prior = None
    omegas, directions, scores = coarse_search(
        ev, v0, omega_min_rad_s=omega_min_rad_s, omega_max_rad_s=omega_max_rad_s, omega_ratio=omega_ratio,
        n_directions=n_directions, n_events=coarse_events, hemispheres=hemispheres)
    starts = distinct_candidates(omegas, directions, scores, n_candidates)
    if prior is not None:
        starts = [prior] + [w for w in starts if not _same(w, prior, 30.0, 1.3)][:n_candidates - 1]
    window_s = float(ev.tau_s.max() - ev.tau_s.min())

    def geometry(level):
        scale = min(max_scale, level[1] / r)
        # the last level's blur is given in ball pixels (small balls get an upsampled IWE)
        sigma = level[2] * scale if level is levels[-1] else level[2]
        return IweGeometry(r, scale, sigma, hemispheres)

    # first level: every candidate on the same events (chosen for the best one's omega)
    first = levels[0]
    sub = events_for_span(ev, float(np.linalg.norm(starts[0])), first[0], first[3])
    # every candidate takes a few steps (the best goes on at the next level)
    results = sorted(maximise(sub, starts, v0, geometry(first), max_iterations=first[4], ftol=first[5]),
                     key=lambda m: -m.contrast)
    best = results[0]
    # a rival is another solution: at least 10 deg or 10 % away (nearer, it is the same maximum)
    rival = next((m for m in results[1:] if not _same_solution(m.w_rad_s, best.w_rad_s)), None)
    # further levels: the winner only, over longer spans and finer IWEs, ending on the whole window;
    # the runner-up is refined along with it on the second-last level's events, to measure the margin
    # (it stops where it comes within reach of the winner: no rival then), and takes over where it
    # scores higher there
    w, v = best.w_rad_s, best.v_px_s
    margin = gain = 1.0
    for li, level in enumerate(levels[1:], start=1):
        span, _, _, n_ev, iterations, ftol = level
        last = li == len(levels) - 1
        omega = float(np.linalg.norm(w))
        sub = events_for_span(ev, 1e-9 if last else omega, np.inf if last else span, n_ev)
        rv = False
        if last:
            rv = (omega * window_s >= np.pi or not velocity_known) if refine_velocity is None else refine_velocity
        lifted = None if rv else lift_moving(sub, v)
        runs = [best] + ([rival] if rival is not None and li == len(levels) - 2 else [])
        # an estimated (not tracked) velocity needs more steps: rotation and translation trade off slowly
        runs = maximise(sub, [m.w_rad_s for m in runs], v, geometry(level), refine_velocity=rv,
                        max_iterations=iterations if velocity_known else 3 * iterations, ftol=ftol,
                        inverse_hessians=[m.inverse_hessian for m in runs], lifted=lifted,
                        stop_same=_same)
        best = runs[0]
        if len(runs) > 1:
            rival = runs[1]
            if rival.contrast > best.contrast:
                best, rival = rival, best
            if runs[1].stopped:  # it reached the winner's maximum: no rival
                rival = None
        w, v = best.w_rad_s, best.v_px_s
        if li == len(levels) - 2:
            still = contrast(sub, np.zeros(3), v, geometry(level), gradient=False, lifted=lifted)
            gain = 1.0 - still / max(best.contrast, 1e-30)
            if rival is not None and _same_solution(rival.w_rad_s, w):
                rival = None
            elif rival is not None:
                margin = max(0.0, best.contrast - rival.contrast) / max(best.contrast - still, 1e-30)
    # half agreement at the second-last level's resolution and event count (as telling, 4x cheaper)
    agreement = _half_agreement(events_for_span(sub, 1e-9, np.inf, levels[-2][3]), w, v, geometry(levels[-2]))
    coverage_px = float(np.linalg.norm(w)) * window_s * r
    disc_fill = _disc_fill(ev, v)
    time_fill = _time_fill(ev)
    confidence = float(np.clip(gain / 0.1, 0, 1) * np.clip((agreement - 0.2) / 0.4, 0, 1)
                       * np.clip(margin / 0.05, 0, 1) * np.clip(coverage_px / 3.0, 0, 1)
                       * np.clip((disc_fill - 0.45) / 0.2, 0, 1)
                       * np.clip((time_fill - 0.5) / 0.3, 0, 1))
    if not velocity_known:
        # without a tracker velocity the centre motion is itself estimated (and errors in it bend
        # the axis): at most 0.5, less for in-image axes on windows short of a quarter turn, where
        # rotation and translation trade off
        in_plane = float(np.linalg.norm(w[:2]) / max(np.linalg.norm(w), 1e-30))
        rotation_rad = float(np.linalg.norm(w)) * window_s
        confidence *= 0.5 * (1.0 - in_plane * (1.0 - min(1.0, rotation_rad / (np.pi / 2))))
    return FastResult(w, v, best.contrast, best.success, confidence, None if rival is None else rival.w_rad_s,
                      agreement, margin, coverage_px, disc_fill, time_fill)
