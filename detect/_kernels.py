"""Compiled loops of the rim fit, the hot-pixel map and the circle's Kalman filter (Numba).

:func:`detect.event_detector.fit_circle` needs, in each sector around the current centre, the
``k``-th and the ``depth``-th outermost event (:func:`sector_tops`: one pass keeps each sector's
``depth`` outermost, where sorting all events by (sector, squared radius) took most of a fit; the
sector from a pseudo-angle, where ``atan2`` took half of that pass), and
then fits a circle to those boundary points with outlier rejection, a few times over
(:func:`rim_fit`: in NumPy, a fit's dozens of calls on arrays of 12-32 points cost more than its
arithmetic); :func:`hot_update` updates :class:`detect.hot_pixels.HotPixelMap` from one block's
events without a pass over every pixel of the sensor; ``kf_*`` and :func:`rts_gain` do the 7-state
filter's algebra for :class:`detect.kalman.CircleKalman` (a dozen NumPy calls per update on 7x7 arrays
cost more than their arithmetic).

The tracker's passes over the events are single loops too: :func:`split_checked` copies a batch's
columns out of its packed records while checking order and coordinates, :func:`box_select` takes the
events around a ball's prediction (and those of them off hot pixels), :func:`kept_events` the ones
left to the search, :func:`moved_near` the events of a window moved along the ball's velocity and
those near the predicted circle, and :func:`surrounded` counts the ring around a fitted circle. In
NumPy each was several passes with a temporary array each; at 20 Mev/s, where the events around a
ball can be most of a slice, those passes took about a fifth of tracking.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from capture.events import EVENT_DTYPE


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _pseudo_angle(dx, dy):
    """A monotone stand-in for the direction angle of ``(dx, dy)``: 0..4 for 0..2 pi (one per quadrant,
    ``tan a / (1 + tan a)`` within each), a few times cheaper than ``atan2``; 2 (pi) for ``(0, 0)``."""
    if dy >= 0.0:
        if dx >= 0.0:
            return dy / (dx + dy) if dx + dy > 0.0 else 2.0
        return 1.0 - dx / (dy - dx)
    if dx < 0.0:
        return 2.0 - dy / (-dx - dy)
    return 3.0 + dx / (dx - dy)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _sectors(x, y, cx, cy, n_sectors):
    """Sector ``floor((atan2(y - cy, x - cx) + pi) n_sectors / 2 pi) mod n_sectors`` of each event, exact on
    the boundaries at multiples of pi/4 (an event straight left of the centre is in sector 0, not
    n - 1), elsewhere up to rounding: (N,) int64 of ``x, y`` (N,) float64 px."""
    # the sectors' first directions as pseudo-angles (exact at the quadrants), and 4 after the last
    bound = np.empty(n_sectors + 1)
    for j in range(n_sectors):
        q, rem = divmod(4 * j, n_sectors)
        a = 0.5 * math.pi * rem / n_sectors
        bound[j] = q + math.sin(a) / (math.sin(a) + math.cos(a))
    bound[n_sectors] = np.inf  # (d may round to 4.0 just below straight left)
    per_quadrant = n_sectors / 4.0
    out = np.empty(len(x), np.int64)
    for i in range(len(x)):
        d = _pseudo_angle(cx - x[i], cy - y[i])  # the angle + pi
        t = d * per_quadrant
        s = min(np.int64(t), n_sectors - 1) if t > 0.0 else 0  # within one of the right sector (0: NaN)
        while bound[s + 1] <= d:
            s += 1
        while s > 0 and bound[s] > d:
            s -= 1
        out[i] = s
    return out


@numba.njit(nogil=True, cache=True, boundscheck=False)
def sector_tops(x, y, cx, cy, n_sectors, k, depth):
    """Per angular sector around ``(cx, cy)``: its events, and its ``k``-th and ``depth``-th outermost.

    Sectors as in :func:`_sectors`.

    Parameters
    ----------
    x, y : (N,) float64 event positions, px.
    k, depth : ranks from outside (1 = the outermost), ``k <= depth``.

    Returns
    -------
    counts : (n_sectors,) int64 events per sector.
    kth : (n_sectors,) int64 index of the ``k``-th outermost event (-1 where fewer).
    kth_rho2, deep_rho2 : (n_sectors,) float64 squared distances of the ``k``-th and the
        ``depth``-th outermost (NaN where fewer). Of equal distances the earlier event ranks outer.
    """
    return _tops(x, y, cx, cy, _sectors(x, y, cx, cy, n_sectors), n_sectors, k, depth)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _tops(x, y, cx, cy, sec, n_sectors, k, depth):
    """:func:`sector_tops` of events whose sectors ``sec`` ((N,) int64, :func:`_sectors`) are known."""
    counts = np.zeros(n_sectors, np.int64)
    top_rho2 = np.full((n_sectors, depth), -1.0)   # descending
    top_idx = np.full((n_sectors, depth), -1, np.int64)
    for i in range(len(x)):
        dx = x[i] - cx
        dy = y[i] - cy
        r2 = dx * dx + dy * dy
        s = sec[i]
        counts[s] += 1
        if r2 <= top_rho2[s, depth - 1]:
            continue
        j = depth - 1
        while j > 0 and top_rho2[s, j - 1] < r2:
            top_rho2[s, j] = top_rho2[s, j - 1]
            top_idx[s, j] = top_idx[s, j - 1]
            j -= 1
        top_rho2[s, j] = r2
        top_idx[s, j] = i
    kth = np.full(n_sectors, -1, np.int64)
    kth_rho2 = np.full(n_sectors, np.nan)
    deep_rho2 = np.full(n_sectors, np.nan)
    for s in range(n_sectors):
        if counts[s] >= k:
            kth[s] = top_idx[s, k - 1]
            kth_rho2[s] = top_rho2[s, k - 1]
        if counts[s] >= depth:
            deep_rho2[s] = top_rho2[s, depth - 1]
    return counts, kth, kth_rho2, deep_rho2


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _kasa(x, y, keep):
    """Algebraic least-squares (Kasa) circle through the points ``(x, y)[keep]`` -> ``(cx, cy, r)``;
    r = 0 where they are collinear."""
    n = 0
    mx = 0.0
    my = 0.0
    for i in range(len(x)):
        if keep[i]:
            n += 1
            mx += x[i]
            my += y[i]
    mx /= n
    my /= n
    suu = svv = suv = suz = svz = 0.0
    for i in range(len(x)):
        if keep[i]:
            u = x[i] - mx
            v = y[i] - my
            z = u * u + v * v
            suu += u * u
            svv += v * v
            suv += u * v
            suz += u * z
            svz += v * z
    det = suu * svv - suv * suv
    if det <= 1e-12:
        return mx, my, 0.0
    a = 0.5 * (suz * svv - svz * suv) / det
    b = 0.5 * (svz * suu - suz * suv) / det
    return mx + a, my + b, math.sqrt(a * a + b * b + (suu + svv) / n)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _circle_normal(bx, by, keep, cx, cy, r):
    """Normal equations of a geometric circle fit at ``(cx, cy, r)`` through the ``keep`` points
    ``(bx, by)``: ``(J^T J, J^T e, ok)`` with J's rows ``(u_x, u_y, 1)`` (``u`` the unit vector from the
    centre to a point) and ``e`` the points' distances from the circle; ``ok`` False where a point sits
    on the centre."""
    a = np.zeros((3, 3))
    g = np.zeros(3)
    u = np.ones(3)
    for j in range(len(bx)):
        if not keep[j]:
            continue
        dx = bx[j] - cx
        dy = by[j] - cy
        d = math.hypot(dx, dy)
        if d <= 0.0:
            return a, g, False
        u[0] = dx / d
        u[1] = dy / d
        for p in range(3):
            g[p] += u[p] * (d - r)
            for q in range(3):
                a[p, q] += u[p] * u[q]
    return a, g, True


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _det3(a):
    """Determinant of a 3x3 ``a``."""
    return (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
            + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _solve3(a, b):
    """``(ok, x)`` of ``a x = b`` for a 3x3 ``a`` (Cramer's rule; ok False where ``a`` is near singular)."""
    det = _det3(a)
    x = np.zeros(3)
    if abs(det) < 1e-9:
        return False, x
    for c in range(3):
        m = a.copy()
        m[:, c] = b
        x[c] = _det3(m) / det
    return True, x


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _dilution(bx, by, keep, cx, cy):
    """How the centre's error of a geometric circle fit grows with the points' spread round the circle:
    ``sqrt((C_xx + C_yy) / 2)`` of ``C = (J^T J)^-1`` (:func:`_circle_normal`); ``sqrt(2 / n)`` for n
    points spread evenly round the whole circle, more for a shorter arc (``inf`` where it is singular)."""
    a, _, ok = _circle_normal(bx, by, keep, cx, cy, 0.0)
    det = _det3(a)
    if not ok or det < 1e-9:
        return math.inf
    # the diagonal of the inverse: cofactors over the determinant
    return math.sqrt(0.5 * ((a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) + (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0])) / det)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def rim_fit(x, y, ignore, cx, cy, n_sectors, k, gap_events, min_sector_events, n_iter):
    """The rim as a circle through each sector's boundary point, fitted again around each new centre.

    Each of ``n_iter`` rounds: in each sector around ``(cx, cy)`` holding at least
    ``max(min_sector_events, k + gap_events)`` events, the ``k``-th outermost event moved outwards
    by ``k`` times the mean gap (in squared radius) to the next ``gap_events`` events (an order
    statistic's inward bias, whatever the local density) is a boundary point, unless ``ignore``
    marks it; a Kasa circle is fitted through them up to 3 times, each time on the points within
    ``max(1.5 px, 3 MAD)`` of the last. Rounds stop once the centre moves less than 0.05 px.

    Parameters
    ----------
    x, y : (N,) float64 event positions, px.
    ignore : (N,) bool, events that cannot be boundary points.
    cx, cy : float, starting centre, px.
    n_sectors : int, angular sectors around the centre.
    k, gap_events : int, the boundary point's rank from outside and the events below it that give
        its gap correction.
    min_sector_events : int, least events for a sector to give a point.
    n_iter : int, most rounds.

    Returns
    -------
    found : bool, False where fewer than 5 sectors qualify or fewer than 5 boundary points are left.
    cx, cy, r : float, the circle, px.
    rms : float, the kept boundary points' RMS distance from it, px.
    n_in : int, boundary points kept.
    dilution : float, the centre's error per px of ``rms`` (:func:`_dilution`).
    """
    r = math.nan
    rms = math.inf
    n_in = 0
    dilution = math.inf
    need = max(min_sector_events, k + gap_events)
    bx = np.empty(n_sectors)
    by = np.empty(n_sectors)
    res = np.empty(n_sectors)
    dev = np.empty(n_sectors)  # the kept points' |res|, sorted
    keep = np.empty(n_sectors, np.bool_)
    new_keep = np.empty(n_sectors, np.bool_)
    for _ in range(n_iter):
        counts, kth, kth_rho2, deep_rho2 = sector_tops(x, y, cx, cy, n_sectors, k, k + gap_events)
        n_ok = 0
        m = 0
        for s in range(n_sectors):
            if counts[s] < need:
                continue
            n_ok += 1
            i = kth[s]
            if ignore[i]:
                continue
            rho2 = kth_rho2[s]
            gap = (rho2 - deep_rho2[s]) / gap_events
            scale = math.sqrt((rho2 + k * gap) / max(rho2, 1e-9))
            bx[m] = cx + (x[i] - cx) * scale
            by[m] = cy + (y[i] - cy) * scale
            m += 1
        if n_ok < 5:
            return False, cx, cy, r, rms, n_in, dilution
        for j in range(m):
            keep[j] = True
        n_keep = m
        fcx = fcy = fr = 0.0
        for _ in range(3):
            if n_keep < 5:
                return False, cx, cy, r, rms, n_in, dilution
            fcx, fcy, fr = _kasa(bx[:m], by[:m], keep[:m])
            for j in range(m):
                res[j] = math.hypot(bx[j] - fcx, by[j] - fcy) - fr
            q = 0
            for j in range(m):
                if keep[j]:
                    dev[q] = abs(res[j])
                    q += 1
            for a in range(1, n_keep):  # insertion sort: at most 32 values
                v = dev[a]
                b = a - 1
                while b >= 0 and dev[b] > v:
                    dev[b + 1] = dev[b]
                    b -= 1
                dev[b + 1] = v
            mad = 0.5 * (dev[(n_keep - 1) // 2] + dev[n_keep // 2])
            limit = max(1.5, 3.0 * 1.4826 * mad)
            same = True
            n_new = 0
            for j in range(m):
                new_keep[j] = abs(res[j]) <= limit
                n_new += new_keep[j]
                same = same and new_keep[j] == keep[j]
            if same:
                break
            for j in range(m):
                keep[j] = new_keep[j]
            n_keep = n_new
        if n_keep < 5:
            return False, cx, cy, r, rms, n_in, dilution
        moved = math.hypot(fcx - cx, fcy - cy)
        cx, cy, r = fcx, fcy, fr
        ss = 0.0
        for j in range(m):
            if keep[j]:
                ss += res[j] * res[j]
        rms = math.sqrt(ss / n_keep)
        n_in = n_keep
        if moved < 0.05:  # sectors would not change
            break
    return True, cx, cy, r, rms, n_in, _dilution(bx[:m], by[:m], keep[:m], cx, cy)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def limb_profile(x, y, cx, cy, r, n_sectors, inner_px, edge_px):
    """Events per sector around ``(cx, cy)`` in two rings of the circle of radius ``r``: the ``inner``
    ring ``[r - inner_px[0], r - inner_px[1])`` and the ``edge`` ring ``[r - edge_px, r + edge_px)``.

    Returns (n_sectors, 2) float64: column 0 the inner ring's counts, column 1 the edge ring's.
    Sectors as in :func:`_sectors`.
    """
    out = np.zeros((n_sectors, 2))
    sec = _sectors(x, y, cx, cy, n_sectors)
    in0, in1 = (r - inner_px[0]) ** 2, (r - inner_px[1]) ** 2
    ed0, ed1 = max(r - edge_px, 0.0) ** 2, (r + edge_px) ** 2
    for i in range(len(x)):
        dx = x[i] - cx
        dy = y[i] - cy
        r2 = dx * dx + dy * dy
        if in0 <= r2 < in1:
            out[sec[i], 0] += 1.0
        elif ed0 <= r2 < ed1:
            out[sec[i], 1] += 1.0
    return out


@numba.njit(nogil=True, cache=True, boundscheck=False)
def lit_rim_fit(x, y, rim, cx, cy, r, k, band_px, min_sector_events, n_iter):
    """The rim as a circle through the sharp edge of the sectors ``rim`` (bool, one per sector) only.

    Each of ``n_iter`` rounds: in each ``rim`` sector around ``(cx, cy)`` holding at least
    ``min_sector_events`` events, the boundary point is the mean of the events within ``band_px`` of its
    ``k``-th outermost (in distance from the centre, and in direction); a geometric circle (Gauss-Newton
    on the distances, from the last circle) is fitted through those points.

    Returns
    -------
    found : bool, False where fewer than 4 sectors give a point or the fit diverges.
    cx, cy, r : float, the circle, px.
    rms : float, the points' RMS distance from it, px.
    dilution : float, the centre's error per px of ``rms`` (:func:`_dilution`).
    """
    n_sectors = len(rim)
    rms = math.inf
    dilution = math.inf
    bx = np.empty(n_sectors)
    by = np.empty(n_sectors)
    for _ in range(n_iter):
        sec = _sectors(x, y, cx, cy, n_sectors)
        counts, kth, kth_rho2, deep_rho2 = _tops(x, y, cx, cy, sec, n_sectors, k, k)
        lo2 = np.full(n_sectors, np.inf)
        hi2 = np.full(n_sectors, -1.0)
        for s in range(n_sectors):
            if rim[s] and counts[s] >= min_sector_events:
                rk = math.sqrt(kth_rho2[s])
                lo2[s] = max(rk - band_px, 0.0) ** 2
                hi2[s] = (rk + band_px) ** 2
        n = np.zeros(n_sectors)
        sr = np.zeros(n_sectors)
        su = np.zeros(n_sectors)
        sv = np.zeros(n_sectors)
        for i in range(len(x)):
            dx = x[i] - cx
            dy = y[i] - cy
            r2 = dx * dx + dy * dy
            if r2 <= 0.0:
                continue
            s = sec[i]
            if lo2[s] <= r2 <= hi2[s]:
                rho = math.sqrt(r2)
                n[s] += 1.0
                sr[s] += rho
                su[s] += dx / rho
                sv[s] += dy / rho
        m = 0
        for s in range(n_sectors):
            if n[s] > 0.0:
                norm = math.hypot(su[s], sv[s])
                if norm <= 0.0:
                    continue
                rho = sr[s] / n[s]
                bx[m] = cx + rho * su[s] / norm
                by[m] = cy + rho * sv[s] / norm
                m += 1
        if m < 4:
            return False, cx, cy, r, rms, math.inf
        fcx, fcy, fr = cx, cy, r
        everything = np.ones(m, np.bool_)
        for _ in range(6):  # Gauss-Newton on (cx, cy, r): residual d - r, Jacobian -(u_x, u_y, 1)
            a, g, ok = _circle_normal(bx[:m], by[:m], everything, fcx, fcy, fr)
            ok_step, step = _solve3(a, g)
            if not (ok and ok_step):
                return False, cx, cy, r, rms, math.inf
            fcx += step[0]
            fcy += step[1]
            fr += step[2]
            if abs(step[0]) + abs(step[1]) + abs(step[2]) < 1e-4:
                break
        if not (fr > 0.0) or not math.isfinite(fcx + fcy + fr):
            return False, cx, cy, r, rms, math.inf
        moved = math.hypot(fcx - cx, fcy - cy)
        cx, cy, r = fcx, fcy, fr
        ss = 0.0
        for j in range(m):
            e = math.hypot(bx[j] - cx, by[j] - cy) - r
            ss += e * e
        rms = math.sqrt(ss / m)
        dilution = _dilution(bx[:m], by[:m], everything, cx, cy)
        if moved < 0.05:
            break
    return True, cx, cy, r, rms, dilution


@numba.njit(nogil=True, cache=True, boundscheck=False)
def hot_update(stored, gain, pixel, cand, mark, stamp, hot, width, height, min_count, ratio):
    """One update of :class:`detect.hot_pixels.HotPixelMap` from a block's events.

    Adds the events to the ``stored`` counts, clears the hot flags of the previous candidates and sets
    them anew on the pixels now at ``min_count`` or more (previous candidates and pixels hit in this
    block: with a decay of at most 1 no other can have risen) that hold ``ratio`` times their 8
    neighbours' mean.

    Parameters
    ----------
    stored : (height * width,) float64, counts / ``gain``; updated in place.
    gain : float, the decay so far (this block's included).
    pixel : (N,) int, flat pixel index ``y * width + x`` of each event.
    cand : (M,) int64, the previous update's candidates.
    mark, stamp : (height * width,) int64 and int: a pixel listed in this update gets ``mark = stamp``
        (``stamp`` new per update).
    hot : (height * width,) bool, the mask; updated in place.
    width, height : int, sensor size, px.
    min_count, ratio : float, the map's thresholds.

    Returns
    -------
    (K,) int64, this update's candidates, in no particular order.
    """
    add = 1.0 / gain
    for p in pixel:
        stored[p] += add
    limit = min_count / gain
    out = np.empty(len(cand) + len(pixel), np.int64)
    n = 0
    for p in cand:
        hot[p] = False
        if stored[p] >= limit and mark[p] != stamp:
            mark[p] = stamp
            out[n] = p
            n += 1
    for p in pixel:
        if stored[p] >= limit and mark[p] != stamp:
            mark[p] = stamp
            out[n] = p
            n += 1
    for i in range(n):
        p = out[i]
        py, px = divmod(p, width)
        nb = 0.0
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                yy, xx = py + dy, px + dx
                if (dy or dx) and 0 <= yy < height and 0 <= xx < width:
                    nb += stored[yy * width + xx]
        hot[p] = stored[p] >= ratio * nb / 8.0
    return out[:n].copy()


_STATE_MEASURED = (0, 1, 6)  # the circle filter's measured states: cx, cy, r


@numba.njit(nogil=True, cache=True, boundscheck=False)
def kf_predict(f, q, x, p):
    """Kalman prediction of state ``x`` (n,) and covariance ``p`` (n, n) by transition ``f`` and
    process noise ``q`` (n, n): ``(f @ x, f @ p @ f.T + q)``, in plain loops (7 states: BLAS calls cost
    more than the sums, and compiling them several seconds)."""
    n = len(x)
    fx = np.zeros(n)
    fp = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            fik = f[i, k]
            if fik != 0.0:
                fx[i] += fik * x[k]
                for j in range(n):
                    fp[i, j] += fik * p[k, j]
    out = q.copy()
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += fp[i, k] * f[j, k]
            out[i, j] += acc
    return fx, out


@numba.njit(nogil=True, cache=True, boundscheck=False)
def kf_update(f, q, x, p, z, r_var):
    """Kalman prediction by ``(f, q)`` and fusion of the measurement ``z = (cx, cy, r)`` of states 0, 1
    and 6 of the circle's filter.

    Parameters
    ----------
    f, q : (7, 7) float64, transition and process noise.
    x, p : (7,), (7, 7) float64, the state and covariance before.
    z, r_var : (3,) float64, the measurement (px) and its variances (px^2).

    Returns
    -------
    xp, pp : the prior state and covariance; x_post, p_post : the posterior's (``p_post`` symmetrised).
    """
    xp, pp = kf_predict(f, q, x, p)
    hp = np.empty((3, 7))  # H pp
    s = np.empty((3, 3))  # H pp H^T + R
    for i in range(3):
        for a in range(7):
            hp[i, a] = pp[_STATE_MEASURED[i], a]
        for j in range(3):
            s[i, j] = hp[i, _STATE_MEASURED[j]]
        s[i, i] += r_var[i]
    # s = L L^T (Cholesky: s is symmetric positive definite; as accurate as an LU solve, where
    # cofactors lose digits with the square of s's condition number)
    l00 = math.sqrt(s[0, 0])
    l10 = s[1, 0] / l00
    l20 = s[2, 0] / l00
    l11 = math.sqrt(s[1, 1] - l10 * l10)
    l21 = (s[2, 1] - l20 * l10) / l11
    l22 = math.sqrt(s[2, 2] - l20 * l20 - l21 * l21)
    nu = np.empty(3)
    for i in range(3):
        nu[i] = z[i] - xp[_STATE_MEASURED[i]]
    gain = np.empty((7, 3))  # (s^-1 H pp)^T: per column of H pp, forward then back substitution
    for a in range(7):
        y0 = hp[0, a] / l00
        y1 = (hp[1, a] - l10 * y0) / l11
        y2 = (hp[2, a] - l20 * y0 - l21 * y1) / l22
        gain[a, 2] = y2 / l22
        gain[a, 1] = (y1 - l21 * gain[a, 2]) / l11
        gain[a, 0] = (y0 - l10 * gain[a, 1] - l20 * gain[a, 2]) / l00
    x_post = xp.copy()
    p_post = np.empty((7, 7))
    for a in range(7):
        for i in range(3):
            x_post[a] += gain[a, i] * nu[i]
        for b in range(7):
            acc = pp[a, b]
            for i in range(3):
                acc -= gain[a, i] * hp[i, b]
            p_post[a, b] = acc
    for a in range(7):
        for b in range(a + 1, 7):
            m = 0.5 * (p_post[a, b] + p_post[b, a])
            p_post[a, b] = m
            p_post[b, a] = m
    return xp, pp, x_post, p_post


@numba.njit(nogil=True, cache=True, boundscheck=False)
def kf_mahalanobis(x, p, zx, zy, var):
    """Squared Mahalanobis distance of the centre ``(zx, zy)`` (px) from state ``x`` (its first two
    entries, covariance ``p``), the measurement's variance ``var`` (px^2) added on each axis."""
    a, b, d = p[0, 0] + var, p[0, 1], p[1, 1] + var
    u, v = zx - x[0], zy - x[1]
    return (d * u * u - 2.0 * b * u * v + a * v * v) / (a * d - b * b)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def rts_gain(p_post, f_next, p_prior_next):
    """Rauch-Tung-Striebel smoother gain ``p_post @ f_next.T @ pinv(p_prior_next)`` (all (n, n); the
    pseudo-inverse: a ``"cv"`` filter's pinned acceleration leaves the prior covariance singular)."""
    return p_post @ f_next.T @ np.linalg.pinv(p_prior_next)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def split_checked(t_in, x_in, y_in, t_before):
    """An event array's columns (its field views, any strides) copied to contiguous arrays and checked,
    in one pass.

    Parameters
    ----------
    t_in, x_in, y_in : (N,) int64 times (µs), unsigned pixel coordinates.
    t_before : int, the time of the event before the first (the previous batch's last), µs.

    Returns
    -------
    t : (N,) int64; x, y : (N,) int32.
    back : int, index of the first event earlier than the one before it (the first compared with
        ``t_before``), -1 if none.
    x_max, y_max : int, the largest coordinates (-1 if N = 0).
    """
    n = len(t_in)
    t = np.empty(n, np.int64)
    x = np.empty(n, np.int32)
    y = np.empty(n, np.int32)
    back, x_max, y_max = -1, -1, -1
    prev = t_before
    for i in range(n):
        ti, xi, yi = t_in[i], np.int32(x_in[i]), np.int32(y_in[i])
        if ti < prev and back < 0:
            back = i
        prev = ti
        x_max = max(x_max, xi)
        y_max = max(y_max, yi)
        t[i], x[i], y[i] = ti, xi, yi
    return t, x, y, back, x_max, y_max


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _first(a, k):
    """``a[:k]``, copied where that is under half of ``a`` (a window or a chain may keep it: at most
    twice its size is held)."""
    return a[:k].copy() if 2 * k < len(a) else a[:k]


@numba.njit(nogil=True, cache=True, boundscheck=False)
def box_select(t, x, y, lo_x, hi_x, lo_y, hi_y, hot, width):
    """The events in a box of whole pixels, and those of them not on a hot pixel, in one pass.

    Parameters
    ----------
    t : (N,) int64 times, µs; x, y : (N,) int32 pixel coordinates.
    lo_x, hi_x, lo_y, hi_y : int, the box: ``lo_x <= x <= hi_x`` and ``lo_y <= y <= hi_y``.
    hot : (height * width,) bool hot-pixel mask (``y * width + x``), or empty: none.

    Returns
    -------
    near : (K,) intp indices of the events in the box.
    tk, xk, yk : (J,) the events in the box not on a hot pixel, in order.
    """
    n = len(x)
    near = np.empty(n, np.intp)
    tk = np.empty(n, np.int64)
    xk = np.empty(n, np.int32)
    yk = np.empty(n, np.int32)
    has_hot = len(hot) > 0
    k = j = 0
    for i in range(n):
        xi, yi = x[i], y[i]
        if lo_x <= xi <= hi_x and lo_y <= yi <= hi_y:
            near[k] = i
            k += 1
            if has_hot and hot[yi * width + xi]:
                continue
            tk[j], xk[j], yk[j] = t[i], xi, yi
            j += 1
    return _first(near, k), _first(tk, j), _first(xk, j), _first(yk, j)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def kept_events(t, x, y, keep, hot, width):
    """The events with ``keep`` set (all if ``keep`` is empty) that are not on a hot pixel (none if
    ``hot`` is empty), as new ``(t, x, y)`` arrays; shapes and mask as in :func:`box_select`."""
    n = len(t)
    tk = np.empty(n, np.int64)
    xk = np.empty(n, np.int32)
    yk = np.empty(n, np.int32)
    all_kept, has_hot = len(keep) == 0, len(hot) > 0
    j = 0
    for i in range(n):
        if (all_kept or keep[i]) and not (has_hot and hot[y[i] * width + x[i]]):
            tk[j], xk[j], yk[j] = t[i], x[i], y[i]
            j += 1
    return _first(tk, j), _first(xk, j), _first(yk, j)


@numba.njit(nogil=True, cache=True, boundscheck=False)
def moved_near(t, x, y, m, vx, vy, cx, cy, reach):
    """Events moved to time ``m`` (µs) along velocity ``(vx, vy)`` (px/s): their positions, and those
    of them that lie within ``reach`` px of ``(cx, cy)`` there.

    Returns
    -------
    xc, yc : (N,) float64 moved positions, px.
    tn, xn, yn : (K,) the events within ``reach`` (as given, not moved), in order.
    """
    n = len(t)
    xc = np.empty(n)
    yc = np.empty(n)
    tn = np.empty(n, np.int64)
    xn = np.empty(n, np.int32)
    yn = np.empty(n, np.int32)
    reach2 = reach * reach
    k = 0
    for i in range(n):
        dt_s = (t[i] - m) * 1e-6
        xi = x[i] - vx * dt_s
        yi = y[i] - vy * dt_s
        xc[i], yc[i] = xi, yi
        dx, dy = xi - cx, yi - cy
        if dx * dx + dy * dy < reach2:
            tn[k], xn[k], yn[k] = t[i], x[i], y[i]
            k += 1
    return xc, yc, _first(tn, k), _first(xn, k), _first(yn, k)


@numba.njit(nogil=True, cache=True)
def ring_radii(r):
    """The ring just outside a circle of radius ``r`` (px) that :func:`ring_counts` and :func:`surrounded`
    look at: its inner radius ``1.15 r + 1``, the radius halving it and its outer radius ``1.5 r + 2`` (px)."""
    r0, r1 = 1.15 * r + 1.0, 1.5 * r + 2.0
    return r0, 0.5 * (r0 + r1), r1


@numba.njit(nogil=True, cache=True, boundscheck=False)
def ring_counts(x, y, cx, cy, r, n_sectors, step):
    """Events in each of ``n_sectors`` directions of the ring just outside the circle ``(cx, cy, r)``
    (px; ``1.15 r + 1`` to ``1.5 r + 2``), in its inner and outer halves (by radius), sector 0 from
    angle -pi; events inside the circle; and of those, events in its outer band (``0.7 r`` to ``r``,
    where any ball fires, a plain one too); from every ``step``-th event of ``x, y`` (px, (N,) float64
    or int32), in float32: ``(counts (2, n_sectors), n_in, n_band)``."""
    r0, rm, r1 = ring_radii(r)
    in2, r02, rm2, r12 = np.float32(r * r), np.float32(r0 * r0), np.float32(rm * rm), np.float32(r1 * r1)
    band2 = np.float32(0.49 * r * r)
    fcx, fcy = np.float32(cx), np.float32(cy)
    to_sector = np.float32(n_sectors / (2.0 * np.pi))
    counts = np.zeros((2, n_sectors), np.int64)
    n_in = 0
    n_band = 0
    for i in range(0, len(x), step):
        dx = np.float32(x[i]) - fcx
        dy = np.float32(y[i]) - fcy
        d2 = dx * dx + dy * dy
        if d2 < in2:
            n_in += 1
            if d2 >= band2:
                n_band += 1
        elif r02 < d2 < r12:
            s = int((math.atan2(dy, dx) + np.float32(np.pi)) * to_sector) % n_sectors
            counts[int(d2 >= rm2), s] += 1
    return counts, n_in, n_band


@numba.njit(nogil=True, cache=True, boundscheck=False)
def surrounded(x, y, cx, cy, r, n_sectors, step):
    """Share of the ``n_sectors`` directions around the circle ``(cx, cy, r)`` (px) in which the ring
    just outside it (``1.15 r + 1`` to ``1.5 r + 2``) holds events at least 0.3 times as dense as the
    disk, from every ``step``-th event of ``x, y`` (px, (N,) float64 or int32), in float32. Its own
    loop, not :func:`ring_counts`': through that, the tracker's surround tests took 0.064 s instead of
    0.015 s on ``bench/replay_bench.py``'s 20 Mev/s session (752 calls, profiled)."""
    r0, _, r1 = ring_radii(r)
    in2, r02, r12 = np.float32(r * r), np.float32(r0 * r0), np.float32(r1 * r1)
    fcx, fcy = np.float32(cx), np.float32(cy)
    to_sector = np.float32(n_sectors / (2.0 * np.pi))
    counts = np.zeros(n_sectors, np.int64)
    n_in = 0
    for i in range(0, len(x), step):
        dx = np.float32(x[i]) - fcx
        dy = np.float32(y[i]) - fcy
        d2 = dx * dx + dy * dy
        if d2 < in2:
            n_in += 1
        elif r02 < d2 < r12:
            s = int((math.atan2(dy, dx) + np.float32(np.pi)) * to_sector) % n_sectors
            counts[s] += 1
    dens_in = n_in / (np.pi * r * r)
    ring_area = np.pi * (r1 * r1 - r0 * r0) / n_sectors
    dense = 0
    for s in range(n_sectors):
        if counts[s] / ring_area >= 0.3 * dens_in:
            dense += 1
    return dense / n_sectors


@numba.njit(nogil=True, cache=True, boundscheck=False)
def cell_counts(x, y, cell_px, gw, gh):
    """Events per cell of ``cell_px`` x ``cell_px`` pixels: a (gh, gw) float32 map from integer pixel
    coordinates ``x, y`` ((N,)); events outside the map are not counted."""
    dens = np.zeros((gh, gw), np.float32)
    shift = 0
    while (1 << shift) < cell_px:
        shift += 1
    pow2 = (1 << shift) == cell_px  # shifts, else divisions
    for i in range(len(x)):
        if x[i] < 0 or y[i] < 0:
            continue
        cx = x[i] >> shift if pow2 else x[i] // cell_px
        cy = y[i] >> shift if pow2 else y[i] // cell_px
        if 0 <= cx < gw and 0 <= cy < gh:
            dens[cy, cx] += 1.0
    return dens


@numba.njit(nogil=True, cache=True, boundscheck=False)
def cluster_stats(labels, dens, n):
    """Each of ``n`` labels' events and bounding box on a (gh, gw) map of cluster ``labels`` (0: none)
    and event counts ``dens``.

    Returns
    -------
    sums : (n,) float64 events per label (label 0's left at 0).
    stats : (n, 4) int64 ``(x0, y0, w, h)`` bounding box in cells (zeros for label 0).
    """
    gh, gw = labels.shape
    sums = np.zeros(n)
    lo_x = np.full(n, gw)
    lo_y = np.full(n, gh)
    hi_x = np.full(n, -1)
    hi_y = np.full(n, -1)
    for cy in range(gh):
        for cx in range(gw):
            lab = labels[cy, cx]
            if lab == 0:
                continue
            sums[lab] += dens[cy, cx]
            lo_x[lab] = min(lo_x[lab], cx)
            hi_x[lab] = max(hi_x[lab], cx)
            lo_y[lab] = min(lo_y[lab], cy)
            hi_y[lab] = max(hi_y[lab], cy)
    stats = np.zeros((n, 4), np.int64)
    for lab in range(1, n):
        if hi_x[lab] >= 0:
            stats[lab, 0], stats[lab, 1] = lo_x[lab], lo_y[lab]
            stats[lab, 2], stats[lab, 3] = hi_x[lab] - lo_x[lab] + 1, hi_y[lab] - lo_y[lab] + 1
    return sums, stats


@numba.njit(nogil=True, cache=True, boundscheck=False)
def near_track(t, x, y, t_row, ends, cx, cy, vx, vy, reach):
    """Indices of the events near a track: each event (time-sorted ``t`` µs, pixel ``x, y``, any
    strides) against the last row ``i`` at or before it (rows sorted by ``t_row`` µs), kept when
    ``t < ends[i]`` (µs) and it lies within ``reach[i]`` px of that row's centre ``(cx, cy)[i]`` px
    moved along its velocity ``(vx, vy)[i]`` px/s. Events before the first row are not kept. (M,)
    arrays for the rows; returns (K,) int64, increasing."""
    n, m = len(t), len(t_row)
    out = np.empty(n, np.int64)
    k = 0
    i = -1
    for j in range(np.searchsorted(t, t_row[0]) if m else n, n):
        tj = t[j]
        while i + 1 < m and t_row[i + 1] <= tj:
            i += 1
        if tj >= ends[i]:
            if i == m - 1:
                break  # after the track's end
            continue
        dt_s = (tj - t_row[i]) * 1e-6
        dx = x[j] - (cx[i] + vx[i] * dt_s)
        dy = y[j] - (cy[i] + vy[i] * dt_s)
        if dx * dx + dy * dy <= reach[i] * reach[i]:
            out[k] = j
            k += 1
    return _first(out, k)


@functools.cache
def load() -> None:
    """Load the compiled loops now (from the cache: about 0.5 s once per process, holding the GIL; after
    an install or an upgrade, compiling them first takes several seconds), not in the first fit or
    block: a tracker made before a recording streams pays it before the stream.
    Once per process (a second thread asking meanwhile waits on Numba's lock)."""
    rim_fit(np.zeros(1), np.zeros(1), np.zeros(1, np.bool_), 0.0, 0.0, 12, 1, 2, 1, 1)
    limb_profile(np.zeros(1), np.zeros(1), 0.0, 0.0, 1.0, 16, (4.0, 2.0), 1.0)
    sector_tops(np.zeros(1), np.zeros(1), 0.0, 0.0, 16, 3, 3)  # (the limb model's check of a refit)
    lit_rim_fit(np.zeros(1), np.zeros(1), np.zeros(16, np.bool_), 0.0, 0.0, 1.0, 3, 1.0, 8, 1)
    hot_update(np.zeros(1), 1.0, np.zeros(1, np.int32), np.zeros(0, np.int64), np.zeros(1, np.int64), 1,
               np.zeros(1, np.bool_), 1, 1, 1.0, 1.0)
    eye = np.eye(7)
    kf_update(eye, eye, np.zeros(7), eye, np.zeros(3), np.ones(3))
    kf_mahalanobis(*kf_predict(eye, eye, np.zeros(7), eye), 0.0, 0.0, 1.0)
    rts_gain(eye, eye, eye)
    events = np.zeros(2, EVENT_DTYPE)
    t, x, y, *_ = split_checked(events["t"], events["x"], events["y"], 0)
    rows = np.zeros(1)
    for writable in (True, False):  # (a batch read from a file or store may be read-only)
        events.setflags(write=writable)
        # a batch's field views: strided and unaligned; one event's: contiguous, aligned or not
        for batch in (events, events[:1], events[1:]):
            split_checked(batch["t"], batch["x"], batch["y"], 0)
            near_track(batch["t"], batch["x"], batch["y"], np.zeros(1, np.int64), np.ones(1, np.int64), rows,
                       rows, rows, rows, rows)
    box_select(t, x, y, 0, 0, 0, 0, np.zeros(1, np.bool_), 1)
    kept_events(t, x, y, np.zeros(2, np.bool_), np.zeros(1, np.bool_), 1)
    moved_near(t, x, y, 0, 0.0, 0.0, 0.0, 0.0, 1.0)
    surrounded(x, y, 0.0, 0.0, 1.0, 12, 1)
    surrounded(np.zeros(1), np.zeros(1), 0.0, 0.0, 1.0, 12, 1)
    ring_counts(np.zeros(1), np.zeros(1), 0.0, 0.0, 1.0, 24, 1)
    ring_radii(1.0)
    dens = cell_counts(x, y, 4, 1, 1)
    cluster_stats(np.zeros((1, 1), np.int32), dens, 1)
