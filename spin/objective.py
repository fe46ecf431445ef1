"""Image of warped events (IWE) and its variance, with the analytic gradient.

The IWE is the orthographic projection of the events rotated to ``t_ref`` (see
:mod:`spin.warp`), accumulated with bilinear voting of their signed polarity and
smoothed with a Gaussian.  Its variance (the contrast) peaks when the rotation and
translation parameters align the events.  Because voting and smoothing are linear,
the gradient w.r.t. each warped point is the bilinear-interpolated gradient of
``G * (G * H - mean)`` at that point; chained through the rotation's left Jacobian
it gives ``d contrast / d w`` (``w = omega * axis``, rad/s) and ``d contrast / d v``
(px/s) exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from spin.warp import rotation_coefficients, cross, left_jacobian_transpose_apply, rotate


@dataclass(frozen=True)
class BallEvents:
    """Ball events prepared for warping.

    Attributes
    ----------
    x_px, y_px : ndarray (N,)
        Pixel coordinates minus the centre at ``t0`` (so the ball starts at the origin).
    s_s : ndarray (N,)
        Time since ``t0``, seconds.
    tau_s : ndarray (N,)
        ``t_ref - t``, seconds.
    weight : ndarray (N,)
        Signed polarity (+1 ON, -1 OFF) or 1.
    radius_px : float
    """

    x_px: np.ndarray
    y_px: np.ndarray
    s_s: np.ndarray
    tau_s: np.ndarray
    weight: np.ndarray
    radius_px: float

    def __len__(self) -> int:
        return len(self.x_px)

    def take(self, index) -> BallEvents:
        """Subset (index array, mask or slice)."""
        return BallEvents(self.x_px[index], self.y_px[index], self.s_s[index], self.tau_s[index],
                          self.weight[index], self.radius_px)

    def astype(self, dtype) -> BallEvents:
        return BallEvents(*(a.astype(dtype) for a in (self.x_px, self.y_px, self.s_s, self.tau_s, self.weight)),
                          self.radius_px)


@dataclass(frozen=True)
class IweGeometry:
    """Raster of the IWE: ``scale`` pixels per ball pixel, Gaussian ``sigma`` (IWE px).

    With ``hemispheres`` the points rotated to the far side (``z > 0``) go to a
    second disc beside the first, so front and back textures do not overlap.
    """

    radius_px: float
    scale: float = 1.0
    sigma: float = 1.0
    hemispheres: bool = False

    @property
    def pad(self) -> int:
        return int(np.ceil(3.0 * self.sigma)) + 2

    @property
    def size(self) -> int:
        return int(np.ceil(2.0 * self.radius_px * self.scale)) + 2 * self.pad + 1

    @property
    def shape(self) -> tuple[int, int]:
        return (self.size, 2 * self.size if self.hemispheres else self.size)

    def to_iwe(self, px, py, pz):
        """IWE coordinates (u, v) of points given relative to the ball centre (px)."""
        dt = np.result_type(px).type
        off = dt(self.radius_px * self.scale + self.pad)
        u = px * dt(self.scale) + off
        if self.hemispheres:
            u = u + (pz > 0) * self.size
        return u, py * dt(self.scale) + off


def blur(image: np.ndarray, sigma: float) -> np.ndarray:
    k = 2 * int(np.ceil(3.0 * sigma)) + 1
    return cv2.GaussianBlur(image, (k, k), sigma, sigmaY=sigma, borderType=cv2.BORDER_CONSTANT)


def _corners(u, v, width, height):
    # points pushed off the raster (possible only for wild velocities) are held at its border
    u = np.clip(u, 0.0, width - 1.001)
    v = np.clip(v, 0.0, height - 1.001)
    iu = np.floor(u)
    iv = np.floor(v)
    fu = (u - iu).astype(np.float32, copy=False)
    fv = (v - iv).astype(np.float32, copy=False)
    idx = iv.astype(np.int64) * width + iu.astype(np.int64)
    return idx, fu, fv


def vote(u, v, weight, shape) -> np.ndarray:
    """Bilinear voting of ``weight`` (N,) at IWE coordinates ``(u, v)`` (N,); float32 image of ``shape``."""
    h, w = shape
    idx, fu, fv = _corners(u, v, w, h)
    wgt = weight.astype(np.float32)
    a = wgt * (1.0 - fv)
    b = wgt * fv
    n = h * w
    img = (np.bincount(idx, a * (1.0 - fu), n) + np.bincount(idx + 1, a * fu, n)
           + np.bincount(idx + w, b * (1.0 - fu), n) + np.bincount(idx + w + 1, b * fu, n))
    return img.astype(np.float32).reshape(h, w)


def lift_moving(ev: BallEvents, velocity_px_s):
    """Sphere points (component tuple) at the events' times for centre velocity ``velocity_px_s``.

    Also returns ``dz/ddx`` and ``dz/ddy`` factors (``dx/sqrt(r^2-d^2)``), zero where clamped.
    """
    vx, vy = (ev.s_s.dtype.type(c) for c in velocity_px_s)
    dx = ev.x_px - vx * ev.s_s
    dy = ev.y_px - vy * ev.s_s
    r2 = dx.dtype.type(ev.radius_px * ev.radius_px)
    zq = r2 - dx * dx - dy * dy
    floor = dx.dtype.type(0.01) * r2
    clamped = zq < floor
    root = np.sqrt(np.maximum(zq, floor))
    inv = np.where(clamped, 0.0, 1.0 / root).astype(dx.dtype)
    return (dx, dy, -root), dx * inv, dy * inv


def warp(ev: BallEvents, w_rad_s, velocity_px_s):
    """Points (component tuple, px, relative to the centre) rotated to ``t_ref``."""
    p, _, _ = lift_moving(ev, velocity_px_s)
    theta = tuple(ev.tau_s * np.asarray(w_rad_s[i], dtype=ev.tau_s.dtype) for i in range(3))
    return rotate(p, theta)


def iwe(ev: BallEvents, w_rad_s, velocity_px_s, geometry: IweGeometry) -> np.ndarray:
    """Smoothed image of warped events, float32 of ``geometry.shape``."""
    q = warp(ev, w_rad_s, velocity_px_s)
    u, v = geometry.to_iwe(*q)
    return blur(vote(u, v, ev.weight, geometry.shape), geometry.sigma)


def contrast(ev: BallEvents, w_rad_s, velocity_px_s, geometry: IweGeometry, *, gradient: bool = True,
             velocity_gradient: bool = True):
    """Variance of the IWE and, optionally, its gradient.

    Parameters
    ----------
    ev : BallEvents
    w_rad_s : array (3,)
        Angular velocity ``omega * axis`` (rad/s).
    velocity_px_s : array (2,)
        Centre velocity (px/s).
    geometry : IweGeometry

    Returns
    -------
    value : float
    grad_w : ndarray (3,)  (only with ``gradient``)
    grad_v : ndarray (2,)  (only with ``gradient``; zeros unless ``velocity_gradient``)
    """
    dt = ev.tau_s.dtype
    p, dzdx, dzdy = lift_moving(ev, velocity_px_s)
    theta = tuple(ev.tau_s * dt.type(w_rad_s[i]) for i in range(3))
    coef = rotation_coefficients(theta, gradient)
    q = rotate(p, theta, coef)
    u, v = geometry.to_iwe(*q)
    h, width = geometry.shape
    n = h * width
    hs = blur(vote(u, v, ev.weight, geometry.shape), geometry.sigma)
    mean = float(hs.mean())
    value = float(np.mean(np.square(hs - mean, dtype=np.float64)))
    if not gradient:
        return value
    g = blur(hs - mean, geometry.sigma).ravel() * (2.0 / n)
    idx, fu, fv = _corners(u, v, width, h)
    wgt = ev.weight.astype(np.float32)
    g00, g01, g10, g11 = g[idx], g[idx + 1], g[idx + width], g[idx + width + 1]
    du = (wgt * geometry.scale) * ((1.0 - fv) * (g01 - g00) + fv * (g11 - g10))
    dv = (wgt * geometry.scale) * ((1.0 - fu) * (g10 - g00) + fu * (g11 - g01))
    zero = np.zeros_like(du)
    gq = (du.astype(dt), dv.astype(dt), zero.astype(dt))
    # d f / d theta_k = J_l^T (q_k x g_k); d f / d w = sum_k tau_k d f / d theta_k
    dtheta = left_jacobian_transpose_apply(theta, cross(q, gq), coef)
    grad_w = np.array([np.einsum("i,i->", ev.tau_s, dtheta[i]) for i in range(3)], dtype=np.float64)
    if not velocity_gradient:
        return value, grad_w, np.zeros(2)
    # d f / d p_k = R_k^T g_k  (rotation by -theta); p depends on v through the centre offset
    gp = rotate(gq, tuple(-t for t in theta), coef)
    grad_v = np.array([-np.einsum("i,i->", ev.s_s, gp[0] + gp[2] * dzdx), -np.einsum("i,i->", ev.s_s, gp[1] + gp[2] * dzdy)],
                      dtype=np.float64)
    return value, grad_w, grad_v
