"""A flight's spin from all of its events, at the speed its image's period allows.

A window of a few milliseconds shows a sparse texture (two seams, one logo) from one side only, and
its contrast is often highest at a wrong axis. A flight shows the ball from every side, many turns
over: placed on the ball's own surface, its events pile up on the texture's edges at the right spin
and spread evenly at any other. Each event is placed on the disc of the track at its own time
(:func:`spin.period.on_track_disc`), lifted onto the camera-facing half of the unit sphere
(orthographically, as the window estimator without a camera), turned back by the angle the ball
turned since the first event, and counted in a map of the surface (:func:`spin._kernels.sphere_contrast`).
The speed comes from the image's period (:func:`spin.period.flight_period`): one turn per 1-6 repeats
(:data:`FOLDS`), the fold whose map is sharpest; the axis from a scan of the whole sphere, refined
around the best.

The answer holds for a spin that stays the same through the flight (a ball in free flight); a
flight whose spin changes (a bounce, a hit inside one track) gives no sharp map at any axis. It is
trusted where the map is much sharper at the answer than at its rival (the best axis more than
:data:`RIVAL_DEG` away or at another fold) and than with the events' turns shuffled among them
(:data:`TRUST_EXCESS`), and where the flight holds enough turns (:data:`TRUST_TURNS`). Its rate alone, the
fold of the period, stands where the map is sharper at that fold than at any other (:data:`TRUST_FOLD_RATIO`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spin import _kernels
from spin.lens import centring_rotation
from spin.search import fibonacci_sphere

FOLDS = (1, 2, 3, 4, 5, 6)
"""Turns per period tried: one turn is 1-6 repeats of the image (a soccer ball about a five-fold axis)."""
SCAN = (24, 200, 4_000)
"""The whole sphere's scan, per fold: the map's cells across its cube (24: 5 deg of the ball each), axes
(14 deg apart) and events (an even subsample). With 16 cells a broad peak about the line of sight (a ring of
shading, partly textured) outscored the scan's axes near a sparse ball's true one, whose peak is narrow, and
took every refined candidate: a table-tennis ball of held-out seed 11 was trusted 68 deg off, though the map
is sharper at the truth at every grid (the scan's axis nearest it, 8.5 deg away, ranked 19th of 200; more
events or 400 and 800 axes did not help). With 24 cells an axis 12 deg from it ranked first; on the bench's
tracked flights of seeds 1-12 three more answers came out right and none worse (see README), at the same cost."""
REFINE = ((15.0, 24, 100, 8_000), (6.0, 40, 100, 30_000))
"""Then around each of the :data:`REFINED` best: axes within a cap (deg), cells, axes, events (about 1.5 deg
apart, then 0.6 deg). Chosen on the tuning flights (below) among five settings: a finer last map (40 cells
against 32) took the right answers' median error from 1.3 to 1.2 deg and left no trusted answer wrong, at
0.22 s per flight (one core); a scan of 300 axes and 6,000 events found one more flight's fold, at 0.27 s."""
SPEED_SPAN = 0.015
SPEED_DRIFT_DEG = 5.0
MAX_SPEEDS = 201
"""The speed is refined over the period's speed +- ``SPEED_SPAN`` (a share), in steps that turn the ball
``SPEED_DRIFT_DEG`` further over the flight (at most ``MAX_SPEEDS`` speeds)."""
REFINED = 3
"""Candidates refined: the highest of each fold's best axis and of its best more than ``RIVAL_DEG`` away."""
RIVAL_DEG = 30.0
TRUST_RATIO = 1.3
"""A flight's spin is trusted where its map is at least this much sharper than at its rival. Set on the
tuning flights of ``bench/spin_bench.py --flights`` (seeds 1, 2; 40 flights with a period): the two wrong
answers scored 1.02 and 1.16, the right ones 1.39 and more."""
TRUST_EXCESS = 5.0
"""... and where the map's sharpness above 1 (unrelated places) is at least this many times that of the same
map with the events' turns shuffled among them. Events that keep their distance from the ball's centre
(a ring, the shading's edge) pile up about an axis along the line of sight whatever the ball does: on a
ball with little texture such an axis can win (a table-tennis ball 52 deg off at a ratio of 2.35 in the
first held-out set, seeds 3, 4). On the tuning flights the three answers with such an axis (within 26 deg
of the line of sight), all wrong, scored 1.1, 1.2 (and the held-out one 4.2); the right ones 6.6 and more.
Chosen after that held-out set was seen: seeds 5, 6 are the held-out set for it."""
NULL_FLOOR = 0.05
"""The shuffled map's sharpness above 1 counts as at least this (most shuffled maps score about 1: without
a floor the excess of a map barely sharper than 1 would be arbitrary)."""
TRUST_TURNS = 6.0
"""... and where the flight turns at least this many times (the rate, from the period, holds with fewer).
Over few turns the map pins the axis less; and where a ball turns slowly its drift across the image moves
an edge as much as its turn does, so the edge's events change polarity through a turn and the signed map
cancels them at the right axis (a soccer ball at 10 rps, 3.5 turns, scored 39 at its axis against 61 and
59 four degrees either side, and was trusted 17 deg off). At 10 rps (3.4-3.7 turns in the flights of
``bench/spin_bench.py --flights``) the answers that passed the other checks were 0.5-3.1 deg off on the
tuning seeds (1, 2), 1.8-4.5 deg and that soccer ball on seeds 3, 4, and 0.7-7.2 deg on seeds 5, 6 (two of
nine beyond 5 deg), all seen before this rule; at 30 rps (10 turns) and faster at most 3.2 deg (tuning).
On seeds 7, 8, made afterwards, all nine such answers were right (0.5-3.2 deg): 4 wrong of 37 over seeds
1-8, where a trusted answer must be right in 99 %."""
TRUST_FOLD_RATIO = 1.1
"""The rate alone (the fold of the period that is one turn) stands where the whole sphere's scan is at least
this much sharper at the answer's fold than at any other, whatever the axis's checks say: a slow ball's few
turns, or a texture whose axis the map cannot pin, still tell one fold from the others. On the tuning flights
(seeds 1, 2 of ``bench/spin_bench.py --flights``, 49 with a period) every fold was right; the two below this,
at 1.01 and 1.06, were balls whose map peaked about an axis near the line of sight (36 and 78 deg off, the
rings of the shading's edge, sharp at every speed), the lowest above it a soccer ball at fold 5 (1.17)."""
AXIS_SIGMA_DEG = 1.8
"""1-sigma axis uncertainty (deg) of an answer: its error comes mostly from the map's cells and the
track's circle, not from the events' number (the flight's two halves in time, refitted apart, agreed
to a tenth of a degree where the answer was 2-3 deg off). On the tuning flights the right answers' errors
were 1.2 deg at the median, 2.2 at the 90th percentile, 3.2 at most."""


