"""The fast spin estimator: global coarse search, then coarse-to-fine BFGS.

1. Coarse search (:mod:`spin.search`) over axis directions x log-spaced omega on a
   few hundred events per omega spanning a fixed rotation angle, small IWEs.
2. The best mutually distinct grid points (eight) take a few BFGS steps together
   (:mod:`spin.refine`) on a small IWE; the best three distinct ones after those go on
   together on the next level (the small IWE often ranks the right one second or third:
   the coarse grid rarely lands within 30 deg / 35 % of the answer), and the best there is
   refined over growing rotation spans and finer IWEs, ending on the whole window at full
   resolution, each level starting from the previous level's inverse-Hessian estimate; the
   runner-up is refined along with it on the second-last level and takes over if it scores
   higher there.  The velocity stays at the prior unless the window covers enough
   rotation to separate spin from translation.
3. Confidence: the contrast gain over no rotation, the contrast margin of the winner
   over the best distinct rival (another axis or speed, e.g. an aliased omega of a
   symmetric texture or the mirrored axis) on the second-last level's events, the
   agreement of the IWEs of two halves of the events (structure rather than
   over-fitted noise), the motion the window covers (pixels travelled at the ball's
   equator), how much of the ball's rim fires at all (a ball partly outside the
   sensor or hidden) and how evenly the events fill the window in time (bursts leave
   aliased spins possible).
4. Cross-check: the same estimate, from scratch, on the first and on the second half of the
   events in time (on quarters for windows over many turns).  A right answer comes out of both
   halves; a wrong one that wins on the whole window (an aliased speed, a mirrored axis, a sharp
   but spurious alignment of sparse seams) rarely comes out of both.  Confidence falls as either
   half strays beyond 5 deg / 5 % of the whole window's answer, and the halves' spread gives the
   uncertainty.  A half whose answer strays far stops refining early: it is refined again beside
   the whole window's answer on the same events, and the higher contrast speaks for the half.
5. The image's period (:mod:`spin.period`): over a few turns the ball's image repeats once per turn
   (or per fold of a texture's symmetry about the axis).  Its speed is a start of the search; the
   whole window's events folded over the turns at that speed are searched again (:func:`_folded_answer`);
   the answer's rate becomes the period's where the two lie within the cross-check's 5 %, and an
   answer turning more than once per period (the image would repeat sooner) is not trusted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from spin.objective import BallEvents, IweGeometry, contrast, iwe_parts, lift_moving
from spin.period import image_period, turn_speeds
from spin.pixel_lag import Bursts, rate_bias_pct
from spin.refine import maximise
from spin.search import coarse_search, distinct_candidates, events_for_span

# the fast method thins a window's ball events to at most this many (its finest level uses 8,000)
FAST_EVENTS = 24_000
# (rotation span rad, IWE radius px, blur sigma IWE px, events, BFGS iterations, relative contrast
# change that ends them); the first level screens the coarse candidates (a few steps each, all
# together), the last gives its blur in ball pixels.  No level spans more than 1.5 rad (86 deg) of
# rotation: over longer spans texture seen at the window's ends has turned out of view (far
# hemisphere) and the lift's depth errors near the rim grow, which lets spurious alignments win.
# The IWE scale is capped at ``max_scale``.
LEVELS = ((1.5, 12.0, 1.2, 500, 6, 1e-4), (1.5, 40.0, 1.0, 2500, 6, 3e-4), (1.5, 100.0, 0.55, 8000, 6, 1e-6))
# levels from this one on (0: the first) keep the warped points that turn to the far side of the ball in an
# IWE of their own (``IweGeometry.hemispheres``) instead of over the near side's texture.  On the benchmark's
# tuning seeds 64.4 % of the windows came out right against 60.5 % with one IWE, 374 trusted against 348,
# at 42 against 37 ms per estimate (mean); with the coarse search and the first level too, 63.8 % right
# and 376 trusted, at more cost
FAR_SIDE_FROM_LEVEL = 1
# the cross-check's parts must agree with the whole window within these (deg, ratio) for full trust
CHECK_ANGLE_DEG, CHECK_RATIO = 5.0, 1.05
# trust in the whole window's answer falls from full to none as its parts' largest deviation from it
# grows from the first to the second of these (in units of those limits).  On the benchmark's tuning
# seeds (0-3) 90 % of the trusted windows that were right had parts within 0.6 of the limits, and
# (1.0, 1.6) trusted wrong ones at 1.05-1.1, which (0.9, 1.4) does not (two more, at 0.8 and 0.9, had a
# single quarter finding the answer: see QUARTER_QUORUM)
TRUST_WORST_FULL, TRUST_WORST_ZERO = 0.9, 1.4
# of a window checked on quarters, at least this many quarters' own searches must find the whole's answer
# for full trust (on the tuning seeds, one of the two trusted windows with a single such quarter was wrong)
QUARTER_QUORUM = 2
# a part whose answer strays more than this many times those limits from the whole window's after a
# level (the first level, the second-last) refines it no further: the cross-check then refines it again
# beside the whole's answer (:func:`_half_answer`).  The first level's answers on windows of little
# rotation lie up to ~25 deg from the truth; the second-last level's within a few degrees.
STRAY_FACTORS = (6.0, 3.0)
# the cross-check's parts search with fewer starts (:func:`estimate_window`'s ``n_candidates``,
# ``n_carry``) than the whole window: on the benchmark's tuning seeds as many windows were right
# (55.8 %) and 340 against 347 were trusted, at 30 against 34 ms per estimate (median); so do windows
# that start from a trusted neighbour's answer (``spin.estimate_windows``), which is one of the starts
NARROW_SEARCH = {"n_candidates": 3, "n_carry": 1}
# a window turning through at least this much (rad: eight times a level's span) is checked on quarters
QUARTERS_FROM_RAD = 8 * LEVELS[-1][0]
# the fastest spin looked for (rad/s)
OMEGA_MAX_RAD_S = 2 * np.pi * 1500.0
# the folds of a texture's symmetry about its axis that the image's period may show (:func:`spin.period.turn_speeds`)
PERIOD_FOLDS = (1, 2, 3, 4, 5, 6)
# uncertainty (1 sigma): the halves' difference times these (axis, rate), at least the floors (deg, %).
# Two independent halves differ with sqrt(2) times either's sigma; a half has half the events and
# (time halves) half the rotation, which costs the rate about twice as much precision as the axis.
# Checked on the benchmark's tuning seeds: 2 sigma should cover 95 % of the trusted windows' errors
# (seeds 0-3: axis 95.5 %, rate 95.9 %; 94.0 % with a rate floor of 0.6 %).
SIGMA_SCALE_AXIS, SIGMA_SCALE_RPS = 0.75, 0.35
SIGMA_FLOOR_DEG, SIGMA_FLOOR_PCT = 1.0, 0.7
# the rate's floor (%) where it is the speed of the image's period as one whole turn (:func:`_period_speed`;
# a fold of a texture's symmetry repeats the image only roughly) and the window holds at least
# ``PERIOD_SIGMA_MIN_PERIODS`` periods (no lag term then: the period is not biased by it).
# On the benchmark's tuning seeds the rate errors of the windows right both ways over 4-8 turns fell from
# 0.099 % (median; 90th percentile 0.44 %) with the search's rate to 0.029 % (0.062 %, largest 0.32 %) at
# the period's; over fewer periods a period found can be some percent off
PERIOD_SIGMA_FLOOR_PCT, PERIOD_SIGMA_MIN_PERIODS = 0.15, 4.0
# the rate's systematic uncertainty from the sensor's lag (1 sigma): this times
# spin.pixel_lag.rate_bias_pct, added in quadrature.  On the benchmark's tuning seeds 0.3 brings
# the rate's 2 sigma over 97 % of the trusted windows' errors (91 % without the term).
LAG_SIGMA_SCALE = 0.3
# the lag's trail makes the contrast peak at a slower spin: the rate is raised by this share of the trail
# (rate_bias_pct) beyond LAG_RATE_FROM_PCT.  On the benchmark's tuning seeds (realistic sensor, axis right)
# the rate came out 0.0 % off (median) for trails under 2 %, 0.8-0.9 % low for 2-8 %, 4 % for 8-16 % and
# 8-21 % beyond (0.3-0.5 of the trail); corrected so, 211 of 223 such windows were within 5 % (207 before)
# and 189 within 1.5 % (180)
LAG_RATE_GAIN, LAG_RATE_FROM_PCT = 0.45, 4.0
# where the ball's image moves at least this many times as fast as its rim turns (|v| >= this * omega r),
# the contrast's peak depends on the IWE's blur: most events then come from the texture sliding across
# the pixels with the flight, and the peak moves towards a slower spin as the blur grows (a soccer ball of
# r 14 px at 30 rps and 2,700 px/s: 1.5 % low at a blur of 0.3 px, 3 % at 0.55 px, 6-8 % at 1 px; a
# still ball: none at any blur).  There the answer is moved to zero blur (:func:`_blur_shift`: the last
# level's peak again at ``BLUR_SHIFT_FACTOR`` times its blur, extrapolated linearly) and the move is
# counted in the uncertainty.  On the benchmark's tuning seeds (orthographic, axis within 10 deg) the rate
# came out +0.00 % off (median) below 0.3, -0.28 % at 0.3-1 and -0.80 % at 1-3; at 8 rps (translating,
# dense textures) the trusted windows' rate -0.47 % (median) with 2 sigma covering 82 % of them,
# -0.04 % and 94 % so
BLUR_SHIFT_FROM_DRIFT, BLUR_SHIFT_FACTOR = 0.3, 2.0


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
    period_s: float = float("nan")
    axis_sigma_deg: float = float("nan")
    rps_sigma_pct: float = float("nan")
    rps_lag_pct: float = float("nan")


def _deviation(w, w_ref) -> tuple[float, float]:
    """Axis angle (deg) and speed ratio's log distance of ``w`` from ``w_ref`` (rad/s vectors)."""
    w, w_ref = np.asarray(w, dtype=np.float64), np.asarray(w_ref, dtype=np.float64)
    o, o_ref = float(np.linalg.norm(w)), float(np.linalg.norm(w_ref))
    if min(o, o_ref) <= 0:
        return 180.0, np.inf
    angle = math.degrees(math.acos(float(np.clip(w @ w_ref / (o * o_ref), -1.0, 1.0))))
    return angle, abs(math.log(o / o_ref))


