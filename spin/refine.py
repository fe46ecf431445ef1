"""Local maximisation of the IWE contrast with L-BFGS and the analytic gradient."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from threadpoolctl import ThreadpoolController

from spin.objective import BallEvents, IweGeometry, contrast, lift_moving


# L-BFGS-B's few-parameter BLAS calls are ~50x slower with BLAS worker threads (each call wakes and
# syncs them); a controller made once makes the per-call limit cheap (~10 µs)
_BLAS = ThreadpoolController()


@dataclass(frozen=True)
class LocalMax:
    """Result of one local maximisation: ``w`` (rad/s, 3), ``v`` (px/s, 2), contrast, success.

    ``success``: the optimiser's own test passed, or the final gradient is below 1 % of the
    contrast per blur width (at the peak to a small fraction of the blur).
    """

    w_rad_s: np.ndarray
    v_px_s: np.ndarray
    contrast: float
    success: bool
    n_evaluations: int


def maximise(ev: BallEvents, w0_rad_s, v0_px_s, geometry: IweGeometry, *, refine_velocity: bool = False,
             max_iterations: int = 40) -> LocalMax:
    """Maximise the contrast from ``(w0, v0)`` with L-BFGS-B.

    Parameters are scaled so that one unit moves the outermost events by about one
    blur width (``geometry.sigma``) over the events' time span; the objective is
    normalised by its starting value.
    """
    w0 = np.asarray(w0_rad_s, dtype=np.float64)
    v0 = np.asarray(v0_px_s, dtype=np.float64)
    span_s = max(float(ev.tau_s.max() - ev.tau_s.min()), 1e-6)
    reach_px = ev.radius_px * geometry.scale
    w_unit = geometry.sigma / (span_s * reach_px)
    v_unit = geometry.sigma / (span_s * geometry.scale)
    n_params = 5 if refine_velocity else 3
    norm = None  # 1 / contrast at the start, set by the first evaluation
    lifted = None if refine_velocity else lift_moving(ev, v0)  # fixed velocity: lift the events once

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

    with _BLAS.limit(limits=1, user_api="blas"):
        res = minimize(fun, np.zeros(n_params), jac=True, method="L-BFGS-B",
                       options={"maxiter": max_iterations, "maxfun": 2 * max_iterations, "gtol": 1e-5,
                                "ftol": 1e-9})
    w, v = unpack(res.x)
    success = bool(res.success) or float(np.linalg.norm(res.jac)) < 1e-2
    return LocalMax(w, np.asarray(v, dtype=np.float64), float(-res.fun / norm), success, int(res.nfev))
