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
from functools import cached_property, lru_cache

import math

import cv2
import numpy as np



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

    The Gaussian kernel reaches ``truncate`` sigmas; the raster's margin around the disc
    as far plus 2 px.  With ``hemispheres`` the points rotated to the far side (``z > 0``) go to a
    second disc beside the first, so front and back textures do not overlap.
    """

    radius_px: float
    scale: float = 1.0
    sigma: float = 1.0
    hemispheres: bool = False
    truncate: float = 3.0

    @cached_property
    def pad(self) -> int:
        return int(np.ceil(self.truncate * self.sigma)) + 2

    @cached_property
    def size(self) -> int:
        return int(np.ceil(2.0 * self.radius_px * self.scale)) + 2 * self.pad + 1

    @cached_property
    def shape(self) -> tuple[int, int]:
        return (self.size, 2 * self.size if self.hemispheres else self.size)

    @cached_property
    def holds_sphere(self) -> bool:
        """Whether every point of the lifted sphere (norm up to ``1.005 r``) votes inside the raster."""
        reach = 1.005 * self.radius_px * self.scale
        centre = self.radius_px * self.scale + self.pad
        return centre - reach >= 0.0 and centre + reach <= self.size - 2.001


def blur(image: np.ndarray, sigma: float, truncate: float = 3.0) -> np.ndarray:
    """Gaussian blur (zero outside the image), kernel to ``truncate`` sigmas."""
    k = 2 * int(np.ceil(truncate * sigma)) + 1
    return cv2.GaussianBlur(image, (k, k), sigma, sigmaY=sigma, borderType=cv2.BORDER_CONSTANT)


@lru_cache(maxsize=64)
def _raster_constants(h: int, w: int, dtype):
    """Coordinate limits (2, 1) and the four corners' index offsets (4, 1) of an ``h`` x ``w`` raster."""
    return np.array([[w - 1.001], [h - 1.001]], dtype=dtype), np.array([[0], [1], [w], [w + 1]], dtype=np.intp)


def _bilinear(uv, weight, shape, clip: bool = True):
    """Bilinear voting of ``weight`` (N,) at IWE coordinates ``uv`` (2, N) (changed in place).

    Returns the image (float32, ``shape``), the four corners' flat indices (4, N) and the
    weights split along v, ``a = weight (1 - fv)`` and ``b = weight fv`` (float32, (N,)).
    ``clip=False`` where every point is known to lie on the raster.
    """
    h, w = shape
    limits, offsets = _raster_constants(h, w, uv.dtype)
    if clip:
        # points pushed off the raster (possible only for wild velocities) are held at its border
        np.clip(uv, 0.0, limits, out=uv)  # (np.clip: 3x faster than np.maximum then np.minimum)
    base = np.floor(uv)
    frac = np.subtract(uv, base, out=uv).astype(np.float32, copy=False)
    idx = (base[1] * w + base[0]).astype(np.intp)  # exact: the raster has far fewer than 2**24 pixels
    corners = idx + offsets
    wgt = weight.astype(np.float32, copy=False)
    b = wgt * frac[1]
    a = wgt - b
    votes = np.empty((4, len(wgt)), dtype=np.float64)  # what bincount takes without a copy
    np.multiply(a, frac[0], out=votes[1])
    np.subtract(a, votes[1], out=votes[0])
    np.multiply(b, frac[0], out=votes[3])
    np.subtract(b, votes[3], out=votes[2])
    img = np.bincount(corners.ravel(), votes.ravel(), h * w).astype(np.float32).reshape(h, w)
    return img, corners, frac, a, b


def vote(u, v, weight, shape) -> np.ndarray:
    """Bilinear voting of ``weight`` (N,) at IWE coordinates ``(u, v)`` (N,); float32 image of ``shape``."""
    return _bilinear(np.array([u, v]), weight, shape)[0]