def _same(w1, w2, angle_deg=5.0, ratio=1.03) -> bool:
    """Whether two angular velocities lie within ``angle_deg`` and a speed factor ``ratio`` of each other."""
    angle, log_ratio = _deviation(w1, w2)
    if math.isinf(log_ratio):  # a zero vector: the same only as another
        return not (np.any(w1) or np.any(w2))
    return angle < angle_deg and log_ratio < math.log(ratio)


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


def _folded(ev: BallEvents, velocity_px_s, omega_rad_s: float) -> BallEvents:
    """``ev`` folded over the turns of a spin at ``omega_rad_s``: each event's ``tau`` less the whole turns
    in it (within half a turn of ``t_ref``), positions in the ball's frame (the centre's motion at
    ``velocity_px_s`` taken out: warp them with no velocity), sorted by time again; events beyond the
    radius there are dropped.  At that speed an event turns by the same rotation either way."""
    vx, vy = (ev.s_s.dtype.type(c) for c in velocity_px_s)
    period = ev.tau_s.dtype.type(2 * np.pi / omega_rad_s)
    tau = np.remainder(ev.tau_s + period / 2, period) - period / 2
    x, y = ev.x_px - vx * ev.s_s, ev.y_px - vy * ev.s_s
    inside = x * x + y * y < ev.radius_px ** 2
    order = np.flatnonzero(inside)[np.argsort(-tau[inside], kind="stable")]
    tau = tau[order]
    return BallEvents(x[order], y[order], -tau, tau, ev.weight[order], ev.radius_px)


