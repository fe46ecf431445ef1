"""Local maximisation of the IWE contrast: BFGS with the analytic gradient.

A dense BFGS on 3 (or 5) parameters with a backtracking line search, written out
here: a library L-BFGS costs more per step in bookkeeping than an objective on a
few hundred events does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spin.objective import BallEvents, IweGeometry, contrast, lift_moving


@dataclass(frozen=True)
class LocalMax:
    """Result of one local maximisation: ``w`` (rad/s, 3), ``v`` (px/s, 2), contrast, success.

    ``success``: the gradient fell below ``gtol`` or a step changed the contrast by less than
    ``ftol`` (relative) before the evaluation budget ran out.
    """

    w_rad_s: np.ndarray
    v_px_s: np.ndarray
    contrast: float
    success: bool
    n_evaluations: int
    inverse_hessian: np.ndarray | None = None


def bfgs_minimise(fun, x0: np.ndarray, *, max_evaluations: int, gtol: float = 1e-3, ftol: float = 1e-6,
                  step0: float = 1.0, h0: np.ndarray | None = None, stop=None):
    """Minimise ``fun(x) -> (value, gradient)`` from ``x0``.

    Dense inverse-Hessian BFGS from ``h0`` if given; else the first step has length at
    most ``step0`` and the inverse Hessian is rescaled by ``s.y / y.y`` after it (as
    L-BFGS does).  Armijo backtracking (quadratic interpolation, at least a tenth of
    the step each time).  ``stop(x)``, if given, ends the search after a step where it is
    true (returned as not converged).  Returns ``(x, value, gradient, converged, n_eval, h)`` with
    ``h`` the last inverse-Hessian estimate (None if none was formed).
    """
    x = np.asarray(x0, dtype=np.float64)
    f, g = fun(x)
    n_eval = 1
    h = None if h0 is None else np.array(h0, dtype=np.float64)
    while n_eval < max_evaluations:
        gnorm = float(np.sqrt(g @ g))
        if gnorm < gtol:
            return x, f, g, True, n_eval, h
        p = -g * min(1.0, step0 / gnorm) if h is None else -(h @ g)
        slope = float(g @ p)
        if slope >= 0:  # not a descent direction (curvature lost): restart along the gradient
            h = None
            p = -g * min(1.0, step0 / gnorm)
            slope = float(g @ p)
        alpha = 1.0
        while True:
            x_new = x + alpha * p
            f_new, g_new = fun(x_new)
            n_eval += 1
            if f_new <= f + 1e-4 * alpha * slope or n_eval >= max_evaluations:
                break
            # minimum of the quadratic through f, slope and f_new, kept within [0.1, 0.5] alpha
            alpha *= min(0.5, max(0.1, -slope * alpha / (2.0 * (f_new - f - slope * alpha))))
        if f_new > f:  # budget ran out inside a failed line search
            return x, f, g, False, n_eval, h
        s = x_new - x
        y = g_new - g
        sy = float(s @ y)
        converged = f - f_new <= ftol * max(abs(f), 1e-30)
        x, f, g = x_new, f_new, g_new
        if converged:
            return x, f, g, True, n_eval, h
        if stop is not None and stop(x):
            return x, f, g, False, n_eval, h
        if sy > 1e-12:
            if h is None:
                h = np.eye(len(x)) * (sy / float(y @ y))
            rho = 1.0 / sy
            hy = h @ y
            h = h - rho * (np.outer(s, hy) + np.outer(hy, s)) + (rho * rho * float(y @ hy) + rho) * np.outer(s, s)
    return x, f, g, float(np.sqrt(g @ g)) < gtol, n_eval, h


def maximise(ev: BallEvents, w0_rad_s, v0_px_s, geometry: IweGeometry, *, refine_velocity: bool = False,
             max_iterations: int = 40, ftol: float = 1e-6, inverse_hessian=None, stop_w=None,
             lifted=None) -> LocalMax:
    """Maximise the contrast from ``(w0, v0)`` with BFGS, at most ``2 * max_iterations`` evaluations.

    Parameters are scaled so that one unit moves the outermost events by about one
    blur width (``geometry.sigma``) over the events' time span; the objective is
    normalised by its starting value, so an ``inverse_hessian`` (in these units, for ``w``;
    e.g. a previous level's :attr:`LocalMax.inverse_hessian`) carries over between levels.
    ``stop_w(w_rad_s) -> bool``, if given, ends the search after a step to a ``w`` where it is true.
    ``lifted``: ``lift_moving(ev, v0_px_s)`` if already computed (used only with a fixed velocity).
    """
    w0 = np.asarray(w0_rad_s, dtype=np.float64)
    v0 = np.asarray(v0_px_s, dtype=np.float64)
    span_s = max(float(ev.tau_s.max() - ev.tau_s.min()), 1e-6)
    reach_px = ev.radius_px * geometry.scale
    w_unit = geometry.sigma / (span_s * reach_px)
    v_unit = geometry.sigma / (span_s * geometry.scale)
    n_params = 5 if refine_velocity else 3
    norm = None  # 1 / contrast at the start, set by the first evaluation
    if refine_velocity:
        lifted = None
    elif lifted is None:
        lifted = lift_moving(ev, v0)  # fixed velocity: lift the events once

    def unpack(x):
        return w0 + x[:3] * w_unit, (v0 + x[3:5] * v_unit) if refine_velocity else v0

    def fun(x):
        nonlocal norm
        w, v = unpack(x)
        val, gw, gv = contrast(ev, w, v, geometry, velocity_gradient=refine_velocity, lifted=lifted)
        if norm is None:
            norm = 1.0 / max(val, 1e-30)
        g = -gw * w_unit * norm
        if refine_velocity:
            g = np.concatenate([g, -gv * v_unit * norm])
        return -val * norm, g

    h0 = None
    if inverse_hessian is not None:
        h0 = np.eye(n_params) * float(np.trace(inverse_hessian)) / 3.0
        h0[:3, :3] = inverse_hessian
    x, f, _, converged, n_eval, h = bfgs_minimise(fun, np.zeros(n_params), max_evaluations=2 * max_iterations,
                                                  ftol=ftol, h0=h0,
                                                  stop=None if stop_w is None else (lambda x: stop_w(unpack(x)[0])))
    w, v = unpack(x)
    return LocalMax(w, np.asarray(v, dtype=np.float64), float(-f / norm), converged, n_eval,
                    None if h is None else h[:3, :3])
