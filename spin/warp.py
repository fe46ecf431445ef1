"""Lift ball events onto the sphere and rotate them to a reference time.

Geometry (see ``docs/conventions.md``): camera frame X right, Y down, Z forward.
An event at pixel ``(x, y)`` and time ``t`` on a ball of radius ``r`` whose
centre moves as ``c(t) = c0 + v (t - t0)`` is lifted to the visible (camera-facing)
half of the sphere::

    p = (x - cx(t), y - cy(t), -sqrt(r^2 - dx^2 - dy^2))

A surface point moves with ``dp/dt = omega * cross(n, p)``, so the point seen at
``t_k`` is at ``R(n, omega (t_ref - t_k)) p`` at ``t_ref``.  This module gives the seed
paper's quaternion form; the estimator evaluates the same rotation in Rodrigues form
(:func:`spin.objective.warp`), and the two agree to rounding.
"""

from __future__ import annotations

import numpy as np


def rotate_quaternion(points: np.ndarray, axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rotate ``points`` (N, 3) by ``angle_rad`` (N,) about unit ``axis`` ((3,) or (N, 3)): ``p' = q p q*``.

    ``q = (cos(a/2), axis sin(a/2))``; evaluated as ``p' = p + 2 s (u x p) + 2 u x (u x p)``
    with ``s = cos(a/2)``, ``u = axis sin(a/2)`` (the expanded Hamilton product).
    """
    half = 0.5 * np.asarray(angle_rad)[:, None]
    s = np.cos(half)
    u = np.asarray(axis, dtype=np.float64) * np.sin(half)
    uxp = np.cross(u, points)
    return points + 2.0 * s * uxp + 2.0 * np.cross(u, uxp)