def _folded_answer(ev: BallEvents, w, v, period_s: float, speeds, *, levels, max_scale: float,
                   hemispheres: bool) -> np.ndarray:
    """The best answer (rad/s) at one of the speeds of the image's period ``period_s`` (s), searched on
    the events folded over its turns, or ``w`` (the search's answer on the events as they are).

    Folded, every turn's events of one side of the ball fill the same half turn: a sparse texture seen
    over many turns shows its seams as often as it passed them, where the levels' spans (1.5 rad of
    rotation, one turn's worth of events) hold them once.  At each of ``speeds`` (rad/s) the whole
    search runs again on the events folded at that speed (its coarse grid at 1/1.1 and 1.45 times that
    speed, the refinement free), and its answer, brought to that speed, is scored there (the last
    level's events and IWE, the far side's IWE included).  ``w``, where it lies within ``CHECK_RATIO`` of
    a speed of the period (any of :data:`PERIOD_FOLDS`), is scored the same way at that speed; the
    highest score wins.  An answer near none of them (the period contradicts it) gives way to the best
    folded one.
    """
    level = levels[-1]
    geometry = _geometry(level, True, ev.radius_px, max_scale, _far_side(len(levels) - 1, hemispheres))
    omega = float(np.linalg.norm(w))
    near = _near_folds(w, period_s)
    own = near[0] if near else None  # the fold of the period that ``w`` lies near
    runs = [(speed, True) for speed in speeds]  # (speed, search there)
    if own is not None and not np.any(np.isclose(speeds, own)):
        runs.append((own, False))
    best_contrast, best_w = -np.inf, w
    for speed, search in runs:
        folded = _folded(ev, v, speed)
        if len(folded) < len(ev) // 2:  # the velocity moves most events off the disc: no folding
            continue
        answers = [w * (speed / omega)] if own is not None and np.isclose(own, speed) else []
        if search:
            alt = estimate_window(folded, (0.0, 0.0), omega_min_rad_s=speed / 1.1, omega_max_rad_s=speed * 1.1,
                                  assess=False, levels=levels, max_scale=max_scale,
                                  hemispheres=hemispheres, refine_velocity=False)
            answers.append(alt.w_rad_s * (speed / float(np.linalg.norm(alt.w_rad_s))))
        sub = events_for_span(folded, speed, level[0], level[3])
        for answer in answers:
            c = float(contrast(sub, answer, np.zeros(2), geometry, gradient=False))
            if c > best_contrast:
                best_contrast, best_w = c, answer
    return best_w


