"""Rotations about an axis (right-hand rule, camera frame of ``docs/conventions.md``)."""

from __future__ import annotations

import numpy as np


def unit(v) -> np.ndarray:
    """``v`` scaled to unit length; raises ``ValueError`` for a zero vector."""
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n == 0.0:
        raise ValueError(f"axis must be a non-zero finite 3-vector, got {v.tolist()}")
    return v / n


def skew(v) -> np.ndarray:
    """Cross-product matrix ``[v]x`` (3, 3) with ``[v]x @ r == cross(v, r)``."""
    x, y, z = np.asarray(v, dtype=np.float64).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def axis_angle_matrices(axis, angles_rad) -> np.ndarray:
    """Rotation matrices ``exp(angle [axis]x)`` (Rodrigues), shape (K, 3, 3).

    Parameters
    ----------
    axis : array_like, shape (3,) or (K, 3)
        Rotation axis, shared or one per angle (normalised here).
    angles_rad : array_like, shape (K,)
        Rotation angles in radians; positive angles turn counter-clockwise when
        looking down the axis (right-hand rule).
    """
    a = np.atleast_1d(np.asarray(angles_rad, dtype=np.float64))
    s = np.sin(a)[:, None, None]
    c = np.cos(a)[:, None, None]
    axis = np.asarray(axis, dtype=np.float64)
    if axis.ndim == 1:
        k = skew(unit(axis))[None]
    else:
        n = axis / np.linalg.norm(axis, axis=1, keepdims=True)
        k = np.zeros((len(n), 3, 3))
        k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -n[:, 2], n[:, 1], -n[:, 0]
        k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = n[:, 2], -n[:, 1], n[:, 0]
    return np.eye(3)[None] + s * k + (1.0 - c) * (k @ k)


def random_axes(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` unit vectors drawn uniformly on the sphere, shape (n, 3)."""
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation matrix (3, 3)."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