def lift_moving(ev: BallEvents, velocity_px_s):
    """Sphere points (3, N) at the events' times for centre velocity ``velocity_px_s`` (px, centre-relative).

    Also returns ``dz/ddx`` and ``dz/ddy`` factors (``dx/sqrt(r^2-d^2)``), zero where clamped,
    and whether every event lies within the ball's radius (then no point is longer than
    ``1.005 r``: the depth is clamped at ``0.1 r``).
    """
    vx, vy = (ev.s_s.dtype.type(c) for c in velocity_px_s)
    p = np.empty((3, len(ev)), dtype=ev.x_px.dtype)
    dx = np.subtract(ev.x_px, vx * ev.s_s, out=p[0])
    dy = np.subtract(ev.y_px, vy * ev.s_s, out=p[1])
    r2 = dx.dtype.type(ev.radius_px * ev.radius_px)
    zq = r2 - dx * dx - dy * dy
    floor = dx.dtype.type(0.01) * r2
    clamped = zq < floor
    root = np.sqrt(np.maximum(zq, floor))
    np.negative(root, out=p[2])
    inv = np.where(clamped, 0.0, 1.0 / root).astype(dx.dtype)
    return p, dx * inv, dy * inv, bool(zq.min(initial=0.0) >= 0.0)


def _rotation_rows(n, scale: float, dtype) -> np.ndarray:
    """(9, 3) matrix stacking ``scale * (I, [n]x, [n]x^2)`` for a unit axis ``n`` ([n]x^2 = n n^T - I)."""
    x, y, z = n
    s = float(scale)
    return np.array([[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s],
                     [0.0, -s * z, s * y], [s * z, 0.0, -s * x], [-s * y, s * x, 0.0],
                     [s * (x * x - 1), s * x * y, s * x * z], [s * x * y, s * (y * y - 1), s * y * z],
                     [s * x * z, s * y * z, s * (z * z - 1)]], dtype=dtype)


def _rotated(p, tau_s, w_rad_s, scale: float):
    """Points ``p`` (3, N) rotated by ``|w| tau`` about ``w / |w|``, times ``scale``.

    Also returns the axis ``n`` (3 floats), ``omega`` (rad/s), ``phi``, ``sin(phi)`` and ``1 - cos(phi)`` (N,).
    """
    wx, wy, wz = (float(c) for c in w_rad_s)
    omega = math.sqrt(wx * wx + wy * wy + wz * wz)
    n = (wx / omega, wy / omega, wz / omega) if omega > 0 else (0.0, 0.0, 1.0)
    phi = tau_s * tau_s.dtype.type(omega)
    sin = np.sin(phi)
    one_cos = 1 - np.cos(phi)
    # q = p + sin(phi) n x p + (1 - cos(phi)) n x (n x p): the three terms from one (9, 3) product
    terms = _rotation_rows(n, scale, p.dtype) @ p
    q = terms[0:3]
    q += sin * terms[3:6]
    q += one_cos * terms[6:9]
    return q, n, omega, phi, sin, one_cos


def warp(ev: BallEvents, w_rad_s, velocity_px_s) -> np.ndarray:
    """Points (3, N), px relative to the centre, rotated to ``t_ref``."""
    return _rotated(lift_moving(ev, velocity_px_s)[0], ev.tau_s, w_rad_s, 1.0)[0]


def _iwe_coords(q, geometry: IweGeometry):
    """IWE coordinates (2, N) of scaled points ``q`` (3, N) relative to the centre."""
    uv = q[:2] + q.dtype.type(geometry.radius_px * geometry.scale + geometry.pad)
    if geometry.hemispheres:
        uv[0] += (q[2] > 0) * q.dtype.type(geometry.size)
    return uv


