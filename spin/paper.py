"""The seed paper's estimator: joint (axis, omega, velocity) by Adam on the IWE variance.

Faithful settings: up to 50,000 events inside the circle, IWE at sensor
resolution (1 IWE px per px, Gaussian sigma 1 px), variance objective, Adam with
1,500 iterations over the unit axis ``n`` (renormalised), ``omega`` and ``v``
jointly; events are rotated to the middle of the window (as in the fast method).
The paper does not describe a global initialisation; here it starts from the same
coarse grid search as the fast method (:mod:`spin.search`), best point only, so
both methods see the same start.  On short windows (little rotation) the joint
velocity trades off against rotation about in-image axes, which is what limits
this method's axis accuracy in the benchmark.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spin.objective import BallEvents, IweGeometry, contrast

PAPER_EVENTS = 50_000
PAPER_ITERATIONS = 1500


@dataclass(frozen=True)
class PaperResult:
    w_rad_s: np.ndarray
    v_px_s: np.ndarray
    contrast: float
    converged: bool


def estimate_paper(ev: BallEvents, w0_rad_s, v0_px_s, *, iterations: int = PAPER_ITERATIONS,
                   learning_rate: float = 0.01, final_learning_rate: float = 0.0005) -> PaperResult:
    """Adam ascent on the IWE variance from ``w0`` (rad/s) and ``v0`` (px/s).

    Parameters are ``(n (3), omega / omega0, v / v_scale)`` with ``v_scale`` = one
    ball radius per window; the learning rate decays exponentially from
    ``learning_rate`` to ``final_learning_rate``.  ``converged`` is true when the
    last 10 % of iterations changed omega by less than 0.5 %.
    """
    geometry = IweGeometry(ev.radius_px, 1.0, 1.0, False)
    w0 = np.asarray(w0_rad_s, dtype=np.float64)
    omega0 = max(float(np.linalg.norm(w0)), 1e-3)
    span_s = max(float(ev.s_s.max() - ev.s_s.min()), 1e-6)
    v_scale = ev.radius_px / span_s
    x = np.concatenate([w0 / omega0, [1.0], np.asarray(v0_px_s, dtype=np.float64) / v_scale])
    m = np.zeros_like(x)
    s = np.zeros_like(x)
    b1, b2, eps = 0.9, 0.999, 1e-8
    decay = (final_learning_rate / learning_rate) ** (1.0 / max(iterations - 1, 1))
    history = np.empty(iterations)
    value = 0.0
    for k in range(iterations):
        norm = np.linalg.norm(x[:3])
        n = x[:3] / norm
        omega = x[3] * omega0
        value, gw, gv = contrast(ev, omega * n, x[4:6] * v_scale, geometry)
        gn = omega * gw  # d f / d n_hat
        grad = np.concatenate([(gn - n * np.dot(n, gn)) / norm, [np.dot(n, gw) * omega0], gv * v_scale])
        grad = -grad / max(value, 1e-30)  # minimise -f, scale-free
        m = b1 * m + (1 - b1) * grad
        s = b2 * s + (1 - b2) * grad * grad
        mh = m / (1 - b1 ** (k + 1))
        sh = s / (1 - b2 ** (k + 1))
        x = x - learning_rate * decay ** k * mh / (np.sqrt(sh) + eps)
        history[k] = x[3]
    n = x[:3] / np.linalg.norm(x[:3])
    w = x[3] * omega0 * n
    tail = history[-max(iterations // 10, 1):]
    converged = bool(np.ptp(tail) < 0.005 * abs(tail[-1]))
    return PaperResult(w, x[4:6] * v_scale, float(value), converged)