@dataclass(frozen=True)
class FlightSpin:
    """A flight's spin from all its events: ``axis`` (3,) unit vector (camera frame), ``omega_rad_s``,
    ``fold`` (the image repeats this many times a turn), ``ratio`` (the map's sharpness at the answer over
    its rival's), ``excess`` (its sharpness above 1 over that of the map with the events' turns shuffled),
    ``trusted`` (``ratio >= TRUST_RATIO``, ``excess >= TRUST_EXCESS`` and ``turns >= TRUST_TURNS``),
    ``axis_sigma_deg`` and ``rps_sigma_pct`` (1 sigma), ``turns`` (turns through the events at the answer's
    speed), ``fold_ratio`` (the whole-sphere scan's best sharpness at the answer's fold over its best at any
    other fold) and ``rate_trusted`` (the fold, hence the rate, stands: ``trusted`` or
    ``fold_ratio >= TRUST_FOLD_RATIO``, whatever the axis)."""

    axis: np.ndarray
    omega_rad_s: float
    fold: int
    ratio: float
    excess: float
    trusted: bool
    axis_sigma_deg: float
    rps_sigma_pct: float
    turns: float
    fold_ratio: float
    rate_trusted: bool

    @property
    def rps(self) -> float:
        return self.omega_rad_s / (2.0 * math.pi)


