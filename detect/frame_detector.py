"""Ball detection in camera frames with OpenCV Hough circles.

The frame is converted to grey and blurred; a background model (MOG2) gives a
foreground mask so that static round things (court markings, lamps) are
ignored once the model has seen a few frames; ``cv2.HOUGH_GRADIENT_ALT`` finds
circles in the radius range, inside an optional search region (the track's
prediction). Each circle is scored by the foreground fraction of its disk
and by the Hough accumulator order.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class FrameCircle:
    """A circle found in a frame: centre ``(cx, cy)`` and radius ``r`` in px, score 0..1."""

    cx: float
    cy: float
    r: float
    score: float


def _refine(blurred: np.ndarray, cx: float, cy: float, r: float, band_px: float = 3.0):
    """Sub-pixel circle from the gradient-weighted rim pixels near ``(cx, cy, r)``.

    Pixels within ``band_px`` of the rim whose gradient is mostly radial are
    fitted with a gradient-magnitude-weighted algebraic circle.
    Returns ``(cx, cy, r)`` or None.
    """
    h, w = blurred.shape
    x0, y0 = max(0, int(cx - r - band_px - 1)), max(0, int(cy - r - band_px - 1))
    x1, y1 = min(w, int(cx + r + band_px + 2)), min(h, int(cy + r + band_px + 2))
    if x1 - x0 < 5 or y1 - y0 < 5:
        return None
    crop = blurred[y0:y1, x0:x1].astype(np.float32)
    gx = cv2.Sobel(crop, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(crop, cv2.CV_32F, 0, 1, ksize=3)
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    dx, dy = xx - cx, yy - cy
    d = np.hypot(dx, dy) + 1e-9
    mag = np.hypot(gx, gy)
    radial = np.abs(gx * dx + gy * dy) / (d * (mag + 1e-9))
    sel = (np.abs(d - r) <= band_px) & (radial > 0.8)
    if sel.sum() < 12:
        return None
    wgt = mag[sel].astype(np.float64)
    sel &= mag >= 0.3 * wgt.max()
    if sel.sum() < 12:
        return None
    px, py, wgt = xx[sel], yy[sel], mag[sel].astype(np.float64)
    mx, my = np.average(px, weights=wgt), np.average(py, weights=wgt)
    u, v = px - mx, py - my
    sw = np.sqrt(wgt)
    a = np.stack([u, v, np.ones_like(u)], axis=1) * sw[:, None]
    sol, *_ = np.linalg.lstsq(a, (u * u + v * v) * sw, rcond=None)
    ncx, ncy = sol[0] / 2 + mx, sol[1] / 2 + my
    nr = float(np.sqrt(max(sol[2] + (sol[0] / 2) ** 2 + (sol[1] / 2) ** 2, 0.0)))
    if np.hypot(ncx - cx, ncy - cy) > band_px or abs(nr - r) > band_px:
        return None
    return float(ncx), float(ncy), nr


def _gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


class FrameDetector:
    """Hough-circle ball detector with a background model over successive frames.

    Parameters
    ----------
    r_range : (float, float)
        Expected ball radius range in frame pixels.
    blur_sigma_px : float
        Gaussian blur before the Hough transform, px.
    circularity : float
        ``param2`` of ``HOUGH_GRADIENT_ALT`` (0..1, higher = rounder circles only).
    min_foreground : float
        Least foreground fraction of a circle's disk once the background model
        has seen ``warmup_frames`` frames.
    background_scale : float
        The background model runs on the frame resized by this factor (speed).
    """

    def __init__(self, r_range=(5.0, 100.0), *, blur_sigma_px: float = 1.0, circularity: float = 0.75,
                 canny_high: float = 120.0, min_foreground: float = 0.3, warmup_frames: int = 3,
                 background_scale: float = 0.25):
        self.r_range = (float(r_range[0]), float(r_range[1]))
        self.blur_sigma_px = float(blur_sigma_px)
        self.circularity = float(circularity)
        self.canny_high = float(canny_high)
        self.min_foreground = float(min_foreground)
        self.warmup_frames = int(warmup_frames)
        self.background_scale = float(background_scale)
        self._bg = cv2.createBackgroundSubtractorMOG2(history=50, varThreshold=16, detectShadows=False)
        self._seen = 0

    def detect(self, image: np.ndarray, *, roi: tuple[float, float, float] | None = None,
               r_range: tuple[float, float] | None = None, max_circles: int = 3,
               search: bool = True, learn: bool = True) -> list[FrameCircle]:
        """Circles in ``image`` (grey or BGR), best first.

        Every frame of the sequence should pass through here (it updates the
        background model); ``search=False`` only does that. A second region of the same frame
        is searched with ``learn=False`` (the model compares without learning the frame again).

        Parameters
        ----------
        image : ndarray, shape (H, W) or (H, W, 3)
            The frame (already in the event camera's pixel geometry if it is fused
            with events).
        roi : (cx, cy, half_size) or None
            Search only the square of half size ``half_size`` px around ``(cx, cy)``.
        r_range : (float, float) or None
            Radius range for this frame (default: the detector's).
        """
        gray = _gray(image)
        sc = self.background_scale
        small = cv2.resize(gray, None, fx=sc, fy=sc, interpolation=cv2.INTER_AREA) if sc != 1 else gray
        fg = self._bg.apply(small, learningRate=-1 if learn else 0)
        self._seen += learn
        if not search:
            return []
        use_fg = self._seen > self.warmup_frames
        rmin, rmax = r_range if r_range is not None else self.r_range
        h, w = gray.shape
        x0, y0, x1, y1 = 0, 0, w, h
        if roi is not None:
            cx, cy, half = roi
            x0, y0 = max(0, int(cx - half)), max(0, int(cy - half))
            x1, y1 = min(w, int(cx + half) + 1), min(h, int(cy + half) + 1)
            if x1 - x0 < 2 * rmin or y1 - y0 < 2 * rmin:
                return []
        crop = cv2.GaussianBlur(gray[y0:y1, x0:x1], (0, 0), self.blur_sigma_px)
        circles = cv2.HoughCircles(crop, cv2.HOUGH_GRADIENT_ALT, dp=1.5, minDist=max(2.0, rmin),
                                   param1=self.canny_high, param2=self.circularity,
                                   minRadius=max(1, int(np.floor(rmin))), maxRadius=int(np.ceil(rmax)))
        if circles is None:
            return []
        out = []
        for rank, (cx, cy, r) in enumerate(circles.reshape(-1, 3)[: 4 * max_circles]):
            fine = _refine(crop, float(cx), float(cy), float(r))
            if fine is not None:
                cx, cy, r = fine
            cx, cy = cx + x0, cy + y0
            if use_fg:
                frac = self._foreground(fg, cx * sc, cy * sc, max(r * sc, 0.5))
                if frac < self.min_foreground:
                    continue
            else:
                frac = 0.5
            out.append(FrameCircle(float(cx), float(cy), float(r), frac / (1.0 + 0.2 * rank)))
            if len(out) >= max_circles:
                break
        return out

    @staticmethod
    def _foreground(fg: np.ndarray, cx: float, cy: float, r: float) -> float:
        """Foreground fraction of the disk ``(cx, cy, r)`` in mask ``fg`` (mask pixels)."""
        h, w = fg.shape
        x0, x1 = max(0, int(np.floor(cx - r))), min(w, int(np.ceil(cx + r)) + 1)
        y0, y1 = max(0, int(np.floor(cy - r))), min(h, int(np.ceil(cy + r)) + 1)
        if x1 <= x0 or y1 <= y0:
            return 0.0
        yy, xx = np.mgrid[y0:y1, x0:x1]
        disk = (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r
        if not disk.any():
            return float(fg[min(max(int(round(cy)), 0), h - 1), min(max(int(round(cx)), 0), w - 1)] > 0)
        return float(np.mean(fg[y0:y1, x0:x1][disk] > 0))
