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

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

import cv2
import numpy as np

from spin import _kernels


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
    as far plus ``margin_px`` (2 px: room for the bilinear corners of the points the gradient
    samples; nearest-pixel voting needs none).  With ``hemispheres`` the points rotated to the
    far side (``z > 0``) go to a second disc beside the first, so front and back textures do
    not overlap.
    """

    radius_px: float
    scale: float = 1.0
    sigma: float = 1.0
    hemispheres: bool = False
    truncate: float = 3.0
    margin_px: int = 2

    @cached_property
    def pad(self) -> int:
        return int(np.ceil(self.truncate * self.sigma)) + self.margin_px

    @cached_property
    def size(self) -> int:
        return int(np.ceil(2.0 * self.radius_px * self.scale)) + 2 * self.pad + 1

    @cached_property
    def shape(self) -> tuple[int, int]:
        return (self.size, 2 * self.size if self.hemispheres else self.size)

    @cached_property
    def holds_sphere(self) -> bool:
        """Whether every point of the lifted sphere (norm up to ``1.005 r``) votes at least the kernel's
        reach inside the raster's edge (so that clipping would leave it alone)."""
        reach = 1.005 * self.radius_px * self.scale
        centre = self.radius_px * self.scale + self.pad
        kernel = self.pad - self.margin_px
        return centre - reach >= kernel and centre + reach <= self.size - 2.001 - kernel


def blur(image: np.ndarray, sigma: float, truncate: float = 3.0) -> np.ndarray:
    """Gaussian blur (zero outside the image), kernel to ``truncate`` sigmas."""
    k = 2 * int(np.ceil(truncate * sigma)) + 1
    return cv2.GaussianBlur(image, (k, k), sigma, sigmaY=sigma, borderType=cv2.BORDER_CONSTANT)


@lru_cache(maxsize=64)
def _blur_twice_kernel(sigma: float, truncate: float) -> np.ndarray:
    """1-D kernel (float32) of :func:`blur` applied twice: its Gaussian convolved with itself."""
    g = cv2.getGaussianKernel(2 * int(np.ceil(truncate * sigma)) + 1, sigma, cv2.CV_64F).ravel()
    return np.convolve(g, g).astype(np.float32)


def blur_twice(image: np.ndarray, sigma: float, truncate: float = 3.0) -> np.ndarray:
    """``blur(blur(image))`` in one pass (zero outside the image; equal to it when the image is
    zero within the kernel's reach of its edge)."""
    kernel = _blur_twice_kernel(float(sigma), float(truncate))
    return cv2.sepFilter2D(image, -1, kernel, kernel, borderType=cv2.BORDER_CONSTANT)


@lru_cache(maxsize=64)
def _corner_offsets(w: int) -> np.ndarray:
    """Flat index offsets (4, 1) of the four bilinear corners on a raster ``w`` wide."""
    return np.array([[0], [1], [w], [w + 1]], dtype=np.intp)


@lru_cache(maxsize=64)
def _clip_limits(h: int, w: int, inset: int, dtype) -> np.ndarray:
    """Upper coordinate limits (2, 1) of an ``h`` x ``w`` raster, ``inset`` px inside its edge."""
    return np.array([[w - 1.001 - inset], [h - 1.001 - inset]], dtype=dtype)


def _bilinear(uv, weight, shape) -> np.ndarray:
    """Image (float32, ``shape``) of ``weight`` (N,) voted bilinearly at IWE coordinates ``uv`` (2, N)
    (changed in place)."""
    h, w = shape
    base = np.floor(uv)
    frac = np.subtract(uv, base, out=uv).astype(np.float32, copy=False)
    idx = base[1].astype(np.intp)
    idx *= w
    idx += base[0].astype(np.intp)
    corners = idx + _corner_offsets(w)
    wgt = weight.astype(np.float32, copy=False)
    b = wgt * frac[1]
    a = wgt - b
    votes = np.empty((4, len(wgt)), dtype=np.float64)  # what bincount takes without a copy
    np.multiply(a, frac[0], out=votes[1])
    np.subtract(a, votes[1], out=votes[0])
    np.multiply(b, frac[0], out=votes[3])
    np.subtract(b, votes[3], out=votes[2])
    return np.bincount(corners.ravel(), votes.ravel(), h * w).astype(np.float32).reshape(h, w)


