"""ESIM-like event generation from a rendered scene.

Per pixel: log intensity ``L = ln(I + eps)``, a reference level set at the last
event, ON/OFF contrast thresholds ``C+`` / ``C-`` with a fixed per-pixel mismatch
(drawn once per sensor), crossing times interpolated linearly between render
steps, several events when one step spans several thresholds, an optional
refractory period. Render steps adapt so that nothing in the image moves more
than ``step_px`` per step, and only pixels that can change are processed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture.events import EVENT_DTYPE
from .scene import LOG_EPS, Scene, disjoint_groups


@dataclass
class SensorState:
    """Per-pixel state of the simulated event sensor, flat arrays of length H*W.

    ``c_on`` / ``c_off``: contrast thresholds (log units), fixed for the sensor's
    life; ``ref``: log level at each pixel's last event; ``last_t_s``: time of the
    last emitted event (for the refractory period); ``sample_L`` / ``sample_t_s``:
    log level and time of each pixel's latest render sample.
    """

    width: int
    height: int
    c_on: np.ndarray
    c_off: np.ndarray
    ref: np.ndarray
    last_t_s: np.ndarray
    sample_L: np.ndarray
    sample_t_s: np.ndarray

    @classmethod
    def new(cls, width: int, height: int, rng: np.random.Generator, *, threshold: float = 0.15,
            threshold_off: float | None = None, mismatch_sigma: float = 0.03,
            min_threshold: float = 0.05) -> SensorState:
        """Fresh sensor: thresholds with mismatch drawn once from ``rng``, reference unset."""
        if threshold <= 0:
            raise ValueError(f"contrast threshold must be positive, got {threshold}")
        n = width * height
        c_off = threshold if threshold_off is None else threshold_off
        on = threshold + mismatch_sigma * rng.standard_normal(n)
        off = c_off + mismatch_sigma * rng.standard_normal(n)
        return cls(width, height, np.maximum(on, min_threshold), np.maximum(off, min_threshold),
                   np.zeros(n), np.full(n, -np.inf), np.zeros(n), np.zeros(n))


def step_events(L0: np.ndarray, L1: np.ndarray, t0_s, t1_s, ref: np.ndarray,
                c_on: np.ndarray, c_off: np.ndarray, last_t_s: np.ndarray | None = None,
                refractory_s: float = 0.0):
    """Events of one render step for N pixels (updates ``ref`` and ``last_t_s`` in place).

    Parameters
    ----------
    L0, L1 : ndarray, shape (N,)
        Log intensity at the start and the end of the step.
    t0_s, t1_s : float or ndarray, shape (N,)
        Step start and end times (s), shared or per pixel.
    ref, c_on, c_off : ndarray, shape (N,)
        Reference log level and the pixels' thresholds.

    Returns
    -------
    t_s, pix, p : ndarray, shape (M,)
        Event times (linear interpolation of the crossing inside the step), pixel
        index into the N inputs, polarity (1 ON, 0 OFF).
    """
    d = L1 - ref
    out_t, out_i, out_p = [], [], []
    for pol, sign, c in ((1, 1.0, c_on), (0, -1.0, c_off)):
        idx = np.flatnonzero(sign * d >= c)
        if idx.size == 0:
            continue
        n = np.floor(sign * d[idx] / c[idx]).astype(np.int64)
        rep = np.repeat(idx, n)
        start = np.cumsum(n) - n
        j = np.arange(rep.size) - np.repeat(start, n) + 1
        level = ref[rep] + sign * j * c[rep]
        slope = L1[rep] - L0[rep]
        frac = np.clip(np.divide(level - L0[rep], slope, out=np.ones_like(slope), where=slope != 0), 0.0, 1.0)
        t0 = t0_s[rep] if np.ndim(t0_s) else t0_s
        t1 = t1_s[rep] if np.ndim(t1_s) else t1_s
        t = t0 + frac * (t1 - t0)
        ref[idx] += sign * n * c[idx]
        if refractory_s > 0 and last_t_s is not None:
            keep = np.ones(rep.size, bool)
            # events of one pixel are consecutive and in time order: walk them by rank j
            for rank in range(1, int(n.max()) + 1):
                sel = np.flatnonzero(j == rank)
                ok = t[sel] - last_t_s[rep[sel]] >= refractory_s
                keep[sel] = ok
                last_t_s[rep[sel[ok]]] = t[sel[ok]]
            rep, t = rep[keep], t[keep]
        elif last_t_s is not None and rep.size:
            last_t_s[idx] = t[np.cumsum(n) - 1]
        out_t.append(t)
        out_i.append(rep)
        out_p.append(np.full(rep.size, pol, np.int8))
    if not out_t:
        return np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int8)
    return np.concatenate(out_t), np.concatenate(out_i), np.concatenate(out_p)


def simulate(scene: Scene, sensor: SensorState, t_start_s: float, t_end_s: float, *,
             n_events: int | None = None, step_px: float = 0.25, max_step_s: float = 1e-3,
             refractory_s: float = 0.0, chunk_elems: int = 1 << 17, t_offset_us: int = 0,
             init: bool = True) -> np.ndarray:
    """Events of ``scene`` seen by ``sensor`` between ``t_start_s`` and ``t_end_s``.

    Time advances in chunks. Within a chunk every object gets its own render step
    (``step_px`` divided by its image speed); a pixel is rendered at the finest step
    of the objects whose swept footprint covers it, and pixels covered by none are
    static background and are not touched. Each pixel's first step in a chunk starts
    from its latest render sample, so pixels switch rates without losing changes.

    Parameters
    ----------
    n_events : int, optional
        Stop once at least this many events exist and return exactly the first
        ``n_events`` (by time).
    step_px : float
        Largest image motion (px) of any scene point per render step.
    max_step_s : float
        Longest render step (s), used when nothing moves fast.
    t_offset_us : int
        Added to every timestamp (µs): event time = ``t_offset_us + floor(t_s * 1e6)``.
    init : bool
        Set every pixel's reference to the scene's log intensity at ``t_start_s``
        (otherwise continue from the sensor's state).

    Returns
    -------
    ndarray of EVENT_DTYPE sorted by ``t``.
    """
    cam = scene.camera
    w, h = cam.width, cam.height
    bg_all = scene.sensor_background()
    if init:
        v, u = np.divmod(np.arange(w * h), w)
        L = np.log(scene.render(u.astype(float), v.astype(float), [t_start_s], bg=bg_all)[0] + LOG_EPS)
        sensor.ref[:] = L
        sensor.sample_L[:] = L
        sensor.sample_t_s[:] = t_start_s
    ts, xs, ys, ps = [], [], [], []
    count = 0
    t = float(t_start_s)
    n_fine = chunk_elems // 8  # pixels rendered per step; sets the chunk length
    while t < t_end_s:
        speeds = np.array([o.max_speed_px_s(cam, t) for o in scene.objects])
        dts = np.where(speeds > 0, step_px / np.maximum(speeds, 1e-12), max_step_s).clip(None, max_step_s)
        dt = float(dts.min()) if dts.size else max_step_s
        k = int(np.clip(chunk_elems // max(n_fine, 1), 4, 512))
        t1 = min(t_end_s, t + k * dt)
        span = t1 - t
        items = [(scene.footprint_pixels(o, t, t1), max(1, int(np.ceil(span / dto - 1e-9))))
                 for o, dto in zip(scene.objects, dts)]
        fine_total = 0
        for flat, n_steps in disjoint_groups(items, w * h):
            fine_total = max(fine_total, flat.size * n_steps)
            times = t + span * np.arange(1, n_steps + 1) / n_steps
            xx = flat % w
            yy = flat // w
            Lk = np.log(scene.render(xx.astype(float), yy.astype(float), times, bg=bg_all[flat]) + LOG_EPS)
            ref = sensor.ref[flat]
            c_on = sensor.c_on[flat]
            c_off = sensor.c_off[flat]
            last = sensor.last_t_s[flat]
            L_prev, t_prev = sensor.sample_L[flat], sensor.sample_t_s[flat]
            for i in range(n_steps):
                et, ei, ep = step_events(L_prev, Lk[i], t_prev, times[i], ref, c_on, c_off, last, refractory_s)
                L_prev, t_prev = Lk[i], times[i]
                if et.size:
                    ts.append(et)
                    xs.append(xx[ei])
                    ys.append(yy[ei])
                    ps.append(ep)
                    count += et.size
            sensor.ref[flat] = ref
            sensor.last_t_s[flat] = last
            sensor.sample_L[flat] = Lk[-1]
            sensor.sample_t_s[flat] = t1
        n_fine = max(fine_total // max(k, 1), 1)
        t = t1
        if n_events is not None and count >= n_events:
            break
    ev = _pack(ts, xs, ys, ps, t_offset_us)
    if n_events is not None:
        ev = ev[:n_events]
    return ev


def _pack(ts, xs, ys, ps, t_offset_us: int) -> np.ndarray:
    if not ts:
        return np.zeros(0, EVENT_DTYPE)
    t = np.concatenate(ts)
    out = np.empty(t.size, EVENT_DTYPE)
    out["t"] = t_offset_us + np.floor(t * 1e6 + 1e-6).astype(np.int64)
    out["x"] = np.concatenate(xs)
    out["y"] = np.concatenate(ys)
    out["p"] = np.concatenate(ps)
    return out[np.argsort(out["t"], kind="stable")]


def noise_events(width: int, height: int, t0_us: int, t1_us: int, rng: np.random.Generator, *,
                 rate_hz_per_px: float = 0.1, hot_pixels: int = 0, hot_rate_hz: float = 2000.0,
                 hot_xy: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Background-activity noise and hot pixels over ``[t0_us, t1_us)``.

    Returns ``(events, hot_xy)``: events (EVENT_DTYPE, sorted) with uniform random
    pixels, times and polarities at ``rate_hz_per_px`` per pixel, plus ``hot_pixels``
    pixels (``hot_xy`` (n, 2) columns x, y; drawn if not given) firing at ``hot_rate_hz``.
    """
    span_s = max(t1_us - t0_us, 0) * 1e-6
    n = rng.poisson(rate_hz_per_px * width * height * span_s)
    t = rng.integers(t0_us, max(t1_us, t0_us + 1), n)
    x = rng.integers(0, width, n)
    y = rng.integers(0, height, n)
    p = rng.integers(0, 2, n)
    if hot_xy is None:
        hot_xy = np.column_stack([rng.integers(0, width, hot_pixels), rng.integers(0, height, hot_pixels)])
    hot_xy = np.asarray(hot_xy, np.int64).reshape(-1, 2)
    if len(hot_xy):
        nh = rng.poisson(hot_rate_hz * span_s, len(hot_xy))
        t = np.r_[t, rng.integers(t0_us, max(t1_us, t0_us + 1), nh.sum())]
        x = np.r_[x, np.repeat(hot_xy[:, 0], nh)]
        y = np.r_[y, np.repeat(hot_xy[:, 1], nh)]
        p = np.r_[p, rng.integers(0, 2, nh.sum())]
    ev = np.empty(t.size, EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = t, x, y, p
    return ev[np.argsort(ev["t"], kind="stable")], hot_xy


def merge(*batches: np.ndarray) -> np.ndarray:
    """Merge event batches into one array sorted by ``t`` (stable)."""
    ev = np.concatenate([np.asarray(b, EVENT_DTYPE) for b in batches]) if batches else np.zeros(0, EVENT_DTYPE)
    return ev[np.argsort(ev["t"], kind="stable")]