def _period_speed(w, period_s: float) -> np.ndarray:
    """``w`` (rad/s) at the speed the image's period ``period_s`` (s; NaN: none) gives, where its own lies
    within the cross-check's ratio ``CHECK_RATIO`` of one of them (:data:`PERIOD_FOLDS`): the same rate
    measured again, to a fraction of a percent and unbiased by the sensor's lag; else ``w``."""
    near = _near_folds(w, period_s)
    return w * (near[0] / float(np.linalg.norm(w))) if near else w


def _near_folds(w, period_s: float) -> list[float]:
    """The speeds (rad/s) of the period ``period_s``'s folds (:data:`PERIOD_FOLDS`) within ``CHECK_RATIO``
    of ``w``'s (rad/s); none for a NaN period or a zero ``w``."""
    omega = float(np.linalg.norm(w))
    if math.isnan(period_s) or omega <= 0:
        return []
    return [s for s in turn_speeds(period_s, PERIOD_FOLDS) if abs(math.log(s / omega)) < math.log(CHECK_RATIO)]


def _far_side(li: int, hemispheres: bool) -> bool:
    """Whether level ``li`` keeps the far side's points in an IWE of their own (:data:`FAR_SIDE_FROM_LEVEL`)."""
    return hemispheres or li >= FAR_SIDE_FROM_LEVEL


def _geometry(level, last: bool, radius_px: float, max_scale: float, hemispheres: bool) -> IweGeometry:
    """IWE raster of a level of :data:`LEVELS` (the last level gives its blur in ball pixels: small balls
    get an upsampled IWE)."""
    scale = min(max_scale, level[1] / radius_px)
    return IweGeometry(radius_px, scale, level[2] * scale if last else level[2], hemispheres)


def _half_answer(half: BallEvents, own: FastResult, whole: FastResult, *, levels=LEVELS, max_scale: float = 2.0,
                 hemispheres: bool = False, **_) -> np.ndarray:
    """What a half of the events says (rad/s): its own answer, or the whole window's answer refined on
    the half where that scores at least as high there (the half's own search then fell short).

    Both are refined from their points on the same events (the last level's, chosen for the whole
    window's speed), so their contrasts compare.  The far side's points stay in the near side's IWE
    here (unlike the levels from ``FAR_SIDE_FROM_LEVEL`` on): an objective of its own for the check.
    With the far side's IWE here too, 390 windows against 374 were trusted on the benchmark's tuning
    seeds, but the first held-out set held 5 confidently wrong against 2.
    """
    level = levels[-1]
    sub = events_for_span(half, float(np.linalg.norm(whole.w_rad_s)), level[0], level[3])
    runs = maximise(sub, [whole.w_rad_s, own.w_rad_s], whole.v_px_s,
                    _geometry(level, True, half.radius_px, max_scale, hemispheres),
                    max_iterations=level[4], ftol=level[5])
    return runs[0].w_rad_s if runs[0].contrast >= runs[1].contrast else runs[1].w_rad_s


