"""Local maximisation of the IWE contrast: BFGS with the analytic gradient.

A dense BFGS on 3 (or 5) parameters with a backtracking line search, written out
here: a library L-BFGS costs more per step in bookkeeping than an objective on a
few hundred events does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spin.objective import BallEvents, IweGeometry, contrast, lift_moving


@dataclass(frozen=True)
class LocalMax:
    """Result of one local maximisation: ``w`` (rad/s, 3), ``v`` (px/s, 2), contrast, success.

    ``success``: the gradient fell below ``gtol`` or a step changed the contrast by less than
    ``ftol`` (relative) before the evaluation budget ran out.  ``stopped``: ended by
    :func:`maximise`'s ``stop_same`` (it reached the first start's maximum).
    """

    w_rad_s: np.ndarray
    v_px_s: np.ndarray
    contrast: float
    success: bool
    n_evaluations: int
    inverse_hessian: np.ndarray | None = None
    stopped: bool = False


class _Stop(Exception):
    """Thrown into a :func:`_bfgs` run to end it at its last accepted point."""


def _bfgs(x0: np.ndarray, *, max_evaluations: int, gtol: float = 1e-3, ftol: float = 1e-6, step0: float = 1.0,
          h0: np.ndarray | None = None):
    """Minimise a function from ``x0`` by BFGS, as a generator: it yields each point to evaluate and is
    sent back ``(value, gradient)``; it returns ``(x, value, converged, n_evaluations, h)``.

    Dense inverse-Hessian BFGS from ``h0`` if given; else the first step has length at
    most ``step0`` and the inverse Hessian is rescaled by ``s.y / y.y`` after it (as
    L-BFGS does).  Armijo backtracking (quadratic interpolation, at least a tenth of
    the step each time).  ``h`` is the last inverse-Hessian estimate (None if none was formed).
    Throwing :class:`_Stop` into it ends it at its last accepted point (not converged).
    """
    x = np.asarray(x0, dtype=np.float64)
    f, g = yield x
    n_eval = 1
    h = None if h0 is None else np.array(h0, dtype=np.float64)
    while n_eval < max_evaluations:
        gnorm = math.sqrt(g @ g)
        if gnorm < gtol:
            return x, f, True, n_eval, h
        p = -g * min(1.0, step0 / gnorm) if h is None else -(h @ g)
        slope = float(g @ p)
        if slope >= 0:  # not a descent direction (curvature lost): restart along the gradient
            h = None
            p = -g * min(1.0, step0 / gnorm)
            slope = float(g @ p)
        alpha = 1.0
        while True:
            x_new = x + alpha * p
            try:
                f_new, g_new = yield x_new
            except _Stop:
                return x, f, False, n_eval, h
            n_eval += 1
            if f_new <= f + 1e-4 * alpha * slope or n_eval >= max_evaluations:
                break
            # minimum of the quadratic through f, slope and f_new, kept within [0.1, 0.5] alpha
            alpha *= min(0.5, max(0.1, -slope * alpha / (2.0 * (f_new - f - slope * alpha))))
        if f_new > f:  # budget ran out inside a failed line search
            return x, f, False, n_eval, h
        s = x_new - x
        y = g_new - g
        sy = float(s @ y)
        converged = f - f_new <= ftol * max(abs(f), 1e-30)
        x, f, g = x_new, f_new, g_new
        if converged:
            return x, f, True, n_eval, h
        if sy > 1e-12:
            if h is None:
                h = np.eye(len(x)) * (sy / float(y @ y))
            rho = 1.0 / sy
            hy = h @ y
            # h - rho (s hy' + hy s') + (rho^2 y'hy + rho) s s', as two rank-one terms
            h = h + s[:, None] * ((rho * rho * float(y @ hy) + rho) * s - rho * hy) - rho * (hy[:, None] * s)
    return x, f, math.sqrt(g @ g) < gtol, n_eval, h


def maximise(ev: BallEvents, starts_w_rad_s, v0_px_s, geometry: IweGeometry, *, refine_velocity: bool = False,
             max_iterations: int = 40, ftol: float = 1e-6, inverse_hessians=None, lifted=None,
             stop_same=None) -> list[LocalMax]:
    """Maximise the contrast from each start by BFGS, at most ``2 * max_iterations`` evaluations each.

    The starts advance together: each round evaluates every start still going in one
    :func:`~spin.objective.contrast` pass (much cheaper than one pass per start on a few
    hundred events).  Parameters are scaled so that one unit moves the outermost events by
    about one blur width (``geometry.sigma``) over the events' time span; the objective is
    normalised by its starting value, so an inverse Hessian (in these units, for ``w``; e.g.
    a previous level's :attr:`LocalMax.inverse_hessian`) carries over between levels.

    Parameters
    ----------
    starts_w_rad_s : sequence of (3,)
        Starting angular velocities (rad/s).
    v0_px_s : (2,)
        Centre velocity (px/s), refined (one start only) with ``refine_velocity``.
    inverse_hessians : sequence of (3, 3) or None, optional
        One per start.
    lifted : tuple, optional
        ``lift_moving(ev, v0_px_s)`` if already computed (used only with a fixed velocity).
    stop_same : callable, optional
        ``stop_same(w, w_first) -> bool``: a start other than the first ends (not converged,
        :attr:`LocalMax.stopped`) once its latest point and the first start's latest point
        satisfy it (e.g. they reach the same maximum).
    """
    starts = [np.asarray(w, dtype=np.float64) for w in starts_w_rad_s]
    if refine_velocity and len(starts) != 1:
        raise ValueError("refine_velocity takes one start")
    v0 = np.asarray(v0_px_s, dtype=np.float64)
    span_s = max(float(ev.tau_s.max() - ev.tau_s.min()), 1e-6)
    reach_px = ev.radius_px * geometry.scale
    w_unit = geometry.sigma / (span_s * reach_px)
    v_unit = geometry.sigma / (span_s * geometry.scale)
    n_params = 5 if refine_velocity else 3
    if refine_velocity:
        lifted = None
    elif lifted is None:
        lifted = lift_moving(ev, v0)  # fixed velocity: lift the events once
    runs, norms = [], []
    for i in range(len(starts)):
        h0 = None
        if inverse_hessians is not None and inverse_hessians[i] is not None:
            h0 = np.eye(n_params) * float(np.trace(inverse_hessians[i])) / 3.0
            h0[:3, :3] = inverse_hessians[i]
        runs.append(_bfgs(np.zeros(n_params), max_evaluations=2 * max_iterations, ftol=ftol, h0=h0))
        norms.append(None)  # 1 / contrast at the start, set by the first evaluation
    pending = {i: run.send(None) for i, run in enumerate(runs)}
    done = {}
    stopped = set()
    latest = {}  # the latest point evaluated of each start (rad/s)
    while pending:
        order = list(pending)
        xs = [pending[i] for i in order]
        ws = np.array([starts[i] + x[:3] * w_unit for i, x in zip(order, xs)])
        latest.update(zip(order, ws))
        v = v0 + xs[0][3:5] * v_unit if refine_velocity else v0
        val, gw, gv = contrast(ev, ws, v, geometry, velocity_gradient=refine_velocity, lifted=lifted)
        for j, i in enumerate(order):
            if norms[i] is None:
                norms[i] = 1.0 / max(float(val[j]), 1e-30)
            g = -gw[j] * w_unit * norms[i]
            if refine_velocity:
                g = np.concatenate([g, -gv[j] * v_unit * norms[i]])
            try:
                pending[i] = runs[i].send((-float(val[j]) * norms[i], g))
            except StopIteration as stop:
                done[i] = stop.value
                del pending[i]
        if stop_same is not None:
            for i in [i for i in pending if i > 0 and stop_same(latest[i], latest[0])]:
                try:
                    runs[i].throw(_Stop)
                except StopIteration as stop:
                    done[i] = stop.value
                del pending[i]
                stopped.add(i)
    out = []
    for i, w0 in enumerate(starts):
        x, f, converged, n_eval, h = done[i]
        v = v0 + x[3:5] * v_unit if refine_velocity else v0
        out.append(LocalMax(w0 + x[:3] * w_unit, np.asarray(v, dtype=np.float64), float(-f / norms[i]), converged,
                            n_eval, None if h is None else h[:3, :3], i in stopped))
    return out