def lift_moving(ev: BallEvents, velocity_px_s):
    """Sphere points (3, N) at the events' times for centre velocity ``velocity_px_s`` (px, centre-relative).

    Also returns ``dz/ddx`` and ``dz/ddy`` factors (``dx/sqrt(r^2-d^2)``), zero where clamped,
    and whether every event lies within the ball's radius (then no point is longer than
    ``1.005 r``: the depth is clamped at ``0.1 r``).  Raises ``ValueError`` for a non-finite position.
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
    lowest = zq.min(initial=0.0)
    if lowest != lowest:
        raise ValueError("lift_moving: an event's position or time is not finite")
    return p, dx * inv, dy * inv, bool(lowest >= 0.0)


def _rotation_rows(n, scale: float, dtype) -> np.ndarray:
    """(9, 3) matrix stacking ``scale * (I, [n]x, [n]x^2)`` for a unit axis ``n`` ([n]x^2 = n n^T - I)."""
    x, y, z = n
    s = float(scale)
    return np.array([[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s],
                     [0.0, -s * z, s * y], [s * z, 0.0, -s * x], [-s * y, s * x, 0.0],
                     [s * (x * x - 1), s * x * y, s * x * z], [s * x * y, s * (y * y - 1), s * y * z],
                     [s * x * z, s * y * z, s * (z * z - 1)]], dtype=dtype)


def _rotated(p, tau_s, w_rad_s, scale: float) -> np.ndarray:
    """Points ``p`` (3, N) rotated by ``|w| tau`` about ``w / |w|`` (``w_rad_s``: (3,), rad/s), times
    ``scale``: (3, N)."""
    axes, omega = _kernels.axes_speeds(np.reshape(np.asarray(w_rad_s, dtype=np.float64), (1, 3)))
    n = tuple(axes[0].tolist())
    phi = np.multiply(tau_s.dtype.type(omega[0]), tau_s)
    # q = p + sin(phi) n x p + (1 - cos(phi)) n x (n x p): the three terms from one (9, 3) product
    terms = _rotation_rows(n, scale, p.dtype) @ p
    q = terms[0:3]
    q += np.sin(phi) * terms[3:6]
    q += (1 - np.cos(phi)) * terms[6:9]
    return q


def warp(ev: BallEvents, w_rad_s, velocity_px_s) -> np.ndarray:
    """Points (3, N), px relative to the centre, rotated to ``t_ref``."""
    return _rotated(lift_moving(ev, velocity_px_s)[0], ev.tau_s, w_rad_s, 1.0)


def _iwe_coords(q, geometry: IweGeometry):
    """IWE coordinates (2, N) of scaled points ``q`` (3, N) relative to the centre; points off the IWE
    (possible only for wild velocities) are held the kernel's reach inside its edge."""
    dt = q.dtype.type
    uv = np.add(q[:2], dt(geometry.radius_px * geometry.scale + geometry.pad))
    if geometry.hemispheres:
        uv[0] += (q[2] > 0) * dt(geometry.size)
    h, width = geometry.shape
    reach = geometry.pad - geometry.margin_px  # the kernel's
    np.clip(uv, reach, _clip_limits(h, width, reach, q.dtype), out=uv)  # (3x faster than np.maximum, np.minimum)
    return uv


def iwe_parts(ev: BallEvents, w_rad_s, velocity_px_s, geometry: IweGeometry, n_parts: int = 1) -> np.ndarray:
    """Smoothed images of warped events, float32 (n_parts, *geometry.shape): image ``k`` of events ``k::n_parts``."""
    q = _rotated(lift_moving(ev, velocity_px_s)[0], ev.tau_s, w_rad_s, geometry.scale)
    h, width = geometry.shape
    uv = _iwe_coords(q, geometry)
    if n_parts > 1:  # the parts' images side by side in one raster
        uv[0] += (np.arange(len(ev)) % n_parts).astype(uv.dtype) * uv.dtype.type(width)
    img = blur(_bilinear(uv, ev.weight, (h, n_parts * width)), geometry.sigma, geometry.truncate)
    return img.reshape(h, n_parts, width).transpose(1, 0, 2)