def _blur_shift(ev: BallEvents, w, v, omega_rad_s: float, *, levels=LEVELS, max_scale: float = 2.0,
                hemispheres: bool = False, **_) -> np.ndarray:
    """What the contrast's peak at ``w`` (rad/s) moves by as the last level's blur goes to zero (rad/s).

    ``w`` refined on the last level's events (chosen for ``omega_rad_s``, velocity ``v`` px/s held) at its
    blur and at :data:`BLUR_SHIFT_FACTOR` times it; the difference of the two peaks divided by the factor
    less one: the shift to zero blur where the peak moves linearly with the blur.
    """
    level = levels[-1]
    sub = events_for_span(ev, omega_rad_s, level[0], level[3])
    sharp = _geometry(level, True, ev.radius_px, max_scale, _far_side(len(levels) - 1, hemispheres))
    lifted = lift_moving(sub, v)
    peaks = [maximise(sub, [w], v, g, max_iterations=level[4], ftol=level[5], lifted=lifted)[0].w_rad_s
             for g in (sharp, replace(sharp, sigma=sharp.sigma * BLUR_SHIFT_FACTOR))]
    return (peaks[0] - peaks[1]) / (BLUR_SHIFT_FACTOR - 1.0)


def _recentred(ev: BallEvents) -> BallEvents:
    """``ev`` with ``t_ref`` moved to the middle of its own time span."""
    mid = ev.s_s.dtype.type(0.5) * (ev.s_s[0] + ev.s_s[-1])
    return BallEvents(ev.x_px, ev.y_px, ev.s_s, mid - ev.s_s, ev.weight, ev.radius_px)