def iwe(ev: BallEvents, w_rad_s, velocity_px_s, geometry: IweGeometry) -> np.ndarray:
    """Smoothed image of warped events, float32 of ``geometry.shape``."""
    q = _rotated(lift_moving(ev, velocity_px_s)[0], ev.tau_s, w_rad_s, geometry.scale)[0]
    return blur(_bilinear(_iwe_coords(q, geometry), ev.weight, geometry.shape)[0], geometry.sigma,
                geometry.truncate)


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
    p, dzdx, dzdy, inside = lift_moving(ev, velocity_px_s) if lifted is None else lifted
    # q in IWE pixels (scaled), relative to the centre
    q, n, omega, phi, sin, one_cos = _rotated(p, ev.tau_s, w_rad_s, geometry.scale)
    uv = _iwe_coords(q, geometry)
    h, width = geometry.shape
    size = h * width
    img, corners, frac, a, b = _bilinear(uv, ev.weight, geometry.shape, clip=not (inside and geometry.holds_sphere))
    hs = blur(img, geometry.sigma, geometry.truncate)
    mean = cv2.sumElems(hs)[0] / size
    value = cv2.norm(hs, cv2.NORM_L2SQR) / size - mean * mean
    if not gradient:
        return value
    # d value / d H = 2 / size * G * (G * H - mean); its bilinear derivative at each point takes only
    # differences between the four corners, and G * mean is the constant mean wherever points vote
    # (the kernel lies inside the raster there), so G * G * H serves
    # (4, N): g00, g01, g10, g11
    g = np.take(blur(hs, geometry.sigma, geometry.truncate).ravel(), corners)
    d01 = g[1] - g[0]
    d23 = g[3] - g[2]
    du = a * d01
    du += b * d23
    # dv = weight ((1 - fu) (g10 - g00) + fu (g11 - g01)); (g11 - g01) - (g10 - g00) = d23 - d01
    d23 -= d01
    d23 *= frac[0]
    d23 += g[2]
    d23 -= g[0]
    dv = d23 * ev.weight.astype(np.float32, copy=False)
    dt = q.dtype.type
    du = du.astype(dt, copy=False)
    dv = dv.astype(dt, copy=False)
    # d f / d theta_k = J_l(theta_k)^T a_k with a_k = q_k x (du, dv, 0) and theta_k = phi_k n:
    # J_l^T a = a - (1 - cos)/phi n x a + (1 - sin/phi) n x (n x a); d theta_k / d w = tau_k (for the
    # part along n; the same J_l form covers the perpendicular part), so
    # d f / d w = A - n x B + n x (n x C) with A, B, C the tau-weighted sums below
    acr = np.empty((3, len(du)), dtype=dt)
    np.multiply(q[2], dv, out=acr[0])
    np.negative(acr[0], out=acr[0])
    np.multiply(q[2], du, out=acr[1])
    np.multiply(q[0], dv, out=acr[2])
    acr[2] -= q[1] * du
    # tau (1 - cos)/phi and tau (phi - sin)/phi are (1 - cos)/omega and (phi - sin)/omega; three
    # matrix-vector products (a (3, N) x (N, 3) product with a transposed operand costs 4x more), the
    # rest on Python floats (cheaper than NumPy calls on 3-vectors)
    k = 2.0 / size
    k_omega = k / omega if omega > 0 else k  # (B and C are 0 at omega = 0)
    sum_a = [k * c for c in (acr @ ev.tau_s).tolist()]
    sum_b = [k_omega * c for c in (acr @ one_cos).tolist()]
    sum_c = [k_omega * c for c in (acr @ (phi - sin)).tolist()]
    nxb = _axis_cross(n, sum_b)
    nxnxc = _axis_cross(n, _axis_cross(n, sum_c))
    grad_w = np.array([sum_a[i] - nxb[i] + nxnxc[i] for i in range(3)])
    if not velocity_gradient:
        return value, grad_w, np.zeros(2)
    # d f / d p_k = scale R_k^T g_k (rotation by -phi_k about n); p depends on v through the centre offset
    gq = (du, dv, np.zeros_like(du))
    nd = tuple(dt(c) for c in n)
    nxg = _axis_cross(nd, gq)
    nxnxg = _axis_cross(nd, nxg)
    gp = tuple(gq[i] - sin * nxg[i] + one_cos * nxnxg[i] for i in range(3))
    grad_v = np.array([-np.dot(ev.s_s, gp[0] + gp[2] * dzdx), -np.dot(ev.s_s, gp[1] + gp[2] * dzdy)],
                      dtype=np.float64) * (2.0 * geometry.scale / size)
    return value, grad_w, grad_v