def contrast(ev: BallEvents, w_rad_s, velocity_px_s, geometry: IweGeometry, *, gradient: bool = True,
             velocity_gradient: bool = True, lifted=None):
    """Variance of the IWE and, optionally, its gradient, for one or several angular velocities.

    All events turn about the same axis ``n = w / |w|`` by ``phi_k = |w| tau_k``, so the
    rotation is evaluated as ``q = p + sin(phi) n x p + (1 - cos(phi)) n x (n x p)`` and the
    sums over events of the gradient factor through constant cross products with ``n``
    (:mod:`spin._kernels`).  Several angular velocities are evaluated in one pass (their IWEs side
    by side in one raster): the fixed cost of a pass then counts once.

    Parameters
    ----------
    ev : BallEvents
    w_rad_s : array (3,) or (K, 3)
        Angular velocity ``omega * axis`` (rad/s), or K of them.
    velocity_px_s : array (2,)
        Centre velocity (px/s).
    geometry : IweGeometry
    lifted : tuple, optional
        ``lift_moving(ev, velocity_px_s)`` when already computed (saves it on repeated calls
        with the same velocity).

    Returns
    -------
    value : float, or (K,)
    grad_w : ndarray (3,) or (K, 3)  (only with ``gradient``)
    grad_v : ndarray (2,) or (K, 2)  (only with ``gradient``; zeros unless ``velocity_gradient``)
    """
    single = np.ndim(w_rad_s) == 1
    p, dzdx, dzdy, inside = lift_moving(ev, velocity_px_s) if lifted is None else lifted
    axes, omega = _kernels.axes_speeds(np.reshape(np.asarray(w_rad_s, dtype=np.float64), (-1, 3)))
    # (the compiled loops index the raster by the points' coordinates: nothing non-finite may reach them;
    # lift_moving checks the positions)
    if not math.isfinite(float(omega.sum()) + float(velocity_px_s[0]) + float(velocity_px_s[1])
                         + float(ev.tau_s.sum())):
        raise ValueError(f"contrast: angular velocity {np.asarray(w_rad_s).tolist()} rad/s, velocity "
                         f"{np.asarray(velocity_px_s).tolist()} px/s or an event's time is not finite")
    if p.shape[1] != len(ev):
        raise ValueError(f"contrast: lifted points for {p.shape[1]} events, not the {len(ev)} given")
    k = len(omega)
    phi = np.multiply(omega.astype(ev.tau_s.dtype)[:, None], ev.tau_s)
    sin = np.sin(phi)
    one_cos = 1 - np.cos(phi)
    h, width = geometry.shape
    # (points off their IWE, possible only for wild velocities, are held the kernel's reach inside its
    # edge, where neither blur reaches the neighbouring IWE or the raster's edge)
    place = (geometry.scale, geometry.radius_px * geometry.scale + geometry.pad, geometry.size, geometry.hemispheres,
             h, width, not (inside and geometry.holds_sphere and ev.radius_px <= geometry.radius_px),
             float(geometry.pad - geometry.margin_px))
    img, corner, fu, fv, q = _kernels.vote(p, ev.weight, axes, sin, one_cos, *place)
    # the variance of the blurred IWE G * H from one filter pass: <G * H, G * H> = <H, G * G * H> (G is
    # symmetric, and no vote lies within the kernel's reach of the raster's edge but for clipped points)
    ggh = blur_twice(img, geometry.sigma, geometry.truncate)
    value = _kernels.variances(img, ggh, k, width)
    if not gradient:
        return float(value[0]) if single else value
    grad_w, grad_v = _kernels.gradients(ev.tau_s, ev.s_s, ev.weight, dzdx, dzdy, axes, omega, phi, sin, one_cos,
                                        geometry.scale, corner, fu, fv, q, ggh, velocity_gradient)
    if single:
        return float(value[0]), grad_w[0], grad_v[0]
    return value, grad_w, grad_v