def cap_axes(centre: np.ndarray, radius_deg: float, n: int) -> np.ndarray:
    """``centre`` (3,) and ``n`` unit vectors spread evenly within ``radius_deg`` of it, (n + 1, 3)."""
    i = np.arange(n) + 0.5
    z = 1.0 - (1.0 - math.cos(math.radians(radius_deg))) * i / n
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    rho = np.sqrt(1.0 - z * z)
    a = centre / np.linalg.norm(centre)
    e1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return np.vstack([a, np.outer(rho * np.cos(phi), e1) + np.outer(rho * np.sin(phi), e2) + np.outer(z, a)])


def flight_spin(t_us, x_px, y_px, p, cx_px, cy_px, r_px, period_s: float, *, period_sigma_pct: float,
                ray=None) -> FlightSpin | None:
    """The spin of a flight (constant through it) from its events and its image's period.

    Parameters
    ----------
    t_us, x_px, y_px, p : ndarray (N,)
        Time-sorted events of the ball (µs, px, polarity 0/1), e.g. those within
        ``spin.period.FLIGHT_INNER`` of the track's circle (:func:`spin.period.on_track_disc`).
    cx_px, cy_px, r_px : ndarray (N,)
        The ball's circle at each event's time (px).
    period_s : float
        The period over which the ball's image repeats (:func:`spin.period.flight_period`), s.
    period_sigma_pct : float
        Its 1-sigma uncertainty (%): the rate's at one turn per repeat; an answer at fold k (the image
        repeating k times a turn, a near-symmetry of its texture) has k times it.
    ray : array_like (3,), optional
        The direction from the camera to the ball (camera frame; a pinhole's ray through the track's
        middle): the answer, found about that line of sight, is turned into the camera frame. None: the
        optical axis (orthographic).

    Returns
    -------
    FlightSpin or None
        None where there are fewer than 100 events or the period is not positive.
    """
    n = len(t_us)
    if n < 100 or not period_s > 0:
        return None
    keep = np.arange(0, n, max(1, n // REFINE[-1][3]))
    r = np.asarray(r_px, np.float64)[keep]
    u = (np.asarray(x_px, np.float64)[keep] - cx_px[keep]) / r
    v = (np.asarray(y_px, np.float64)[keep] - cy_px[keep]) / r
    w = -np.sqrt(np.clip(1.0 - u * u - v * v, 0.0, None))
    t_s = (np.asarray(t_us, np.int64)[keep] - int(t_us[0])) * 1e-6
    pol = (np.asarray(p)[keep] > 0).astype(np.int8)
    points = (u, v, w)

    def score(axes, cos_a, sin_a, n_cells, n_events):
        """The map's sharpness at ``axes`` for an even subsample of about ``n_events`` of the events."""
        step = max(1, len(u) // n_events)
        return _kernels.sphere_contrast(*(np.ascontiguousarray(a[::step]) for a in (*points, cos_a, sin_a, pol)),
                                        axes, n_cells)

    n_cells, n_axes, n_events = SCAN
    axes = fibonacci_sphere(n_axes).copy()  # (a writable copy: one compiled signature of the kernel)
    found = []  # per fold: its best axis, and the best more than RIVAL_DEG from it
    fold_top = {}  # per fold: the scan's best score
    for fold in FOLDS:
        omega = 2.0 * math.pi / (fold * period_s)
        angle = -omega * t_s  # turned back to the first event's time
        trig = (np.cos(angle), np.sin(angle))
        scan = score(axes, *trig, n_cells, n_events)
        top = int(np.argmax(scan))
        apart = np.flatnonzero(np.degrees(np.arccos(np.clip(axes @ axes[top], -1.0, 1.0))) > RIVAL_DEG)
        other = int(apart[np.argmax(scan[apart])])
        fold_top[fold] = float(scan[top])
        found += [dict(fold=fold, omega=omega, trig=trig, axis=axes[k], score=float(scan[k])) for k in (top, other)]
    refined = sorted(found, key=lambda c: -c["score"])[:REFINED]
    for c in refined:
        for cap_deg, n_cells, n_axes, n_events in REFINE:
            near = cap_axes(c["axis"], cap_deg, n_axes)
            fine = score(near, *c["trig"], n_cells, n_events)
            c["axis"], c["score"] = near[int(np.argmax(fine))], float(fine.max())
    best = max(refined, key=lambda c: c["score"])
    rivals = [c["score"] for c in refined if c["fold"] != best["fold"]
              or np.degrees(np.arccos(np.clip(c["axis"] @ best["axis"], -1.0, 1.0))) > RIVAL_DEG]
    ratio = best["score"] / max(max(rivals, default=0.0), 1e-12)
    fold_ratio = fold_top[best["fold"]] / max(max(v for f, v in fold_top.items() if f != best["fold"]), 1e-12)
    # the period may be a little off (a steep arc across a small sensor: up to about 1 %), and over many
    # turns that blurs the map: the speed is refined at the axis found, and the axis again at that speed
    cap_deg, n_cells, n_axes, n_events = REFINE[-1]
    span_turns = best["omega"] * float(t_s[-1]) / (2.0 * math.pi)
    n_speeds = min(2 * max(1, int(math.ceil(SPEED_SPAN * span_turns * 360.0 / SPEED_DRIFT_DEG))) + 1, MAX_SPEEDS)
    speeds = best["omega"] * (1.0 + np.linspace(-SPEED_SPAN, SPEED_SPAN, n_speeds))
    step = max(1, len(t_s) // (n_events // 2))
    sub = [np.ascontiguousarray(a[::step]) for a in (*points, pol, t_s)]
    at_speed = [_kernels.sphere_contrast(*sub[:3], np.cos(-w_s * sub[4]), np.sin(-w_s * sub[4]), sub[3],
                                         best["axis"][None, :], n_cells)[0] for w_s in speeds]
    middle = n_speeds // 2  # (the period's own speed, where the map cannot tell: events all at one time)
    omega = float(speeds[max(range(n_speeds), key=lambda i: (at_speed[i], -abs(i - middle)))])
    near = cap_axes(best["axis"], cap_deg / 2.0, n_axes)
    cos_a, sin_a = np.cos(-omega * t_s), np.sin(-omega * t_s)
    fine = score(near, cos_a, sin_a, n_cells, n_events)
    axis, fold = near[int(np.argmax(fine))], best["fold"]
    # the same map with the events' turns shuffled among them: what the events' places on the disc alone
    # give (a ring of events round the centre stays a ring about an axis along the line of sight)
    shuffled = np.random.default_rng(0).permutation(len(t_s))
    null = score(axis[None, :], cos_a[shuffled], sin_a[shuffled], n_cells, n_events)[0]
    excess = (float(fine.max()) - 1.0) / max(float(null) - 1.0, NULL_FLOOR)
    turns = span_turns * omega / best["omega"]  # at the refined speed
    if ray is not None:  # found about the line of sight (its Z): turned back into the camera frame
        ray = np.asarray(ray, np.float64)
        axis = centring_rotation(ray / np.linalg.norm(ray)).T @ axis
    trusted = ratio >= TRUST_RATIO and excess >= TRUST_EXCESS and turns >= TRUST_TURNS
    return FlightSpin(axis=axis, omega_rad_s=omega, fold=fold, ratio=ratio, excess=excess, trusted=trusted,
                      axis_sigma_deg=AXIS_SIGMA_DEG, rps_sigma_pct=float(fold * period_sigma_pct), turns=turns,
                      fold_ratio=fold_ratio, rate_trusted=trusted or fold_ratio >= TRUST_FOLD_RATIO)
