"""Lift ball events onto the sphere and rotate them to a reference time.

Geometry (see ``docs/conventions.md``): camera frame X right, Y down, Z forward.
An event at pixel ``(x, y)`` and time ``t`` on a ball of radius ``r`` whose
centre moves as ``c(t) = c0 + v (t - t0)`` is lifted to the visible (camera-facing)
half of the sphere::

    p = (x - cx(t), y - cy(t), -sqrt(r^2 - dx^2 - dy^2))

A surface point moves with ``dp/dt = omega * cross(n, p)``, so the point seen at
``t_k`` is at ``R(n, omega (t_ref - t_k)) p`` at ``t_ref``.  Both the quaternion form
of the seed paper and the Rodrigues form are provided; they agree to rounding.
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


def rotate_rodrigues(points: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    """Rotate ``points`` (N, 3) by rotation vectors ``rotvec`` (N, 3) (axis * angle, rad).

    ``p' = p + a (theta x p) + b theta x (theta x p)`` with ``a = sin(phi)/phi`` and
    ``b = (1 - cos(phi))/phi^2`` (Rodrigues' formula, safe at ``phi = 0``).
    """
    out = rotate(tuple(points.T), tuple(np.asarray(rotvec, dtype=points.dtype).T))
    return np.stack(out, axis=-1)


def cross(a, b):
    """Cross product of two vectors given as component tuples ``(x, y, z)`` of arrays."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def rotation_coefficients(theta):
    """Rodrigues coefficients ``a = sin(phi)/phi`` and ``b = (1 - cos(phi))/phi^2`` of rotation vectors."""
    phi2 = theta[0] * theta[0] + theta[1] * theta[1] + theta[2] * theta[2]
    phi = np.sqrt(phi2)
    small = phi < 1e-2
    safe = np.where(small, 1.0, phi)
    a = np.where(small, 1.0 - phi2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - phi2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    return a, b


def rotate(p, theta):
    """Rotate points ``p`` by rotation vectors ``theta`` (component tuples of (N,) arrays); returns the components."""
    a, b = rotation_coefficients(theta)
    txp = cross(theta, p)
    txtxp = cross(theta, txp)
    return tuple(p[i] + a * txp[i] + b * txtxp[i] for i in range(3))
