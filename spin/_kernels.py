"""Compiled loops of the contrast and the coarse search (Numba).

:func:`spin.objective.contrast` rotates every event for each of K angular velocities, votes it
bilinearly into K side-by-side IWEs, blurs them (OpenCV) and, for the gradient, samples the
twice-blurred image at each point and sums its products with the rotation's derivatives.  In NumPy
each step was a pass with a temporary array of K x N (the rotation's three terms, the corners, their
four weights, the samples, the products) and those passes took about half of a spin estimate
(mean 40 ms on the benchmark's matrix, 28 ms with these loops): :func:`vote` rotates and votes in one
pass and keeps each point's corner, fractions and position for :func:`gradients`, which samples and
sums in one more.  ``sin(phi)`` and ``1 - cos(phi)`` stay NumPy's (vectorised) and are passed in.
:func:`vote_nearest` is the coarse search's voting (its rotations stay one BLAS matrix product);
bincount's index arithmetic took most of a search.

The gradients' sums run in float64 (NumPy's ran partly in float32: on 64,000 points some components
were 1 % off).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from capture.events import EVENT_DTYPE


@numba.njit(nogil=True, cache=True, boundscheck=False)
def axes_speeds(w_rad_s):
    """Unit axes (K, 3) and speeds (K,) (rad/s) of angular velocities ``w_rad_s`` (K, 3); (0, 0, 1) at rest."""
    k_n = w_rad_s.shape[0]
    axes = np.empty((k_n, 3))
    omega = np.empty(k_n)
    for k in range(k_n):
        x, y, z = w_rad_s[k, 0], w_rad_s[k, 1], w_rad_s[k, 2]
        om = math.sqrt(x * x + y * y + z * z)
        omega[k] = om
        if om > 0.0:
            axes[k, 0], axes[k, 1], axes[k, 2] = x / om, y / om, z / om
        else:
            axes[k, 0], axes[k, 1], axes[k, 2] = 0.0, 0.0, 1.0
    return axes, omega


@numba.njit(nogil=True, cache=True, boundscheck=False)
def vote(p, weight, axes, sin, one_cos, scale, offset, size, hemispheres, h, width, clip, reach):
    """IWEs of the events ``p`` (3, N; ball px from the centre) turned about each of ``axes`` (K, 3) by
    ``phi`` (``sin``, ``one_cos``: (K, N)) and scaled by ``scale`` (IWE px per ball px), voted bilinearly
    with ``weight`` (N,); ``offset``, ``size`` and ``reach`` are IWE px.

    IWE ``k`` occupies columns ``[k width, (k + 1) width)`` of an ``h``-row raster; a point's IWE
    coordinates are its scaled ``(x, y) + offset``, moved one ``size`` to the right when
    ``hemispheres`` and it lies on the far side (``z > 0``), and with ``clip`` held ``reach`` px inside
    its IWE's edge (they are never negative: truncation is the floor).

    Returns
    -------
    img : ndarray float32 (h, K width)
    corner : ndarray int32 (K, N)
        Flat index of each point's top-left bilinear corner.
    fu, fv : ndarray float32 (K, N)
        Its fractions along u and v.
    q : ndarray float32 (K, 3, N)
        The rotated, scaled points.

    Every input must be finite (:func:`spin.objective.contrast` checks): the coordinates index the raster.
    """
    k_n, n = sin.shape
    stride = k_n * width
    acc = np.zeros(h * stride)
    corner = np.empty((k_n, n), np.int32)
    fu = np.empty((k_n, n), np.float32)
    fv = np.empty((k_n, n), np.float32)
    q = np.empty((k_n, 3, n), np.float32)
    for k in range(k_n):
        nx, ny, nz = axes[k, 0], axes[k, 1], axes[k, 2]
        for i in range(n):
            # p + sin(phi) n x p + (1 - cos(phi)) (n (n . p) - p), scaled
            px, py, pz = p[0, i], p[1, i], p[2, i]
            s, c1 = sin[k, i], one_cos[k, i]
            d = nx * px + ny * py + nz * pz
            qx = scale * (px + s * (ny * pz - nz * py) + c1 * (nx * d - px))
            qy = scale * (py + s * (nz * px - nx * pz) + c1 * (ny * d - py))
            qz = scale * (pz + s * (nx * py - ny * px) + c1 * (nz * d - pz))
            u = qx + offset + size * (hemispheres and qz > 0.0)  # (a select, not a branch: the sign is random)
            v = qy + offset
            if clip:
                u = min(max(u, reach), width - 1.001 - reach)
                v = min(max(v, reach), h - 1.001 - reach)
            u0 = int(u)
            v0 = int(v)
            j = v0 * stride + u0 + k * width
            a = u - u0
            b = v - v0
            corner[k, i] = j
            fu[k, i] = a
            fv[k, i] = b
            q[k, 0, i] = qx
            q[k, 1, i] = qy
            q[k, 2, i] = qz
            vb = weight[i] * b
            va = weight[i] - vb
            acc[j] += va - va * a
            acc[j + 1] += va * a
            acc[j + stride] += vb - vb * a
            acc[j + stride + 1] += vb * a
    return acc.astype(np.float32).reshape(h, stride), corner, fu, fv, q


@numba.njit(nogil=True, cache=True, boundscheck=False, fastmath={"reassoc", "contract"})
def variances(img, blurred_twice, k_n, width):
    """Per IWE ``k`` of ``k_n`` side by side (``width`` columns each): ``<H, G * G * H> / size - mean(H)^2``
    (the variance of the blurred IWE ``G * H``), float64 (K,).  Each row's sums in float32 (vectorised),
    added up in float64."""
    h = img.shape[0]
    out = np.empty(k_n)
    size = h * width
    for k in range(k_n):
        total = 0.0
        product = 0.0
        for r in range(h):
            row = img[r, k * width:(k + 1) * width]
            row2 = blurred_twice[r, k * width:(k + 1) * width]
            t = np.float32(0.0)
            p = np.float32(0.0)
            for c in range(width):
                t += row[c]
                p += row[c] * row2[c]
            total += t
            product += p
        mean = total / size
        out[k] = product / size - mean * mean
    return out


@numba.njit(nogil=True, cache=True, boundscheck=False, inline="always")
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@numba.njit(nogil=True, cache=True, boundscheck=False)
def gradients(tau_s, s_s, weight, dzdx, dzdy, axes, omega, phi, sin, one_cos, scale, corner, fu, fv, q, blurred_twice,
              velocity_gradient):
    """Gradients of :func:`variances` w.r.t. each angular velocity ``w_k = omega_k axes_k`` (rad/s; (K, 3))
    and the centre velocity (px/s; (K, 2), zeros unless ``velocity_gradient``), for :func:`vote`'s IWEs
    with ``blurred_twice`` = ``G * G * H`` ((h, K width)), from the points ``q``, corners and fractions
    :func:`vote` returned.  Per event (N,): ``tau_s`` (``t_ref - t``, s), ``s_s`` (``t - t0``, s),
    ``weight``, ``dzdx``, ``dzdy`` (:func:`spin.objective.lift_moving`); per angular velocity and event
    (K, N): ``phi`` (rad), ``sin``, ``one_cos``; ``omega`` (K,) rad/s; ``scale`` IWE px per ball px.

    ``d value / d H = 2 / size (G * G * H - mean)``; at each point ``q`` its bilinear derivative
    ``(du, dv)`` (times the weight) takes only differences between the four corners, where the mean
    cancels.  With ``a = q x (du, dv, 0)`` and ``theta = phi n``, ``d f / d theta = J_l(theta)^T a =
    a - (1 - cos)/phi n x a + (1 - sin/phi) n x (n x a)``, and ``d theta / d w = tau``, so ``d f / d w =
    A - n x B + n x (n x C)`` with ``A = sum a tau``, ``B = sum a (1 - cos) / omega``, ``C = sum a (phi -
    sin) / omega``.  For the velocity, ``d f / d p = scale R^T (du, dv, 0)`` and ``p`` moves by ``-s v``
    (its depth with it: ``dz/dx``, ``dz/dy``).
    """
    k_n, n = sin.shape
    h, stride = blurred_twice.shape
    g = blurred_twice.ravel()
    grad_w = np.zeros((k_n, 3))
    grad_v = np.zeros((k_n, 2))
    norm = 2.0 * k_n / (h * stride)
    for k in range(k_n):
        nx, ny, nz = axes[k, 0], axes[k, 1], axes[k, 2]
        sa0 = sa1 = sa2 = sb0 = sb1 = sb2 = sc0 = sc1 = sc2 = 0.0
        gvx = 0.0
        gvy = 0.0
        for i in range(n):
            s = sin[k, i]
            c1 = one_cos[k, i]
            qx, qy, qz = q[k, 0, i], q[k, 1, i], q[k, 2, i]
            j = corner[k, i]
            a = fu[k, i]
            b = fv[k, i]
            g00 = g[j]
            g01 = g[j + 1]
            g10 = g[j + stride]
            g11 = g[j + stride + 1]
            wt = weight[i]
            du = wt * ((1.0 - b) * (g01 - g00) + b * (g11 - g10))
            dv = wt * ((1.0 - a) * (g10 - g00) + a * (g11 - g01))
            ax = -qz * dv
            ay = qz * du
            az = qx * dv - qy * du
            t = tau_s[i]
            e = phi[k, i] - s
            sa0 += ax * t
            sa1 += ay * t
            sa2 += az * t
            sb0 += ax * c1
            sb1 += ay * c1
            sb2 += az * c1
            sc0 += ax * e
            sc1 += ay * e
            sc2 += az * e
            if velocity_gradient:
                cx, cy, cz = _cross(nx, ny, nz, du, dv, 0.0)
                ccx, ccy, ccz = _cross(nx, ny, nz, cx, cy, cz)
                gvx -= s_s[i] * (du - s * cx + c1 * ccx + (c1 * ccz - s * cz) * dzdx[i])
                gvy -= s_s[i] * (dv - s * cy + c1 * ccy + (c1 * ccz - s * cz) * dzdy[i])
        bc = norm / omega[k] if omega[k] > 0.0 else norm  # (B and C are 0 at omega = 0)
        bx, by, bz = _cross(nx, ny, nz, bc * sb0, bc * sb1, bc * sb2)
        cx, cy, cz = _cross(nx, ny, nz, bc * sc0, bc * sc1, bc * sc2)
        cx, cy, cz = _cross(nx, ny, nz, cx, cy, cz)
        grad_w[k, 0] = norm * sa0 - bx + cx
        grad_w[k, 1] = norm * sa1 - by + cy
        grad_w[k, 2] = norm * sa2 - bz + cz
        grad_v[k, 0] = norm * scale * gvx
        grad_v[k, 1] = norm * scale * gvy
    return grad_w, grad_v


@numba.njit(nogil=True, cache=True, boundscheck=False)
def vote_nearest(q, weight, hemispheres, size, h, width):
    """Nearest-pixel IWEs (float32, ``(h, R D width)``) of the coarse search's points.

    ``q`` (N, R, C, D): raster coordinates u, v (and, with ``hemispheres``, z) of event ``i`` of row ``r``
    turned about direction ``d``, with the half pixel that makes truncation round; it votes ``weight[i, r]``
    into IWE ``r D + d``, moved one ``size`` right where ``z > 0`` with ``hemispheres``.
    """
    n, r_n, _, d_n = q.shape
    stride = r_n * d_n * width
    acc = np.zeros(h * stride)
    for i in range(n):
        for r in range(r_n):
            wt = weight[i, r]
            base = r * d_n * width
            for d in range(d_n):
                u = q[i, r, 0, d]
                if hemispheres:
                    u += size * (q[i, r, 2, d] > 0.0)
                # (held on the raster: a point beyond it, which the margins leave no room for, must not
                # write outside the image)
                col = min(max(int(u), 0), width - 1)
                row = min(max(int(q[i, r, 1, d]), 0), h - 1)
                acc[row * stride + col + base + d * width] += wt
    return acc.astype(np.float32).reshape(h, stride)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def on_track_disc(t_us, x, y, t_rows, cx_rows, cy_rows, r_rows, inner):
    """Events within ``inner`` times the radius of a track's circle at their own times.

    The circle is the rows' ``(cx, cy, r)`` interpolated linearly at each event's time (held at the
    first and last rows beyond them, as ``np.interp``); events and rows are time-sorted, so one
    pass walks both.  Returns the events' indices (K,) and their circles' ``cx, cy, r`` (K,) (px).
    """
    n = t_us.shape[0]
    m = t_rows.shape[0]
    # per row: the circle at its time and its change per µs up to the next row (none after the last)
    slope = np.zeros((m, 3))
    for j in range(m - 1):
        dt = t_rows[j + 1] - t_rows[j]
        if dt > 0:
            slope[j, 0] = (cx_rows[j + 1] - cx_rows[j]) / dt
            slope[j, 1] = (cy_rows[j + 1] - cy_rows[j]) / dt
            slope[j, 2] = (r_rows[j + 1] - r_rows[j]) / dt
    idx = np.empty(n, np.int64)
    out = np.empty((3, n))
    k = 0
    j = 0
    for i in range(n):
        t = t_us[i]
        while j + 1 < m and t_rows[j + 1] <= t:
            j += 1
        dt = t - t_rows[j] if t > t_rows[0] else 0
        cx = cx_rows[j] + dt * slope[j, 0]
        cy = cy_rows[j] + dt * slope[j, 1]
        r = inner * (r_rows[j] + dt * slope[j, 2])
        dx = x[i] - cx
        dy = y[i] - cy
        idx[k] = i  # written always, kept by counting it (no branch to mispredict: 1.3x faster)
        out[0, k], out[1, k], out[2, k] = cx, cy, r
        k += dx * dx + dy * dy <= r * r
    return idx[:k], out[0, :k], out[1, :k], out[2, :k] / inner


@numba.njit(nogil=True, cache=True, boundscheck=False)
def sphere_contrast(u, v, w, cos_a, sin_a, p, axes, n_cells):
    """Sharpness of a ball's surface map for each of K spin axes (:mod:`spin.flight`).

    Each point ``(u, v, w)`` (N,) of the unit sphere (camera frame, at its event's time) is turned by
    its angle about each axis ``axes[k]`` (K, 3) (``cos_a``, ``sin_a`` (N,), Rodrigues' rotation),
    counted in a cube of ``n_cells``^3 cells over [-1, 1]^3 (the sphere's surface crosses about
    ``3 n_cells^2`` of them), polarities ``p`` (N,) 0/1 apart, and the map scored by the sum of the
    squared differences of the two polarities' counts per cell, per point (float64 (K,)): about 1 where
    the events' places on the ball are unrelated, however much of the ball the axis lets them cover,
    and more where the texture's edges pile up.
    """
    n = len(u)
    out = np.zeros(len(axes))
    count = np.zeros((2, n_cells * n_cells * n_cells), np.int32)
    touched = np.empty(n, np.int64)
    half = 0.5 * n_cells
    for k in range(len(axes)):
        nx, ny, nz = axes[k, 0], axes[k, 1], axes[k, 2]
        ss = 0.0
        m = 0
        for i in range(n):
            px, py, pz = u[i], v[i], w[i]
            c, s = cos_a[i], sin_a[i]
            d = (1.0 - c) * (nx * px + ny * py + nz * pz)
            qx = px * c + s * (ny * pz - nz * py) + d * nx
            qy = py * c + s * (nz * px - nx * pz) + d * ny
            qz = pz * c + s * (nx * py - ny * px) + d * nz
            ix = min(max(int((qx + 1.0) * half), 0), n_cells - 1)
            iy = min(max(int((qy + 1.0) * half), 0), n_cells - 1)
            iz = min(max(int((qz + 1.0) * half), 0), n_cells - 1)
            cell = (ix * n_cells + iy) * n_cells + iz
            a = count[p[i], cell]
            b = count[1 - p[i], cell]
            if a == 0 and b == 0:
                touched[m] = cell
                m += 1
            ss += 2.0 * (a - b) + 1.0  # (a + 1 - b)^2 - (a - b)^2
            count[p[i], cell] = a + 1
        out[k] = ss / max(n, 1)
        for j in range(m):
            count[0, touched[j]] = 0
            count[1, touched[j]] = 0
    return out


def load() -> None:
    """Load the compiled loops now (from Numba's cache; compiled on first use after an install)."""
    p = np.zeros((3, 1), np.float32)
    one = np.ones(1, np.float32)
    trig = np.zeros((1, 1), np.float32)
    axes, _ = axes_speeds(np.zeros((1, 3)))
    img, corner, fu, fv, q = vote(p, one, axes, trig, trig, 1.0, 4.0, 9, False, 9, 9, True, 2.0)
    variances(img, img, 1, 9)
    for hemispheres in (False, True):
        vote_nearest(np.zeros((1, 1, 3, 1), np.float32), trig, hemispheres, 9, 9, 9)
    gradients(one, one, one, one, one, axes, np.ones(1), trig, trig, trig, 1.0, corner, fu, fv, q, img, True)
    events = np.zeros(2, EVENT_DTYPE)
    for writable in (True, False):  # columns of events read from a store (strided, maybe read-only)
        events.setflags(write=writable)
        on_track_disc(events["t"], events["x"], events["y"], np.zeros(1, np.int64), np.zeros(1), np.zeros(1),
                      np.ones(1), 1.0)
    unit = np.ones(1)
    sphere_contrast(unit, unit, unit, unit, unit, np.zeros(1, np.int8), np.ones((1, 3)), 4)
