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
def _grey(item) -> np.ndarray:
    """A frame as a grey ``(H, W)`` array: from a gray or BGR image, or an ``(index, t_s, image)``
    tuple of :meth:`capture.gopro.Video.frames`."""
    img = np.asarray(item[2] if isinstance(item, tuple) else item)
    return img.mean(axis=2) if img.ndim == 3 else img


def led_brightness(frames: Iterable, roi=None, *, grid: int = 32) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Mean brightness of the LED region in every frame (one pass, bounded memory).

    Parameters
    ----------
    frames : iterable
        Gray ``(H, W)`` or BGR ``(H, W, 3)`` uint8 images, or ``(index, t_s, image)`` tuples as
        yielded by :meth:`capture.gopro.Video.frames`.
    roi : (x0, y0, x1, y1), optional
        LED region in pixels (half-open). When omitted, the frames are reduced to a
        ``grid x grid`` array of block means and the block is taken whose brightness spreads most
        between its 5th and 95th percentiles over time, stays near those two levels and switches
        between them most often (an LED blinking in a scene where a ball passes, or a player moves).
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
        img = _grey(item)
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
    # an LED is at one of two levels in nearly every frame and switches between them again and
    # again; a ball passing a block changes it for a few frames only (a small spread between the
    # 5th and 95th percentiles), a player moving in it gives the levels in between and few switches
    lo, hi = np.percentile(stack, [5, 95], axis=0)
    spread = hi - lo
    near = np.mean((np.abs(stack - lo) <= 0.15 * spread) | (np.abs(stack - hi) <= 0.15 * spread), axis=0)
    above = stack > 0.5 * (lo + hi)
    switches = np.count_nonzero(above[1:] != above[:-1], axis=0)
    k = int(np.argmax(spread * near ** 2 * switches))
    gy, gx = divmod(k, stack.shape[2])
    h, w = shape
    by, bx = max(1, h // grid), max(1, w // grid)
    return stack[:, gy, gx].astype(np.float64), (gx * bx, gy * by, (gx + 1) * bx, (gy + 1) * by)


def refine_led_roi(frames: Iterable, roi) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """The LED's own pixels around a block found by :func:`led_brightness` (a second pass over the
    frames): a block holds part of the LED and some background, whose compression artefacts at
    the LED's border follow the blinking and bias the fit. The pixels within a block's size
    around ``roi`` that brighten with the block (frames near its two levels; a ball passing is
    left out) by at least half as much as the most are kept; their bounding box is the region.

    Returns
    -------
    brightness : ndarray of float64, shape (N,)
        Mean pixel value of the refined region per frame.
    roi : (x0, y0, x1, y1)
        The refined region (half-open); ``roi`` itself when the block never switched.
    """
    x0, y0, x1, y1 = (int(v) for v in roi)
    bw, bh = x1 - x0, y1 - y0
    crops = []
    for item in frames:
        img = _grey(item)
        crops.append(img[max(0, y0 - bh):y1 + bh, max(0, x0 - bw):x1 + bw].astype(np.float32))
    if not crops:
        raise SyncError("no frames given")
    stack = np.stack(crops)
    ox, oy = max(0, x0 - bw), max(0, y0 - bh)
    block = stack[:, y0 - oy:y1 - oy, x0 - ox:x1 - ox].mean(axis=(1, 2))
    lo, hi = np.percentile(block, [5, 95])  # the LED's two levels; a ball passing is beyond or between
    on, off = np.abs(block - hi) <= 0.25 * (hi - lo), np.abs(block - lo) <= 0.25 * (hi - lo)
    if hi <= lo or not on.any() or not off.any():
        return block.astype(np.float64), (x0, y0, x1, y1)
    swing = stack[on].mean(axis=0) - stack[off].mean(axis=0)
    ys, xs = np.nonzero(swing >= 0.5 * swing.max())
    box = (ox + int(xs.min()), oy + int(ys.min()), ox + int(xs.max()) + 1, oy + int(ys.max()) + 1)
    sel = stack[:, box[1] - oy:box[3] - oy, box[0] - ox:box[2] - ox]
    return sel.mean(axis=(1, 2)).astype(np.float64), box


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


def _on_time_knots(trig_t_us: np.ndarray, trig_p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The LED's cumulative on-time on the event clock, from its trigger edges (µs, 1 = turned on):
    knots ``(y_us, c_us)`` of the piecewise-linear cumulative on-time and its slopes before the first
    and after the last edge (0 or 1)."""
    order = np.argsort(trig_t_us, kind="stable")
    y = np.asarray(trig_t_us, np.float64)[order]
    state = (np.asarray(trig_p)[order] == 1).astype(np.float64)  # the LED's state after each edge
    c = np.concatenate([[0.0], np.cumsum(np.diff(y) * state[:-1])])
    return y, c, 1.0 - state[0], state[-1]


def _on_fraction(y0_us: np.ndarray, y1_us: np.ndarray, knots) -> np.ndarray:
    """Fraction of each event-clock interval ``[y0, y1]`` (µs) during which the LED was on."""
    y, c, before, after = knots

    def cum(q):
        return np.interp(q, y, c) + np.minimum(q - y[0], 0.0) * before + np.maximum(q - y[-1], 0.0) * after

    return (cum(y1_us) - cum(y0_us)) / np.maximum(y1_us - y0_us, 1e-9)


LEVEL_ERROR = 0.01
"""Model error of a partly lit frame's on-fraction from its LED levels (codec, gamma), as a share
of the on/off swing (added to the offset's sigma, scaled by the exposure and by how unevenly
rising and falling edges were timed)."""
LEVEL_ERROR_SATURATED = 0.03
"""The same for an LED whose on level is saturated in the video (at or above :data:`SATURATED_DN`):
the clipped noise pulls the on level down (by 2 % of the swing in the simulator's 120 fps clips)."""
SATURATED_DN = 250.0
MAX_DRIFT_PPM = 500.0
"""Largest clock drift the frame fit accepts, ppm (quartz clocks drift tens of ppm; the edge
matching searches 200 by default)."""

CONTRADICTED_CHI2 = 25.0
"""A given exposure is contradicted by the LED frames when fitting the exposure too lowers their
chi-square by more than this (5 sigma)."""


def exposure_span_s(t_frame_s, exposure_s) -> tuple[np.ndarray, np.ndarray]:
    """Start and end of each frame's exposure on the frame clock (s).

    A camera reads frames at a fixed cadence, so its exposures end together: a frame at ``t``
    with exposure ``e`` is exposed over ``[t + ē - e, t + ē]``, ``ē`` the median of the clip's
    exposures. With one exposure for the clip that is ``[t, t + e]``: the time map then gives
    each exposure's start, and with auto-exposure the start of a frame exposed for ``ē``.

    Parameters
    ----------
    t_frame_s : array_like, shape (N,)
        Frame presentation times (s).
    exposure_s : float or array_like, shape (N,)
        Exposure per frame (s), or one for the clip.
    """
    t = np.asarray(t_frame_s, np.float64)
    e = np.broadcast_to(np.asarray(exposure_s, np.float64), t.shape)
    if not np.all(np.isfinite(e) & (e >= 0)):
        raise SyncError("exposures must be finite and not negative")
    end = t + (float(np.median(e)) if e.size else 0.0)
    return end - e, end


def fit_led_frames(brightness, t_frame_s, trig_t_us, trig_p, start: TimeMap, exposure_s, *,
                   fit_exposure: bool = False, gamma: float = 2.2, search_s: float = 0.0) -> tuple[TimeMap, float]:
    """Fit the map to every frame's LED brightness at once (forward model), from a close ``start``.

    Each frame exposed over ``[t, t + e]`` (frame clock; with one exposure per frame, over
    ``[t + ē - e, t + ē]``, :func:`exposure_span_s`) sees the LED on for the fraction of
    ``[map(t), map(t + e)]`` that the trigger edges (event clock) say it was on; its linearised
    brightness ``(b / 255) ** gamma`` is ``lo + (hi - lo) * fraction``. Offset, drift, the two
    levels (and the exposure when ``fit_exposure``) are fitted together by robust least squares
    over the frames inside the triggers' span, so that no level is taken from frames that were
    partly lit (the medians of :func:`led_edges` are pulled inward by them: a bias of a quarter of
    a millisecond at 120 fps). The covariance comes from the fit's Jacobian and the spread of its
    residuals (a model that fits badly reports a larger sigma); the offset's sigma is at least
    half the range of offsets that fit within one sigma (its profile), which is what bounds it
    when edges fall between exposures (short exposures, a blink period a multiple of the frame
    period): then the offset is the middle of that range.

    Parameters
    ----------
    brightness, t_frame_s : array_like, shape (N,)
        LED-region brightness (0-255) and presentation time (s, frame clock) of every frame.
    trig_t_us, trig_p : array_like, shape (M,)
        Trigger edges on the event clock (µs) and whether the LED turned on (1) or off (0).
    start : TimeMap
        A map within a fraction of an exposure of the truth (e.g. :func:`match_edges`).
    exposure_s : float or array_like, shape (N,)
        Exposure per frame (s): one for the clip or one per frame (GPMF ``SHUT``); the start
        value when ``fit_exposure``.
    fit_exposure : bool
        Fit one exposure for the clip too (one scale for every frame's).
    search_s : float
        Before fitting, try offsets within ``± search_s`` of ``start`` (steps of a quarter
        exposure) and start from the one whose frames fit best (a start a frame or more off).

    Returns
    -------
    time_map : TimeMap
        ``method="sync_box"``; ``rms_us`` is the brightness residual expressed as timing (µs).
    exposure_s : float
        The clip's exposure (fitted, or the median of the given ones), s.

    Raises
    ------
    SyncError
        When fewer than 8 frames lie inside the triggers' span, or the frames do not bound the
        offset within ``max(search_s, exposure)`` (every edge between two exposures, at one phase).
    """
    tmap, e, _, _ = _fit_led_frames(brightness, t_frame_s, trig_t_us, trig_p, start, exposure_s,
                                    fit_exposure=fit_exposure, gamma=gamma, search_s=search_s)
    return tmap, e


def _fit_led_frames(brightness, t_frame_s, trig_t_us, trig_p, start, exposure_s, *, fit_exposure, gamma, search_s):
    """:func:`fit_led_frames`, also returning the fit's squared residual over its inlier frames and
    the residual variance per frame (linearised brightness units)."""
    from scipy.optimize import least_squares

    bl = (np.clip(np.asarray(brightness, np.float64), 0, None) / 255.0) ** gamma
    t = np.asarray(t_frame_s, np.float64)
    e0 = np.broadcast_to(np.asarray(exposure_s, np.float64), t.shape).copy()
    if not np.all(np.isfinite(e0) & (e0 > 0)):
        raise SyncError("exposures must be finite and positive")
    scale_e = float(np.median(e0))  # ē: the exposures end together at ē after the frame time
    knots = _on_time_knots(np.asarray(trig_t_us, np.float64), np.asarray(trig_p))
    y_lo, y_hi = knots[0][0], knots[0][-1]
    a0, b0 = exposure_span_s(t, e0)
    inside = (start.to_event_us(a0) >= y_lo) & (start.to_event_us(b0) <= y_hi)
    t, bl, e0 = t[inside], bl[inside], e0[inside]
    if len(t) < 8:
        raise SyncError(f"only {len(t)} frames lie inside the span of the trigger edges (need 8)")
    t_ref = float(np.mean(t))
    off0 = float(start.to_event_us(t_ref))

    def fractions(x):
        off, drift = x[0], x[1]
        k = x[4] * 1e-6 / scale_e if fit_exposure else 1.0  # x[4]: the clip's (median) exposure, µs
        e = e0 * k
        y0 = off + (1 + drift * 1e-6) * (t - t_ref + scale_e * k - e) * 1e6
        return _on_fraction(y0, y0 + (1 + drift * 1e-6) * e * 1e6, knots)

    def levels(f):
        """Least-squares ``lo, hi`` for fractions ``f`` (closed form)."""
        A = np.stack([1 - f, f], axis=1)
        return np.linalg.lstsq(A, bl, rcond=None)[0]

    def residual(x):
        f = fractions(x)
        return bl - (x[2] + (x[3] - x[2]) * f)

    def costs_at(x, offsets_us, mask):
        """Squared residual of the frames in ``mask`` for each offset (µs), the levels solved and
        the rest of ``x`` kept."""
        out = []
        for o in offsets_us:
            f = fractions(np.concatenate([[o], x[1:]]))
            lo, hi = levels(f)
            out.append(float(np.sum((bl - lo - (hi - lo) * f)[mask] ** 2)))
        return np.asarray(out)

    # the drift stays within what clocks do (MAX_DRIFT_PPM): the start's, from a few matched edges
    # of a short clip, can be thousands of ppm off, and a fit started there stays in that valley
    x0 = np.array([off0, np.clip(start.drift_ppm, -MAX_DRIFT_PPM, MAX_DRIFT_PPM), 0.0, 0.0]
                  + ([scale_e * 1e6] if fit_exposure else []))
    every = np.ones(len(t), bool)
    if search_s > 0:  # a coarse scan of the offset, the levels solved for each
        grid = off0 + np.arange(-search_s, search_s + 1e-12, scale_e / 4) * 1e6
        x0[0] = grid[int(np.argmin(costs_at(x0, grid, every)))]
    f = fractions(x0)
    x0[2], x0[3] = levels(f)
    r0 = residual(x0)
    sigma_b = max(1.4826 * float(np.median(np.abs(r0 - np.median(r0)))), 1e-6)
    partial = bool(np.any((f > 0.02) & (f < 0.98)))
    if partial:  # frames that saw an edge during their exposure time it: fit everything together
        x_scale = [scale_e * 1e6 / 10, 10.0, 0.1, 0.1] + ([scale_e * 1e6 / 10] if fit_exposure else [])
        lower = np.full(len(x0), -np.inf)
        upper = np.full(len(x0), np.inf)
        lower[1], upper[1] = -MAX_DRIFT_PPM, MAX_DRIFT_PPM  # x0's drift is already within them
        sol = least_squares(residual, x0, loss="soft_l1", f_scale=3 * sigma_b, x_scale=x_scale, bounds=(lower, upper))
        x, r, jac = sol.x, sol.fun, sol.jac
    else:  # every edge fell between two exposures: only the gaps bound them (the profile below)
        x, r, jac = x0, r0, None
    s_mad = max(1.4826 * float(np.median(np.abs(r - np.median(r)))), 1e-9)
    keep = np.abs(r) <= 4 * s_mad  # outlier frames (compression, a passing player) do not set sigma
    n_free = len(x) if partial else 3
    s2 = max(float(np.sum(r[keep] ** 2) / max(int(keep.sum()) - n_free, 1)), 1e-12)
    cov = np.zeros((2, 2))
    if partial:
        scale = np.linalg.norm(jac[keep], axis=0)
        scale[scale == 0] = 1.0
        normal = (jac[keep] / scale).T @ (jac[keep] / scale)
        if np.linalg.cond(normal) > 1e12:  # e.g. one edge phase only: offset and exposure trade off
            cov = np.diag([(max(search_s, scale_e) * 1e6) ** 2, start.cov[1, 1]])  # known to a period
        else:
            cov = (np.linalg.inv(normal) / np.outer(scale, scale) * s2)[:2, :2]
    else:
        cov[1, 1] = start.cov[1, 1]  # the drift as the edges gave it
    # the offset's profile: how far it moves, the levels refitted, before the fit is worse by one
    # sigma (chi-square + 1); wider than the Jacobian's sigma where edges fall between exposures
    reach_us = max(search_s, scale_e) * 1e6
    d = np.concatenate([[0.0], np.geomspace(0.5, reach_us, 40)])
    base = costs_at(x, [x[0]], keep)[0]

    def crossing(sign):
        c = costs_at(x, x[0] + sign * d, keep) - base
        above = np.flatnonzero(c > s2)
        if not len(above):
            raise SyncError(f"the LED frames do not time the clocks within {reach_us / 1e3:.1f} ms: every LED "
                            "edge fell between two exposures at the same phase; use a longer exposure or a "
                            "blink period that is not a multiple of the frame period")
        i = above[0]
        return float(np.interp(s2, [c[i - 1], c[i]], [d[i - 1], d[i]])) if i else 0.0

    left, right = crossing(-1.0), crossing(1.0)
    if not partial:
        x = x.copy()
        x[0] += 0.5 * (right - left)  # the middle of the range that fits
    cov[0, 0] = max(cov[0, 0], (0.5 * (left + right)) ** 2)
    lo, hi = (x[2], x[3]) if partial else levels(fractions(x))
    if not hi - lo > 0:
        raise SyncError("the LED's fitted on level is not above its off level: check the LED region")
    e_fit = x[4] * 1e-6 if fit_exposure else scale_e
    # the levels' own model error (codec, gamma, a saturated LED whose clipped noise pulls its on
    # level down) biases every partly lit frame's fraction alike: it shifts rising and falling
    # edges in opposite directions, so it cancels in the offset only where both are timed
    f = fractions(x)
    slope = fractions(np.concatenate([[x[0] + 1.0], x[1:]])) - f  # > 0: a rising edge in the exposure
    lit = keep & (f > 0.02) & (f < 0.98)
    n_rise, n_fall = int(np.sum(lit & (slope > 0))), int(np.sum(lit & (slope < 0)))
    if n_rise + n_fall:
        on_dn = float(np.median(np.asarray(brightness, np.float64)[inside][f >= 0.98])) if np.any(f >= 0.98) else 0.0
        level_error = LEVEL_ERROR_SATURATED if on_dn >= SATURATED_DN else LEVEL_ERROR
        imbalance = max(abs(n_rise - n_fall) / (n_rise + n_fall), 1.0 / np.sqrt(n_rise + n_fall))
        cov[0, 0] += (level_error * imbalance * e_fit * 1e6) ** 2
    tmap = TimeMap(offset_us=float(x[0]), drift_ppm=float(x[1]), t_ref_s=t_ref, cov=cov,
                   rms_us=float(np.sqrt(s2) / (hi - lo) * e_fit * 1e6), n=int(keep.sum()), method="sync_box")
    return tmap, float(e_fit), float(np.sum(r[keep] ** 2)), s2


def fit_sync_box(brightness, t_frame_s, triggers, *, exposure_s=None, channel: int | None = None,
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
    exposure_s : float or array_like of shape (N,), optional
        Frame exposure time (s) when known: one for the clip (fixed shutter), or one per frame
        (auto-exposure, from GPMF ``SHUT``; exposures end together, :func:`exposure_span_s`).
        When omitted it is estimated: the exposure in [0.1, 1] frame period whose edge times fit
        the triggers with the smallest weighted residual (edges timed inside an exposure dominate).
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
        The exposure used (given, their median when one per frame, or estimated), seconds.
    """
    t = np.asarray(t_frame_s, np.float64)
    tr = np.asarray(triggers)
    if channel is not None:
        tr = tr[tr["id"] == channel]
    if len(tr) == 0:
        raise SyncError(f"no trigger events{'' if channel is None else f' on channel {channel}'}")
    trig_p = np.where(tr["p"] == led_on_edge, 1, 0)
    period = float(np.median(np.diff(t)))
    given = None if exposure_s is None else np.broadcast_to(np.asarray(exposure_s, np.float64), t.shape)
    e0 = period if given is None else float(np.median(given))
    te, pe, se = led_edges(brightness, t, e0, gamma=gamma)  # rough edges: the fit below takes each exposure
    tmap = match_edges(te, pe, se, tr["t"], trig_p, frame_period_s=period, max_drift_ppm=max_drift_ppm,
                       prior=prior, prior_window_s=prior_window_s)
    if given is not None:
        fixed, _, cost, _ = _fit_led_frames(brightness, t, tr["t"], trig_p, tmap, given, fit_exposure=False,
                                            gamma=gamma, search_s=period)
        # a given exposure that the frames contradict (a wrong value typed, a shutter that changed)
        # leaves the offset uncertain by as much as the best-fitting exposure moves it
        try:
            free, _, cost_free, s2_free = _fit_led_frames(brightness, t, tr["t"], trig_p, fixed, given,
                                                          fit_exposure=True, gamma=gamma, search_s=0.0)
        except SyncError:
            return fixed, e0
        if (cost - cost_free) / s2_free > CONTRADICTED_CHI2:
            shift = free.to_event_us(fixed.t_ref_s) - fixed.offset_us
            fixed.cov = fixed.cov + np.diag([shift ** 2, 0.0])
        return fixed, e0
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
    best, e_best, cost, s2 = _fit_led_frames(brightness, t, tr["t"], trig_p, tmap, e, fit_exposure=True,
                                             gamma=gamma, search_s=period)
    # the exposure's profile: every exposure the frames do not reject (chi-square within 1 of the
    # best) with its own best offset; the offset is uncertain by at least half their range
    offsets = [best.offset_us]
    for e_try in np.linspace(0.1, 1.0, 10) * period:
        try:
            m, _, c, _ = _fit_led_frames(brightness, t, tr["t"], trig_p, best, e_try, fit_exposure=False,
                                         gamma=gamma, search_s=period)
        except SyncError:
            continue
        if (c - cost) / s2 <= 1.0:
            offsets.append(float(m.to_event_us(best.t_ref_s)))
    half_range = 0.5 * (max(offsets) - min(offsets))
    best.cov = best.cov + np.diag([half_range ** 2, 0.0])
    return best, float(e_best)


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
        img = _grey(item).astype(np.float32)
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


def _corr_at(ev, lo_s, hi_s, energy, offsets_us) -> np.ndarray:
    """Correlation of the event counts between each frame pair's exposure centres, moved by each
    offset (µs), with the frame-difference ``energy``."""
    return np.array([_corr(_interval_counts(ev, lo_s * 1e6 + o, hi_s * 1e6 + o).astype(float), energy)
                     for o in offsets_us])


def _fine_offset(ev, lo_s, hi_s, energy, center_us, half_range_us, step_us):
    offs = center_us + np.arange(-half_range_us, half_range_us + step_us / 2, step_us)
    sc = _corr_at(ev, lo_s, hi_s, energy, offs)
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
    # the correlation is flat-topped (events are counted over whole frame intervals): the offset is
    # known only to the offsets that correlate as well within the correlation's own standard error
    sig = max(period * 1e6 / 20 / np.sqrt(12), _profile_sigma_us(ev, lo_s, hi_s, e, o, c, period * 1e6))
    n_seg = int((t[-1] - t[0]) // segment_s)
    if n_seg < 3:
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
        return TimeMap(offset_us=o, drift_ppm=0.0, cov=np.diag([sig**2, 0.0]), n=1, method="activity")
    mids = np.asarray(mids)
    tmap = fit_linear(mids, np.asarray(offs) + mids * 1e6, method="activity")
    tmap.cov = tmap.cov.copy()
    tmap.cov[0, 0] = max(tmap.cov[0, 0], sig ** 2)  # segments share the whole clip's profile
    return tmap


def _profile_sigma_us(ev, lo_s, hi_s, energy, best_us, r_best, period_us):
    """Offset sigma (µs) of an activity correlation: half of the half-width of the offsets within
    two frame periods of ``best_us`` whose correlation is within one standard error of the best,
    ``(1 - r²) / sqrt(n - 2)``. Checked on simulated clips (``bench/sync_bench.py --activity``):
    the errors were within 1.1 of it on the tuning seeds."""
    offs = best_us + np.arange(-2 * period_us, 2 * period_us + 1e-9, period_us / 50)
    sc = _corr_at(ev, lo_s, hi_s, energy, offs)
    n = len(energy)
    close = offs[sc >= r_best - (1 - r_best ** 2) / np.sqrt(max(n - 2, 1))]
    return 0.25 * float(close.max() - close.min()) if len(close) else 0.0
