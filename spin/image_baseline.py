"""Image-based spin baseline after Tamaki et al.: two-frame registration on the sphere.

The ball pixels of frame N are lifted onto the sphere, rotated by ``omega * dt``
about ``n`` (quaternion form), moved by ``v * dt``, projected orthographically and
compared with frame N+1; the sum of squared differences is minimised over the
rotation vector ``theta = omega * dt * n`` (and optionally ``v``).  A frame pair can only
resolve ``|theta| < pi``: faster spins alias, which is why the method degrades with
rps at a fixed frame rate.  Used by the benchmark only.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.optimize import least_squares

from spin.search import fibonacci_sphere
from spin.warp import rotate_quaternion


def _ball_pixels(image, center, radius_px, fraction, max_pixels, rng):
    h, w = image.shape
    cx, cy = center
    ys, xs = np.mgrid[max(0, int(cy - radius_px)):min(h, int(cy + radius_px) + 2),
                      max(0, int(cx - radius_px)):min(w, int(cx + radius_px) + 2)]
    dx, dy = xs.ravel() - cx, ys.ravel() - cy
    keep = dx * dx + dy * dy <= (fraction * radius_px) ** 2
    dx, dy = dx[keep], dy[keep]
    if max_pixels is not None and len(dx) > max_pixels:
        pick = rng.choice(len(dx), max_pixels, replace=False)
        dx, dy = dx[pick], dy[pick]
    z = -np.sqrt(np.maximum(radius_px ** 2 - dx * dx - dy * dy, 0.0))
    values = image[(dy + cy).round().astype(int), (dx + cx).round().astype(int)].astype(np.float64)
    return np.stack([dx, dy, z], axis=1), values


def _residuals(theta, points, values, image1, center1, scale):
    angle = float(np.linalg.norm(theta))
    axis = theta / angle if angle > 0 else np.array([0.0, 0.0, 1.0])
    q = rotate_quaternion(points, axis, np.full(len(points), angle)) * scale
    visible = q[:, 2] < 0
    x = q[:, 0] + center1[0]
    y = q[:, 1] + center1[1]
    sampled = map_coordinates(image1, [y, x], order=1, mode="nearest")
    # pixels rotated out of view are predicted by the mean brightness (hiding them must not pay)
    return np.where(visible, values - sampled, values - values.mean())


def _grid_residuals(angle, directions, points, values, image1, center1, scale):
    """:func:`_residuals` for rotation ``angle`` about each of ``directions`` (D, 3); returns (D, P)."""
    d = len(directions)
    pts = np.broadcast_to(points, (d, *points.shape)).reshape(-1, 3)
    q = rotate_quaternion(pts, np.repeat(directions, len(points), axis=0), np.full(len(pts), angle)) * scale
    sampled = map_coordinates(image1, [q[:, 1] + center1[1], q[:, 0] + center1[0]], order=1, mode="nearest")
    res = np.where(q[:, 2] < 0, np.tile(values, d) - sampled, np.tile(values - values.mean(), d))
    return res.reshape(d, len(points))


def estimate_image_pair(frame0, frame1, dt_s: float, circle0, circle1, *, n_directions: int = 300,
                        n_angles: int = 24, grid_pixels: int = 1500, seed: int = 0):
    """Angular velocity (rad/s, (3,)) registering ``frame1`` to ``frame0``.

    Parameters
    ----------
    frame0, frame1 : ndarray (H, W)
        Grey images.
    dt_s : float
        Time between the frames, s.
    circle0, circle1 : (cx, cy, r)
        Ball circles (px) in the two frames (the translation comes from them).
    """
    rng = np.random.default_rng(seed)
    f0 = np.asarray(frame0, dtype=np.float64)
    f1 = np.asarray(frame1, dtype=np.float64)
    c0, r0 = circle0[:2], float(circle0[2])
    c1, r1 = circle1[:2], float(circle1[2])
    scale = r1 / r0
    pts, vals = _ball_pixels(f0, c0, r0, 0.9, grid_pixels, rng)
    dirs = fibonacci_sphere(n_directions)
    angles = np.linspace(np.pi / n_angles, np.pi, n_angles)
    best, best_cost = np.zeros(3), np.sum(_residuals(np.zeros(3), pts, vals, f1, c1, scale) ** 2)
    for a in angles:  # all directions at once for each angle
        cost = np.sum(_grid_residuals(a, dirs, pts, vals, f1, c1, scale) ** 2, axis=1)
        j = int(np.argmin(cost))
        if cost[j] < best_cost:
            best, best_cost = a * dirs[j], cost[j]
    pts, vals = _ball_pixels(f0, c0, r0, 0.9, None, rng)
    res = least_squares(_residuals, best, args=(pts, vals, f1, c1, scale), x_scale=0.05, max_nfev=200)
    return res.x / dt_s
