"""Event-camera clock <- frame-camera clock mapping (offset + drift, with uncertainty).

The EVK and the GoPro run on independent clocks: ``t_event_us = offset + (1 + drift) * t_frame``
with drift of tens of ppm. Two ways to fit it:

(a) **sync box** (:func:`fit_sync_box`): an LED blinking a pseudo-random pattern, filmed by the
    GoPro and wired to the EVK trigger input. LED edges are timed in the frames below the frame
    period from the fraction of the exposure the LED was on, matched to the trigger edges, and a
    weighted line is fitted. Goal <= 0.5 ms.
(b) **activity** (:func:`fit_activity`): no hardware; event counts are cross-correlated with
    frame-difference energy (FFT coarse search, then exact interval counting on a fine grid,
    per segment for the drift). Goal: within one frame period.

Frame convention: a frame with presentation time ``t`` (s, container clock, see
:func:`capture.gopro.read_video`) is exposed over ``[t, t + exposure_s]`` of the GoPro clock;
``TimeMap.to_event_us(t)`` is the event-clock time (µs) of the instant ``t``. A constant delay
between the container time and the real exposure start is absorbed into the fitted offset by (a).
Rolling shutter is not modelled (keep the LED small in the image).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np


class SyncError(ValueError):
    """The clocks could not be aligned (message says why)."""


# --------------------------------------------------------------------------- the map
@dataclass
class TimeMap:
    """Linear map from the frame camera's clock (s) to the event camera's clock (µs).

    ``t_event_us = offset_us + (1 + drift_ppm * 1e-6) * (t_frame_s - t_ref_s) * 1e6``

    Attributes
    ----------
    offset_us : float
        Event-clock time (µs) of frame-clock time ``t_ref_s``.
    drift_ppm : float
        Rate difference of the clocks in parts per million (event clock runs faster when > 0).
    t_ref_s : float
        Reference frame-clock time (s), chosen where offset and drift are uncorrelated.
    cov : ndarray, shape (2, 2)
        Covariance of ``(offset_us, drift_ppm)`` (µs², µs·ppm, ppm²).
    rms_us : float
        RMS residual of the fit (µs).
    n : int
        Number of measurements fitted.
    method : str
        ``"sync_box"``, ``"activity"`` or ``"manual"``.
    """

    offset_us: float
    drift_ppm: float = 0.0
    t_ref_s: float = 0.0
    cov: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    rms_us: float = 0.0
    n: int = 0
    method: str = "manual"

    def to_event_us(self, t_frame_s):
        """Event-clock time (µs, float) of frame-clock times ``t_frame_s`` (s), any shape."""
        dt = np.asarray(t_frame_s, np.float64) - self.t_ref_s
        return self.offset_us + (1.0 + self.drift_ppm * 1e-6) * dt * 1e6

    def to_frame_s(self, t_event_us):
        """Frame-clock time (s) of event-clock times ``t_event_us`` (µs): the inverse map."""
        y = np.asarray(t_event_us, np.float64)
        return self.t_ref_s + (y - self.offset_us) / ((1.0 + self.drift_ppm * 1e-6) * 1e6)

    def sigma_us(self, t_frame_s):
        """One-sigma uncertainty (µs) of :meth:`to_event_us` at ``t_frame_s`` from ``cov``."""
        dt = np.asarray(t_frame_s, np.float64) - self.t_ref_s  # d(t_event_us)/d(drift_ppm) = dt [µs/ppm]
        var = self.cov[0, 0] + 2 * dt * self.cov[0, 1] + dt * dt * self.cov[1, 1]
        return np.sqrt(np.maximum(var, 0.0))

    def to_dict(self) -> dict:
        """JSON-able dict for the session attrs (``TimeMap.from_dict`` reverses it)."""
        return {"kind": "linear", "offset_us": float(self.offset_us), "drift_ppm": float(self.drift_ppm),
                "t_ref_s": float(self.t_ref_s), "cov": np.asarray(self.cov, float).tolist(),
                "sigma_offset_us": float(np.sqrt(max(self.cov[0, 0], 0.0))),
                "sigma_drift_ppm": float(np.sqrt(max(self.cov[1, 1], 0.0))),
                "rms_us": float(self.rms_us), "n": int(self.n), "method": self.method}

    @classmethod
    def from_dict(cls, d: dict) -> TimeMap:
        """Rebuild from :meth:`to_dict` output."""
        if d.get("kind", "linear") != "linear":
            raise ValueError(f"unknown time map kind {d.get('kind')!r}")
        return cls(offset_us=float(d["offset_us"]), drift_ppm=float(d["drift_ppm"]), t_ref_s=float(d["t_ref_s"]),
                   cov=np.asarray(d["cov"], float).reshape(2, 2), rms_us=float(d["rms_us"]), n=int(d["n"]),
                   method=str(d["method"]))


def fit_linear(t_frame_s, t_event_us, sigma_us=None, *, method: str = "manual") -> TimeMap:
    """Weighted least-squares :class:`TimeMap` through matched time pairs.

    Parameters
    ----------
    t_frame_s : array_like, shape (N,)
        Frame-clock times (s).
    t_event_us : array_like, shape (N,)
        Event-clock times (µs) of the same instants.
    sigma_us : array_like, shape (N,), optional
        One-sigma errors of the pairs (µs); equal weights when omitted.

    The covariance is scaled up by the reduced chi-square when the scatter exceeds ``sigma_us``.
    """
    x = np.asarray(t_frame_s, np.float64)
    y = np.asarray(t_event_us, np.float64)
    if len(x) < 2:
        raise SyncError(f"need at least 2 matched times to fit offset and drift, got {len(x)}")
    s = np.ones_like(x) if sigma_us is None else np.maximum(np.asarray(sigma_us, np.float64), 1e-3)
    w = 1.0 / s**2
    x_ref = float(np.sum(w * x) / np.sum(w))
    dx = x - x_ref
    r = y - dx * 1e6  # = offset + drift_ppm * dx   (drift_ppm * 1e-6 * dx * 1e6)
    A = np.stack([np.ones_like(dx), dx], axis=1)
    AtW = A.T * w
    N = AtW @ A
    if len(x) == 2 or np.ptp(dx) == 0:
        cov = np.linalg.pinv(N)
    else:
        cov = np.linalg.inv(N)
    p = cov @ (AtW @ r)
    res = r - A @ p
    dof = max(len(x) - 2, 1)
    chi2 = float(np.sum(w * res**2) / dof)
    if sigma_us is None:
        cov = cov * chi2
    else:
        cov = cov * max(chi2, 1.0)
    return TimeMap(offset_us=float(p[0]), drift_ppm=float(p[1]), t_ref_s=x_ref, cov=cov,
                   rms_us=float(np.sqrt(np.mean(res**2))), n=len(x), method=method)


# --------------------------------------------------------------------------- (a) sync box
def led_brightness(frames: Iterable, roi=None, *, grid: int = 32) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Mean brightness of the LED region in every frame (one pass, bounded memory).

    Parameters
    ----------
    frames : iterable
        Gray ``(H, W)`` or BGR ``(H, W, 3)`` uint8 images, or ``(index, t_s, image)`` tuples as
        yielded by :meth:`capture.gopro.Video.frames`.
    roi : (x0, y0, x1, y1), optional
        LED region in pixels (half-open). When omitted, the frames are reduced to a
        ``grid x grid`` array of block means and the block whose brightness varies most over
        time is taken (an LED blinking in a static scene).
    grid : int
        Blocks per side for the automatic search.

    Returns
    -------
    brightness : ndarray of float64, shape (N,)
        Mean pixel value of the region per frame.
    roi : (x0, y0, x1, y1)
        The region used.
    """
    vals, blocks = [], []
    shape = None
    for item in frames:
        img = item[2] if isinstance(item, tuple) else item
        img = np.asarray(img)
        if img.ndim == 3:
            img = img.mean(axis=2)
        if shape is None:
            shape = img.shape
        if roi is not None:
            x0, y0, x1, y1 = roi
            vals.append(float(img[y0:y1, x0:x1].mean()))
        else:
            h, w = shape
            by, bx = max(1, h // grid), max(1, w // grid)
            gy, gx = h // by, w // bx
            blocks.append(img[: gy * by, : gx * bx].reshape(gy, by, gx, bx).mean(axis=(1, 3)).astype(np.float32))
    if shape is None:
        raise SyncError("no frames given")
    if roi is not None:
        return np.asarray(vals), tuple(int(v) for v in roi)
    stack = np.stack(blocks)
    k = int(np.argmax(stack.std(axis=0)))
    gy, gx = divmod(k, stack.shape[2])
    h, w = shape
    by, bx = max(1, h // grid), max(1, w // grid)
    return stack[:, gy, gx].astype(np.float64), (gx * bx, gy * by, (gx + 1) * bx, (gy + 1) * by)


def led_edges(brightness, t_frame_s, exposure_s: float, *, gamma: float = 2.2):
    """LED on/off edges on the frame clock, timed below the frame period.

    A frame exposed over ``[t, t + e]`` sees the LED on for a fraction ``f`` of its exposure; an
    edge inside the exposure is at ``t + e (1 - f)`` (rising) or ``t + e f`` (falling). An edge in
    the shutter-closed gap between two frames is placed mid-gap with a uniform-distribution error.

    Parameters
    ----------
    brightness : array_like, shape (N,)
        LED-region brightness per frame (:func:`led_brightness`).
    t_frame_s : array_like, shape (N,)
        Frame presentation times (s).
    exposure_s : float
        Exposure time per frame (s), at most the frame period.
    gamma : float
        Encoding gamma of the video: 8-bit values ``b`` are linearised as ``(b / 255) ** gamma``
        before the on-fraction is read (GoPro footage is gamma-encoded, about 2.2; 1 for linear data).

    Returns
    -------
    t_s : ndarray, shape (M,)
        Edge times on the frame clock (s).
    polarity : ndarray of int8, shape (M,)
        1 LED turned on, 0 turned off.
    sigma_s : ndarray, shape (M,)
        One-sigma timing error of each edge (s).
    """
    b = (np.clip(np.asarray(brightness, np.float64), 0, None) / 255.0) ** gamma
    t = np.asarray(t_frame_s, np.float64)
    if b.shape != t.shape or len(b) < 3:
        raise SyncError(f"brightness {b.shape} and frame times {t.shape} must match, with >= 3 frames")
    lo_p, hi_p = np.percentile(b, [2, 98])
    if hi_p - lo_p <= 0:
        raise SyncError("LED region brightness is constant: no LED blinking found in the frames")
    mid = 0.5 * (lo_p + hi_p)
    lo, hi = np.median(b[b < mid]), np.median(b[b >= mid])
    f = (b - lo) / (hi - lo)
    # noise of the fraction from the plateaus (median absolute deviation)
    plate = np.concatenate([f[f < 0.25], f[f > 0.75] - 1.0])
    sigma_f = max(1.4826 * np.median(np.abs(plate - np.median(plate))), 1e-3)
    eps = max(4 * sigma_f, 0.03)
    fc = np.clip(f, 0.0, 1.0)
    on = f > 0.5
    k = np.nonzero(on[1:] != on[:-1])[0] + 1
    rising = on[k]
    fa, fb, ta, tb = fc[k - 1], fc[k], t[k - 1], t[k]
    e = float(exposure_s)
    gap_mid = 0.5 * (ta + e + tb)
    gap_sigma = np.maximum(tb - ta - e, 0.0) / np.sqrt(12.0)
    sig_in = np.full(len(k), e * sigma_f * np.sqrt(2.0))
    # rising: fraction on = (t + e - tau) / e ; falling: fraction on = (tau - t) / e
    r_prev = fa > eps
    r_next = fb < 1 - eps
    t_r = np.where(r_prev, ta + e * (1 - fa), np.where(r_next, tb + e * (1 - fb), gap_mid))
    s_r = np.where(r_prev | r_next, sig_in, np.maximum(gap_sigma, sig_in))
    f_prev = fa < 1 - eps
    f_next = fb > eps
    t_f = np.where(f_prev, ta + e * fa, np.where(f_next, tb + e * fb, gap_mid))
    s_f = np.where(f_prev | f_next, sig_in, np.maximum(gap_sigma, sig_in))
    return np.where(rising, t_r, t_f), rising.astype(np.int8), np.where(rising, s_r, s_f)


def _match(x_us, p, y_on, y_off, a, b_ppm, x_ref_us, tol_us):
    """Nearest same-polarity trigger edge for each frame edge under the map; -1 where none within tol."""
    pred = a + (x_us - x_ref_us) * (1 + b_ppm * 1e-6)
    out = np.full(len(x_us), np.nan)
    for pol, y in ((1, y_on), (0, y_off)):
        sel = p == pol
        if not np.any(sel) or len(y) == 0:
            continue
        q = pred[sel]
        i = np.clip(np.searchsorted(y, q), 1, max(len(y) - 1, 1))
        cand = np.stack([y[i - 1], y[np.minimum(i, len(y) - 1)]])
        best = cand[np.argmin(np.abs(cand - q), axis=0), np.arange(len(q))]
        out[sel] = np.where(np.abs(best - q) <= (tol_us[sel] if np.ndim(tol_us) else tol_us), best, np.nan)
    return out


def match_edges(edge_t_s, edge_p, edge_sigma_s, trig_t_us, trig_p, *, frame_period_s: float,
                max_drift_ppm: float = 200.0, prior: TimeMap | None = None, prior_window_s: float | None = None,
                method: str = "sync_box") -> TimeMap:
    """Match LED edges seen in frames with trigger edges and fit the map.

    Every pairing of one of a few anchor frame edges with a same-polarity trigger edge proposes
    an offset; the one under which most frame edges find a trigger edge (tolerance 1.5 frame
    periods plus ``max_drift_ppm`` over the distance to the anchor) wins; then the map is refitted
    and re-matched with a tightening tolerance. With a ``prior`` map (e.g. from
    :func:`fit_activity`) only offsets within ``prior_window_s`` (default 3 frame periods) of it
    are tried, which makes a periodic blink pattern usable.

    Raises
    ------
    SyncError
        When too few edges match or two different offsets explain the edges equally well
        (pattern not pseudo-random enough, or recordings that do not overlap).
    """
    x_us = np.asarray(edge_t_s, np.float64) * 1e6
    p = np.asarray(edge_p)
    sx = np.asarray(edge_sigma_s, np.float64) * 1e6
    ty = np.asarray(trig_t_us, np.float64)
    tp = np.asarray(trig_p)
    y_on, y_off = np.sort(ty[tp == 1]), np.sort(ty[tp == 0])
    if len(x_us) < 4 or len(ty) < 4:
        raise SyncError(f"too few edges to match: {len(x_us)} LED edges in frames, {len(ty)} trigger edges")
    tol0 = 1.5 * frame_period_s * 1e6
    anchors = np.unique(np.linspace(0, len(x_us) - 1, min(7, len(x_us))).round().astype(int))
    best = (-1, 0.0, 0.0, 0)
    scores = []
    window_us = (3 * frame_period_s if prior_window_s is None else prior_window_s) * 1e6
    for ia in anchors:
        ys = y_on if p[ia] == 1 else y_off
        if prior is not None:
            ys = ys[np.abs(ys - prior.to_event_us(x_us[ia] / 1e6)) <= window_us]
        for yj in ys:
            a = yj
            tol = tol0 + max_drift_ppm * 1e-6 * np.abs(x_us - x_us[ia])
            m = _match(x_us, p, y_on, y_off, a, 0.0, x_us[ia], tol)
            ok = ~np.isnan(m)
            n = int(ok.sum())
            off = a - x_us[ia]
            scores.append((n, off))
            if n > best[0]:
                best = (n, a, off, ia)
    n_best, a, off, ia = best
    need = max(4, int(0.3 * min(len(x_us), len(ty) // 2)))
    if n_best < need:
        raise SyncError(f"LED pattern not found in the triggers: best offset matches {n_best} of {len(x_us)} "
                        f"edges (need {need}); check the trigger channel and that the recordings overlap")
    sc = np.array(scores)
    rivals = sc[np.abs(sc[:, 1] - off) > 3 * tol0]
    if len(rivals) and rivals[:, 0].max() >= 0.8 * n_best:
        raise SyncError(f"ambiguous LED pattern: offsets {off / 1e6:.4f} s and "
                        f"{rivals[np.argmax(rivals[:, 0]), 1] / 1e6:.4f} s match {n_best} and "
                        f"{int(rivals[:, 0].max())} edges; use a pseudo-random blink pattern")
    tmap = TimeMap(offset_us=a, drift_ppm=0.0, t_ref_s=x_us[ia] / 1e6)
    tol = tol0 + max_drift_ppm * 1e-6 * np.abs(x_us - x_us[ia])
    return _refine(x_us, p, sx, y_on, y_off, tmap, tol, method)[0]


def _refine(x_us, p, sx, y_on, y_off, tmap, tol, method):
    """Re-match and refit from a close map; returns (map, weighted RMS residual of the matched edges, µs)."""
    for _ in range(4):
        m = _match(x_us, p, y_on, y_off, tmap.offset_us, tmap.drift_ppm, tmap.t_ref_s * 1e6, tol)
        ok = ~np.isnan(m)
        if ok.sum() < 3:
            raise SyncError(f"only {int(ok.sum())} LED edges matched trigger edges after refinement")
        tmap = fit_linear(x_us[ok] / 1e6, m[ok], sx[ok], method=method)
        tol = np.maximum(5 * np.maximum(sx, tmap.rms_us), 200.0)
    w = 1.0 / sx[ok] ** 2
    res = m[ok] - tmap.to_event_us(x_us[ok] / 1e6)
    return tmap, float(np.sqrt(np.sum(w * res**2) / np.sum(w)))


def fit_sync_box(brightness, t_frame_s, triggers, *, exposure_s: float | None = None, channel: int | None = None,
                 led_on_edge: int = 1, max_drift_ppm: float = 200.0, prior: TimeMap | None = None,
                 prior_window_s: float | None = None, gamma: float = 2.2) -> tuple[TimeMap, float]:
    """Fit the map from a sync-box recording (method (a)).

    Parameters
    ----------
    brightness : array_like, shape (N,)
        LED-region brightness per frame (:func:`led_brightness`).
    t_frame_s : array_like, shape (N,)
        Frame presentation times (s) on the GoPro clock.
    triggers : ndarray of TRIGGER_DTYPE
        EVK trigger events (µs, event clock).
    exposure_s : float, optional
        Frame exposure time (s) when known (fixed shutter). When omitted it is estimated: the
        exposure in [0.1, 1] frame period whose edge times fit the triggers with the smallest
        weighted residual (edges timed inside an exposure dominate).
    channel : int, optional
        Trigger channel the LED is wired to (default: all).
    led_on_edge : int
        Trigger polarity that corresponds to the LED turning on (1: rising).
    max_drift_ppm : float
        Largest clock drift considered during matching.
    prior, prior_window_s : TimeMap, float, optional
        A rough map (e.g. :func:`fit_activity`) and how far from it (s) the offset may be; needed
        when the blink pattern is periodic rather than pseudo-random.
    gamma : float
        Encoding gamma of the video (see :func:`led_edges`).

    Returns
    -------
    time_map : TimeMap
        ``method="sync_box"``; ``sigma_us`` gives the uncertainty.
    exposure_s : float
        The exposure used (given or estimated), seconds.
    """
    t = np.asarray(t_frame_s, np.float64)
    tr = np.asarray(triggers)
    if channel is not None:
        tr = tr[tr["id"] == channel]
    if len(tr) == 0:
        raise SyncError(f"no trigger events{'' if channel is None else f' on channel {channel}'}")
    trig_p = np.where(tr["p"] == led_on_edge, 1, 0)
    period = float(np.median(np.diff(t)))
    e0 = period if exposure_s is None else float(exposure_s)
    te, pe, se = led_edges(brightness, t, e0, gamma=gamma)
    tmap = match_edges(te, pe, se, tr["t"], trig_p, frame_period_s=period, max_drift_ppm=max_drift_ppm,
                       prior=prior, prior_window_s=prior_window_s)
    if exposure_s is not None:
        return tmap, e0
    y = tr["t"].astype(np.float64)
    y_on, y_off = np.sort(y[trig_p == 1]), np.sort(y[trig_p == 0])
    grid = np.linspace(0.1, 1.0, 19) * period
    rms = []
    for e in grid:
        te, pe, se = led_edges(brightness, t, e, gamma=gamma)
        rms.append(_refine(te * 1e6, pe, se * 1e6, y_on, y_off, tmap, 1.5 * period * 1e6, "sync_box")[1])
    rms = np.asarray(rms)
    i = int(np.argmin(rms))
    e = grid[i]
    if 0 < i < len(grid) - 1:
        den = rms[i - 1] - 2 * rms[i] + rms[i + 1]
        if den > 0:
            e += 0.5 * (grid[1] - grid[0]) * (rms[i - 1] - rms[i + 1]) / den
    te, pe, se = led_edges(brightness, t, e, gamma=gamma)
    tmap = _refine(te * 1e6, pe, se * 1e6, y_on, y_off, tmap, 1.5 * period * 1e6, "sync_box")[0]
    return tmap, float(e)


# --------------------------------------------------------------------------- (b) activity
def frame_difference_energy(frames: Iterable) -> np.ndarray:
    """Mean absolute difference between consecutive frames (one pass).

    Parameters
    ----------
    frames : iterable
        Gray or BGR uint8 images, or ``(index, t_s, image)`` tuples.

    Returns
    -------
    ndarray of float64, shape (N - 1,)
        ``energy[k-1]`` is the change from frame ``k-1`` to frame ``k`` (grey levels).
    """
    out, prev = [], None
    for item in frames:
        img = item[2] if isinstance(item, tuple) else item
        img = np.asarray(img)
        if img.ndim == 3:
            img = img.mean(axis=2)
        img = img.astype(np.float32)
        if prev is not None:
            out.append(float(np.mean(np.abs(img - prev))))
        prev = img
    return np.asarray(out, np.float64)


def _interval_counts(t_sorted_us, lo_us, hi_us):
    return np.searchsorted(t_sorted_us, hi_us) - np.searchsorted(t_sorted_us, lo_us)


def _corr(a, b):
    a = a - a.mean()
    b = b - b.mean()
    d = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return float(np.sum(a * b) / d) if d > 0 else 0.0


def _fine_offset(ev, lo_s, hi_s, energy, center_us, half_range_us, step_us):
    offs = center_us + np.arange(-half_range_us, half_range_us + step_us / 2, step_us)
    sc = np.array([_corr(_interval_counts(ev, lo_s * 1e6 + o, hi_s * 1e6 + o).astype(float), energy) for o in offs])
    i = int(np.argmax(sc))
    o = offs[i]
    if 0 < i < len(offs) - 1:
        den = sc[i - 1] - 2 * sc[i] + sc[i + 1]
        if den < 0:
            o += 0.5 * step_us * (sc[i - 1] - sc[i + 1]) / den
    return float(o), float(sc[i])


def fit_activity(event_t_us, t_frame_s, energy, *, exposure_s: float | None = None,
                 max_offset_s: float | None = None, segment_s: float = 2.0, min_corr: float = 0.3) -> TimeMap:
    """Fit the map by cross-correlating event activity with frame-difference energy (method (b)).

    Parameters
    ----------
    event_t_us : array_like of int, shape (M,)
        Event times on the event clock (µs), non-decreasing (``events["t"]``).
    t_frame_s : array_like, shape (N,)
        Frame presentation times on the GoPro clock (s).
    energy : array_like, shape (N - 1,)
        Frame-difference energy (:func:`frame_difference_energy`).
    exposure_s : float, optional
        Exposure time (s); the change between frames ``k-1`` and ``k`` is compared with the events
        between the two exposure centres. Default: one frame period.
    max_offset_s : float, optional
        Largest |offset| searched (s); default: the whole overlap the recordings allow.
    segment_s : float
        Length of the segments whose offsets give the drift (s); recordings shorter than three
        segments get drift 0.
    min_corr : float
        Smallest correlation accepted.

    Returns
    -------
    TimeMap
        ``method="activity"``.

    Raises
    ------
    SyncError
        When the best correlation is below ``min_corr`` (no common motion).
    """
    ev = np.asarray(event_t_us, np.float64)
    t = np.asarray(t_frame_s, np.float64)
    e = np.asarray(energy, np.float64)
    if len(e) != len(t) - 1:
        raise SyncError(f"energy has {len(e)} values, expected len(t_frame_s) - 1 = {len(t) - 1}")
    if len(ev) < 10 or len(e) < 10:
        raise SyncError(f"too little data to correlate: {len(ev)} events, {len(e)} frame differences")
    period = float(np.median(np.diff(t)))
    half = 0.5 * (period if exposure_s is None else exposure_s)
    lo_s, hi_s = t[:-1] + half, t[1:] + half
    # coarse: both signals on a grid of one frame period, FFT cross-correlation
    ev_rate = np.bincount(((ev - ev[0]) // (period * 1e6)).astype(np.int64)).astype(float)
    fr = np.interp(np.arange(int((t[-1] - t[0]) / period)) * period + t[0] + half, 0.5 * (lo_s + hi_s), e)
    n = len(ev_rate) + len(fr)
    nfft = 1 << int(np.ceil(np.log2(n)))
    a = ev_rate - ev_rate.mean()
    b = fr - fr.mean()
    xc = np.fft.irfft(np.fft.rfft(a, nfft) * np.conj(np.fft.rfft(b, nfft)), nfft)
    lags = np.arange(nfft)
    lags = np.where(lags > nfft // 2, lags - nfft, lags)
    # xc[L] = sum_m a[m + L] b[m]: event bin m + L (centre ev0 + (m + L + 0.5) P) matches the
    # frame-grid point m (frame clock t0 + half + m P)
    offsets_us = ev[0] + (lags + 0.5) * period * 1e6 - (t[0] + half) * 1e6
    if max_offset_s is not None:
        xc = np.where(np.abs(offsets_us) <= max_offset_s * 1e6, xc, -np.inf)
    coarse = float(offsets_us[int(np.argmax(xc))])
    # fine: exact interval counts, offset grid of period/20 within +-2 periods
    o, c = _fine_offset(ev, lo_s, hi_s, e, coarse, 2 * period * 1e6, period * 1e6 / 20)
    if c < min_corr:
        raise SyncError(f"event activity and frame motion do not correlate (best r = {c:.2f} < {min_corr}); "
                        "record a clap or a moving object seen by both cameras")
    n_seg = int((t[-1] - t[0]) // segment_s)
    if n_seg < 3:
        sig = period * 1e6 / 20 / np.sqrt(12)
        return TimeMap(offset_us=o, drift_ppm=0.0, t_ref_s=0.0, cov=np.diag([sig**2, 0.0]), rms_us=0.0, n=1,
                       method="activity")
    mids, offs = [], []
    bounds = np.linspace(0, len(e), n_seg + 1).astype(int)
    for i0, i1 in zip(bounds[:-1], bounds[1:]):
        seg_e = e[i0:i1]
        if np.std(seg_e) == 0:
            continue
        oi, ci = _fine_offset(ev, lo_s[i0:i1], hi_s[i0:i1], seg_e, o, period * 1e6, period * 1e6 / 40)
        if ci >= min_corr:
            mids.append(0.5 * (lo_s[i0] + hi_s[i1 - 1]))
            offs.append(oi)
    if len(offs) < 3:
        sig = period * 1e6 / 20 / np.sqrt(12)
        return TimeMap(offset_us=o, drift_ppm=0.0, cov=np.diag([sig**2, 0.0]), n=1, method="activity")
    mids = np.asarray(mids)
    return fit_linear(mids, np.asarray(offs) + mids * 1e6, method="activity")
