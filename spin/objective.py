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
from functools import cached_property

import cv2
import numpy as np

from spin.warp import rotate


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

    @cached_property
    def pad(self) -> int:
        return int(np.ceil(3.0 * self.sigma)) + 2

    @cached_property
    def size(self) -> int:
        return int(np.ceil(2.0 * self.radius_px * self.scale)) + 2 * self.pad + 1

    @cached_property
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
    u = np.minimum(np.maximum(u, 0.0), width - 1.001)  # (np.clip costs more than both)
    v = np.minimum(np.maximum(v, 0.0), height - 1.001)
    iu = np.floor(u)
    iv = np.floor(v)
    fu = (u - iu).astype(np.float32, copy=False)
    fv = (v - iv).astype(np.float32, copy=False)
    idx = iv.astype(np.int64) * width + iu.astype(np.int64)
    return idx, fu, fv


def vote(u, v, weight, shape) -> np.ndarray:
    """Bilinear voting of ``weight`` (N,) at IWE coordinates ``(u, v)`` (N,); float32 image of ``shape``."""
    h, w = shape
    return _vote_corners(*_corners(u, v, w, h), weight, shape)


def _vote_corners(idx, fu, fv, weight, shape) -> np.ndarray:
    h, w = shape
    wgt = weight.astype(np.float32, copy=False)
    b = wgt * fv
    a = wgt - b
    bu = b * fu
    au = a * fu
    # the four corners' votes in one pass
    img = np.bincount(np.concatenate([idx, idx + 1, idx + w, idx + (w + 1)]),
                      np.concatenate([a - au, au, b - bu, bu]), h * w)
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


def _axis_cross(n, a):
    """``n x a`` for a constant vector ``n`` (3,) and a component tuple ``a`` of (N,) arrays."""
    return (n[1] * a[2] - n[2] * a[1], n[2] * a[0] - n[0] * a[2], n[0] * a[1] - n[1] * a[0])


def contrast(ev: BallEvents, w_rad_s, velocity_px_s, geometry: IweGeometry, *, gradient: bool = True,
             velocity_gradient: bool = True, lifted=None):
    """Variance of the IWE and, optionally, its gradient.

    All events turn about the same axis ``n = w / |w|`` by ``phi_k = |w| tau_k``, so the
    rotation is evaluated as ``q = p + sin(phi) n x p + (1 - cos(phi)) n x (n x p)`` and the
    sums over events of the gradient factor through constant cross products with ``n``.

    Parameters
    ----------
    ev : BallEvents
    w_rad_s : array (3,)
        Angular velocity ``omega * axis`` (rad/s).
    velocity_px_s : array (2,)
        Centre velocity (px/s).
    geometry : IweGeometry
    lifted : tuple, optional
        ``lift_moving(ev, velocity_px_s)`` when already computed (saves it on repeated calls
        with the same velocity).

    Returns
    -------
    value : float
    grad_w : ndarray (3,)  (only with ``gradient``)
    grad_v : ndarray (2,)  (only with ``gradient``; zeros unless ``velocity_gradient``)
    """
    dt = ev.tau_s.dtype.type
    p, dzdx, dzdy = lift_moving(ev, velocity_px_s) if lifted is None else lifted
    w = np.asarray(w_rad_s, dtype=np.float64)
    omega = float(np.sqrt(np.dot(w, w)))
    n = tuple(dt(c) for c in (w / omega if omega > 0 else (0.0, 0.0, 1.0)))
    phi = ev.tau_s * dt(omega)
    sin, one_cos = np.sin(phi), 1 - np.cos(phi)
    nxp = _axis_cross(n, p)
    nxnxp = _axis_cross(n, nxp)
    q = tuple(p[i] + sin * nxp[i] + one_cos * nxnxp[i] for i in range(3))
    u, v = geometry.to_iwe(*q)
    h, width = geometry.shape
    size = h * width
    idx, fu, fv = _corners(u, v, width, h)
    hs = blur(_vote_corners(idx, fu, fv, ev.weight, geometry.shape), geometry.sigma)
    flat = hs.ravel().astype(np.float64)
    mean = float(flat.sum()) / size
    value = float(np.dot(flat, flat)) / size - mean * mean
    if not gradient:
        return value
    g = blur(hs - mean, geometry.sigma).ravel() * (2.0 / size)
    wgt = ev.weight.astype(np.float32, copy=False) * np.float32(geometry.scale)
    g00, g01, g10, g11 = g[idx], g[idx + 1], g[idx + width], g[idx + width + 1]
    d0 = g01 - g00
    d1 = g11 - g10
    du = (wgt * (d0 + fv * (d1 - d0))).astype(dt, copy=False)
    e0 = g10 - g00
    e1 = g11 - g01
    dv = (wgt * (e0 + fu * (e1 - e0))).astype(dt, copy=False)
    # d f / d theta_k = J_l(theta_k)^T a_k with a_k = q_k x (du, dv, 0) and theta_k = phi_k n:
    # J_l^T a = a - (1 - cos)/phi n x a + (1 - sin/phi) n x (n x a); d theta_k / d w = tau_k (for the
    # part along n; the same J_l form covers the perpendicular part), so
    # d f / d w = A - n x B + n x (n x C) with A, B, C the tau-weighted sums below
    a = (-q[2] * dv, q[2] * du, q[0] * dv - q[1] * du)
    safe = phi + (phi == 0)  # b1 and c1 are 0 at phi = 0; float32 rounding near 0 is far below 1
    b1 = one_cos / safe
    c1 = (phi - sin) / safe
    tb = ev.tau_s * b1
    tc = ev.tau_s * c1
    big_a = [float(np.dot(ev.tau_s, a[i])) for i in range(3)]
    big_b = [float(np.dot(tb, a[i])) for i in range(3)]
    big_c = [float(np.dot(tc, a[i])) for i in range(3)]
    nn = tuple(float(c) for c in n)
    nxb = _axis_cross(nn, big_b)
    nxnxc = _axis_cross(nn, _axis_cross(nn, big_c))
    grad_w = np.array([big_a[i] - nxb[i] + nxnxc[i] for i in range(3)])
    if not velocity_gradient:
        return value, grad_w, np.zeros(2)
    # d f / d p_k = R_k^T g_k (rotation by -phi_k about n); p depends on v through the centre offset
    gq = (du, dv, np.zeros_like(du))
    nxg = _axis_cross(n, gq)
    nxnxg = _axis_cross(n, nxg)
    gp = tuple(gq[i] - sin * nxg[i] + one_cos * nxnxg[i] for i in range(3))
    grad_v = np.array([-np.dot(ev.s_s, gp[0] + gp[2] * dzdx), -np.dot(ev.s_s, gp[1] + gp[2] * dzdy)],
                      dtype=np.float64)
    return value, grad_w, grad_v