def estimate_fast(ev: BallEvents, velocity_px_s, *, check: bool = True, min_half_events: int = 100,
                  bursts: Bursts | None = None, drift_radii_s: float = 0.0, **opts) -> FastResult:
    """Estimate ``w = omega * axis`` (rad/s) and the velocity from prepared (time-sorted) ball events.

    :func:`estimate_window` on all the events and, with ``check``, again from scratch on each half
    of them in time (the cross-check; on each quarter where the window turns through at least
    ``QUARTERS_FROM_RAD``: there a sparse or symmetric texture can alias alike in both halves).
    Where a part's answer strays, the whole window's answer refined on that part replaces it if it
    scores at least as high there (:func:`_half_answer`).  The confidence of the whole window's
    answer is scaled by ``clip((TRUST_WORST_ZERO - worst) / (TRUST_WORST_ZERO - TRUST_WORST_FULL), 0, 1)``,
    ``worst`` being the largest of the parts' deviations from it in units of (``CHECK_ANGLE_DEG``,
    ``log CHECK_RATIO``): 1 while all parts lie within 4.5 deg / 4.5 %, 0 beyond 7 deg / 7 %; and by
    ``clip(1.75 - spread, 0, 1)``, ``spread`` the larger of the uncertainties in units of 2.5 deg / 2.5 %.
    Halves of fewer than ``min_half_events`` events cannot check: the confidence is then halved.  The
    product is halved too where fewer than ``QUARTER_QUORUM`` quarters' own searches found the whole
    window's answer: the others agreed only through the whole's answer refined on them, and a sparse or
    symmetric texture seen over many turns can align as well on a wrong spin in each (a one-logo ball
    33 deg off at 800 rps with its four quarters "agreeing", a tennis ball 57 deg off at 1,200 rps with
    one), and where the answer turns more than once per period of the image (``period_s``: the image
    would repeat sooner; rare once the whole window's answer is chosen at the period's speeds, see
    :func:`_folded_answer`).  The product is squared (see the code): a window is trusted (0.5) only
    while its 2 sigma stays within about 5 deg / 5 % and every part within about 5 deg / 5 % of its
    answer.

    The uncertainty (1 sigma) is the difference of the first and the last part scaled by ``SIGMA_SCALE_AXIS`` /
    ``SIGMA_SCALE_RPS``, at least ``SIGMA_FLOOR_DEG`` / ``SIGMA_FLOOR_PCT``; the rate's also holds,
    in quadrature, ``LAG_SIGMA_SCALE`` times the sensor's lag seen on the ball's ``bursts``
    (:func:`spin.pixel_lag.rate_bias_pct`: a bias every part shares), which ``rps_lag_pct`` gives
    alone; a rate of one turn per period of the image over at least ``PERIOD_SIGMA_MIN_PERIODS`` periods
    has no lag term and the floor ``PERIOD_SIGMA_FLOOR_PCT``.  The rate itself is raised by ``LAG_RATE_GAIN``
    of the lag beyond ``LAG_RATE_FROM_PCT`` (the contrast stays the search's, at the rate before).
    Where the ball's image drifts fast against its spin (``drift_radii_s``, the centre's image speed in
    radii per second, at least ``BLUR_SHIFT_FROM_DRIFT`` times the speed found), the answer is moved by
    :func:`_blur_shift` (its speed kept where it is the image period's) and the move's angle and rate
    change are added in quadrature to the uncertainty.
    ``axis_sigma_deg``, ``rps_sigma_pct`` and ``rps_lag_pct`` are NaN, and neither the rate nor the blur
    corrected, without a cross-check.  ``opts`` go to :func:`estimate_window`.
    """
    whole = estimate_window(ev, velocity_px_s, **opts)
    if not check:
        return whole
    half = len(ev) // 2
    if half < min_half_events:
        return replace(whole, confidence=0.5 * whole.confidence)
    # windows over many turns are checked on quarters (each still spans more than a level uses): on
    # them, a sparse or symmetric texture can alias the same way in both halves
    omega = float(np.linalg.norm(whole.w_rad_s))
    window_s = float(ev.tau_s[0] - ev.tau_s[-1])
    turns_rad = omega * window_s
    n_parts = 4 if turns_rad >= QUARTERS_FROM_RAD and len(ev) // 4 >= min_half_events else 2
    bounds = [len(ev) * k // n_parts for k in range(n_parts + 1)]
    parts = []
    worst = 0.0
    found = 0  # parts whose own search found the whole window's answer
    for i0, i1 in zip(bounds[:-1], bounds[1:]):
        events = _recentred(ev.take(slice(i0, i1)))
        own = estimate_window(events, velocity_px_s, assess=False, reference_w_rad_s=whole.w_rad_s,
                              **{**NARROW_SEARCH, **opts})
        angle, log_ratio = _deviation(own.w_rad_s, whole.w_rad_s)
        w = own.w_rad_s
        if angle > CHECK_ANGLE_DEG or log_ratio > math.log(CHECK_RATIO):
            w = _half_answer(events, own, whole, **opts)
            angle, log_ratio = _deviation(w, whole.w_rad_s)
        else:
            found += 1
        worst = max(worst, angle / CHECK_ANGLE_DEG, log_ratio / math.log(CHECK_RATIO))
        parts.append(w)
    angle, log_ratio = _deviation(parts[0], parts[-1])
    axis_sigma = max(SIGMA_SCALE_AXIS * angle, SIGMA_FLOOR_DEG)
    # a rate of one turn per image period, which the window holds several times over, is measured
    # without the lag's bias, more finely
    on_period = window_s >= PERIOD_SIGMA_MIN_PERIODS * whole.period_s and math.isclose(
        omega * whole.period_s, 2 * np.pi, rel_tol=1e-9)
    trail_pct = 0.0 if on_period else rate_bias_pct(bursts, whole.w_rad_s, window_s)
    lag = LAG_SIGMA_SCALE * trail_pct
    floor = PERIOD_SIGMA_FLOOR_PCT if on_period else SIGMA_FLOOR_PCT
    rps_sigma = math.hypot(max(SIGMA_SCALE_RPS * 100.0 * math.expm1(log_ratio), floor), lag)
    w = whole.w_rad_s
    if omega > 0 and drift_radii_s >= BLUR_SHIFT_FROM_DRIFT * omega:
        w = w + _blur_shift(ev, w, whole.v_px_s, omega, **opts)
        if on_period:  # the period's rate stands
            w = w * (omega / float(np.linalg.norm(w)))
        move_deg, move_log = _deviation(w, whole.w_rad_s)
        axis_sigma = math.hypot(axis_sigma, move_deg)
        rps_sigma = math.hypot(rps_sigma, 100.0 * math.expm1(move_log))
    spread = max(axis_sigma / (0.5 * CHECK_ANGLE_DEG), rps_sigma / (50.0 * (CHECK_RATIO - 1.0)))
    # squared: on the benchmark's tuning seeds the product's windows between 0.5 and 0.7 were right only
    # 70 % of the time, those above 0.7 always (squaring puts 0.71 at 0.5)
    agree = float(np.clip((TRUST_WORST_ZERO - worst) / (TRUST_WORST_ZERO - TRUST_WORST_FULL), 0.0, 1.0))
    # an answer turning more than once per period of the image contradicts it (the image would repeat sooner)
    too_fast = omega * whole.period_s > 2 * np.pi * CHECK_RATIO
    confidence = (whole.confidence * agree * float(np.clip(1.75 - spread, 0.0, 1.0))
                  * (0.5 if n_parts == 4 and found < QUARTER_QUORUM else 1.0) * (0.5 if too_fast else 1.0)) ** 2
    # the trail makes the contrast peak at a slower spin: the rate is corrected by part of it
    raise_by = 1.0 + LAG_RATE_GAIN * max(trail_pct - LAG_RATE_FROM_PCT, 0.0) / 100.0
    return replace(whole, w_rad_s=w * raise_by, confidence=confidence, axis_sigma_deg=axis_sigma,
                   rps_sigma_pct=rps_sigma, rps_lag_pct=lag)


def estimate_window(ev: BallEvents, velocity_px_s, *, velocity_known: bool = True,
                    omega_min_rad_s: float = 2 * np.pi * 3.0, omega_max_rad_s: float = OMEGA_MAX_RAD_S,
                    omega_ratio: float = 1.6, n_candidates: int = 8, n_directions: int = 40,
                    coarse_events: int = 450, levels=LEVELS, max_scale: float = 2.0,
                    refine_velocity: bool | None = None, hemispheres: bool = False,
                    prior_w_rad_s=None, prior_span: float = 2.2, assess: bool = True,
                    reference_w_rad_s=None, n_carry: int = 3) -> FastResult:
    """One estimate of ``w = omega * axis`` (rad/s) and the velocity from prepared ball events.

    Parameters
    ----------
    ev : BallEvents
    velocity_px_s : (2,)
        Velocity prior (px/s), e.g. from the tracker.
    velocity_known : bool
        Whether the prior is a measurement (else 0 was assumed).
    refine_velocity : bool or None
        Refine v on the last level; ``None``: when the last level's events span at least half
        a revolution (where rotation about an in-image axis no longer mimics translation) or
        no prior is known.
    hemispheres : bool
        Warped points on the far side of the ball go to a second IWE beside the first (the
        texture there does not overlap the near side's) in the coarse search and every level;
        without, in the levels from ``FAR_SIDE_FROM_LEVEL`` on.
    prior_w_rad_s : (3,), optional
        A trusted estimate of a neighbouring window of the same flight (rad/s): it joins the
        candidates and the coarse search keeps to speeds within a factor ``prior_span`` of it
        (which still holds omega/2 and 2 omega, the aliases of symmetric textures).
    assess : bool
        Measure the confidence (else NaN, with no runner-up refined for a margin: the cross-check's
        halves need only the answer).
    reference_w_rad_s : (3,), optional
        The answer a cross-check's part is compared with (rad/s): once this one strays more than
        ``STRAY_FACTORS`` times the check's limits from it, the levels stop (its exact value no longer
        matters).
    n_candidates, n_carry : int
        Distinct coarse-grid points refined on the first level, and distinct answers of it refined
        together on the second (the best there goes on alone).  On the benchmark's tuning seeds (one
        estimate per window, no cross-check) 3 and 1 found 52 % of the ideal sensor's windows and
        26 % of the realistic sensor's within 5 deg / 5 %, 8 and 3 (and 6 BFGS steps on the first
        level, not 2) 65 % and 49 %, at about a quarter more CPU.
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
    found = image_period(ev, v0, min_period_s=math.pi / omega_max_rad_s) if math.isfinite(omega_max_rad_s) else None
    period_s = float("nan") if found is None else found[0]
    periodic = np.empty(0) if found is None else turn_speeds(period_s, PERIOD_FOLDS[:2])
    periodic = periodic[(periodic >= omega_min_rad_s) & (periodic <= omega_max_rad_s)]
    omegas, directions, scores = coarse_search(
        ev, v0, omega_min_rad_s=omega_min_rad_s, omega_max_rad_s=omega_max_rad_s, omega_ratio=omega_ratio,
        n_directions=n_directions, n_events=coarse_events, hemispheres=hemispheres, extra_omegas_rad_s=periodic)
    starts = distinct_candidates(omegas, directions, scores, n_candidates)
    # the best direction at each speed the image's period gives is a start too, first after a prior
    # (the first level's events are chosen for the first start's speed)
    forced = [] if prior is None else [prior]
    for i in range(len(omegas) - len(periodic), len(omegas)):
        start = omegas[i] * directions[np.argmax(scores[i])]
        if all(not _same(start, f, 30.0, 1.3) for f in forced):
            forced.append(start)
    if forced:
        starts = forced + [w for w in starts if all(not _same(w, f, 30.0, 1.3) for f in forced)]
        starts = starts[:max(n_candidates, len(forced))]
    window_s = float(ev.tau_s.max() - ev.tau_s.min())

    def geometry(li):
        return _geometry(levels[li], li == len(levels) - 1, r, max_scale, _far_side(li, hemispheres))

    # first level: every candidate on the same events (chosen for the first one's omega)
    first = levels[0]
    sub = events_for_span(ev, float(np.linalg.norm(starts[0])), first[0], first[3])
    # every candidate takes a few steps (the best ``n_carry`` distinct ones go on to the next level)
    results = sorted(maximise(sub, starts, v0, geometry(0), max_iterations=first[4], ftol=first[5]),
                     key=lambda m: -m.contrast)
    best = results[0]
    # a rival is another solution: at least 10 deg or 10 % away (nearer, it is the same maximum)
    rival = next((m for m in results[1:] if not _same_solution(m.w_rad_s, best.w_rad_s)), None)
    # further levels: the winner only (on the second, with the first level's next best distinct answers,
    # up to ``n_carry`` in all: the highest there wins), over longer spans and finer IWEs, ending on the
    # whole window; the runner-up is refined along with it on the second-last level's events, to measure
    # the margin (it stops where it comes within reach of the winner: no rival then), and takes over
    # where it scores higher there
    w, v = best.w_rad_s, best.v_px_s
    margin = gain = 1.0
    for li, level in enumerate(levels[1:], start=1):
        span, _, _, n_ev, iterations, ftol = level
        last = li == len(levels) - 1
        if reference_w_rad_s is not None:
            angle, log_ratio = _deviation(w, reference_w_rad_s)
            stray = STRAY_FACTORS[0] if li == 1 else STRAY_FACTORS[1]
            if angle > stray * CHECK_ANGLE_DEG or log_ratio > stray * math.log(CHECK_RATIO):
                break
        omega = float(np.linalg.norm(w))
        sub = events_for_span(ev, omega, span, n_ev)
        rv = False
        if last:
            sub_s = float(sub.tau_s.max() - sub.tau_s.min())
            rv = (omega * sub_s >= np.pi or not velocity_known) if refine_velocity is None else refine_velocity
        lifted = None if rv else lift_moving(sub, v)
        runs = [best] + ([rival] if assess and rival is not None and li == len(levels) - 2 else [])
        if li == 1 and not rv:  # the first level's best distinct answers go on together
            for m in results[1:]:
                if len(runs) < n_carry and all(not _same_solution(m.w_rad_s, o.w_rad_s) for o in runs):
                    runs.append(m)
        # an estimated (not tracked) velocity needs more steps: rotation and translation trade off slowly
        runs = maximise(sub, [m.w_rad_s for m in runs], v, geometry(li), refine_velocity=rv,
                        max_iterations=iterations if velocity_known else 3 * iterations, ftol=ftol,
                        inverse_hessians=[m.inverse_hessian for m in runs], lifted=lifted,
                        stop_same=_same)
        if len(runs) > 1:  # the highest wins; a run that reached the first's maximum stopped there: no rival
            ranked = sorted(runs, key=lambda m: -m.contrast)
            best = ranked[0]
            rival = next((m for m in ranked[1:] if not m.stopped and not _same_solution(m.w_rad_s, best.w_rad_s)),
                         None)
        else:
            best = runs[0]
        w, v = best.w_rad_s, best.v_px_s
        if assess and li == len(levels) - 2:
            still = contrast(sub, np.zeros(3), v, geometry(li), gradient=False, lifted=lifted)
            gain = 1.0 - still / max(best.contrast, 1e-30)
            if rival is not None and _same_solution(rival.w_rad_s, w):
                rival = None
            elif rival is not None:
                margin = max(0.0, best.contrast - rival.contrast) / max(best.contrast - still, 1e-30)
    # the whole window only (the cross-check's parts search as they are); the contrast, the gain and
    # the margin stay those of the unfolded search's answer, which is the runner-up where it loses
    unfolded = w
    if assess and len(periodic):
        w = _folded_answer(ev, w, v, period_s, periodic, levels=levels, max_scale=max_scale, hemispheres=hemispheres)
        if not _same_solution(w, unfolded):
            rival = replace(best, w_rad_s=unfolded)
    w = _period_speed(w, period_s)
    if not assess:
        nan = float("nan")
        return FastResult(w, v, best.contrast, best.success, nan, None, nan, nan, nan, nan, nan, period_s)
    # half agreement at the second-last level's resolution and event count (as telling, 4x cheaper)
    agreement = _half_agreement(events_for_span(sub, 1e-9, np.inf, levels[-2][3]), w, v, geometry(len(levels) - 2))
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
                      agreement, margin, coverage_px, disc_fill, time_fill, period_s)
