"""Ball detection in short slices of events (1-2 ms).

Two steps over the events of a slice (the density map's counts and clusters' statistics, and the rim
fit, compiled in :mod:`detect._kernels`; the map's blur and labelling in OpenCV):

* :func:`find_candidates` builds a coarse event-density map (cells of
  ``cell_px`` pixels), thresholds it against the slice's noise level and keeps
  the connected components whose size fits a ball of the expected radius range.
* :func:`fit_circle` fits a circle to the events of one candidate after motion
  compensation (events moved to a reference time along the centre velocity).
  A spinning textured ball fires over its whole disk and a translating one
  mostly at its leading and trailing edges; in both cases the *outer boundary*
  of the compensated events is the ball's rim, so the fit takes, in each of
  ``n_sectors`` angular sectors around the current centre, the outermost events
  (robustly: the ``k_outer``-th from outside) and fits a circle to those
  boundary points with outlier rejection. The score says how circle-like the
  boundary is (sector coverage, boundary residual, events inside vs around).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from detect._kernels import cell_counts, cluster_stats, rim_fit


@dataclass(frozen=True)
class CircleFit:
    """Result of a circle fit on events.

    Attributes
    ----------
    cx, cy, r : float
        Circle centre and radius, px, at the reference time of the fit.
    score : float
        Circle-likeness 0..1.
    sigma_px : float
        Standard deviation of the centre estimate, px.
    n_events : int
        Events used (after noise filtering).
    coverage : float
        Share of the angular sectors whose boundary point lies on the fitted rim, 0..1.
    disc_fill : float
        Share of the events well inside the rim (within ``0.7 r`` of the centre), 0..1: low for a
        ball that fires only at its rim (a plain ball), about half for a textured one.
    """

    cx: float
    cy: float
    r: float
    score: float
    sigma_px: float
    n_events: int
    coverage: float = 1.0
    disc_fill: float = 1.0


def _count_image(x: np.ndarray, y: np.ndarray, pad: int) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Event counts on a local pixel grid holding the rounded positions ``(x, y)`` with ``pad`` px of
    margin: the image (float32, (h, w)), the flat image index of each event, and the sensor pixel
    ``(x0, y0)`` of the image's pixel (0, 0)."""
    xi, yi = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
    x0, y0 = int(xi.min()) - pad, int(yi.min()) - pad
    w, h = int(xi.max()) - x0 + pad + 1, int(yi.max()) - y0 + pad + 1
    idx = (yi - y0) * w + (xi - x0)
    return np.bincount(idx, minlength=w * h).astype(np.float32).reshape(h, w), idx, (x0, y0)


def density_filter(x: np.ndarray, y: np.ndarray, *, min_neighbours: int = 2) -> np.ndarray:
    """Mask of events with at least ``min_neighbours`` other events in their 3x3 pixel neighbourhood.

    Removes isolated noise events. ``x``, ``y`` may be float (motion-compensated); they
    are rounded to pixels on a local grid.
    """
    if len(x) == 0:
        return np.zeros(0, bool)
    img, idx, _ = _count_image(x, y, 1)
    nb = cv2.boxFilter(img, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return nb.reshape(-1)[idx] - 1.0 >= min_neighbours


def fit_circle(x: np.ndarray, y: np.ndarray, *, center0: tuple[float, float], n_sectors: int = 32,
               k_outer: int = 3, gap_events: int = 4, min_sector_events: int = 8, n_iter: int = 3,
               max_events: int = 4000,
               r_range: tuple[float, float] = (3.0, 200.0), ignore: np.ndarray | None = None) -> CircleFit | None:
    """Fit the ball's rim to motion-compensated events.

    Parameters
    ----------
    x, y : ndarray of float, shape (N,)
        Event positions (px) already moved to the fit's reference time.
    center0 : (float, float)
        Starting centre, px (e.g. the events' centroid or the track prediction).
    n_sectors : int
        Most angular sectors for the boundary search (fewer, down to 12, when there are fewer than
        ``1.5 min_sector_events`` events per sector).
    k_outer : int
        In each sector the ``k_outer``-th outermost event is the boundary point
        (robust to ``k_outer - 1`` stray events); it is moved outwards by
        ``k_outer`` times the mean gap (in squared radius) to the next
        ``gap_events`` events, which removes the inward bias of an order
        statistic whatever the local event density.
    min_sector_events : int
        Sectors with fewer events give no boundary point.
    r_range : (float, float)
        Accepted radius range, px.
    max_events : int
        Larger inputs are subsampled evenly to this many events (speed).
    ignore : ndarray of bool, shape (N,), optional
        Events that cannot be boundary points (e.g. on the sensor border, where
        the outermost events are cut by the sensor rather than by the ball's rim, or where
        something touches the ball) and do not count in the score's share of events inside.

    Returns
    -------
    CircleFit or None
        None if there are too few boundary points or the radius is out of range.

    Raises
    ------
    ValueError
        ``n_sectors`` below 12, or ``k_outer``, ``gap_events`` or ``min_sector_events`` below 1.
    """
    if n_sectors < 12 or k_outer < 1 or gap_events < 1 or min_sector_events < 1:
        raise ValueError(f"fit_circle needs n_sectors >= 12 and k_outer, gap_events, min_sector_events >= 1, got "
                         f"{n_sectors}, {k_outer}, {gap_events}, {min_sector_events}")
    x, y = np.ascontiguousarray(x, np.float64), np.ascontiguousarray(y, np.float64)  # (one compiled version)
    n = len(x)
    if n < 3 * min_sector_events:
        return None
    # fewer sectors for few events (a sparse window), so that each still holds min_sector_events
    n_sectors = int(np.clip(n // (1.5 * min_sector_events), 12, n_sectors))
    if n > max_events:
        step = n / max_events
        sub = (np.arange(max_events) * step).astype(np.int64)
        x, y = x[sub], y[sub]
        ignore = None if ignore is None else ignore[sub]
    ignore = np.zeros(len(x), np.bool_) if ignore is None else np.ascontiguousarray(ignore, np.bool_)
    found, cx, cy, r, rms, n_in, dilution = rim_fit(x, y, ignore, float(center0[0]), float(center0[1]), n_sectors,
                                                    k_outer, gap_events, min_sector_events, n_iter)
    if not found:
        return None
    if not (r_range[0] <= r <= r_range[1]):
        return None
    d2 = (x - cx) ** 2 + (y - cy) ** 2
    inside = np.count_nonzero((d2 <= (r + 1.5) ** 2) & ~ignore) / max(np.count_nonzero(~ignore), 1)
    disc_fill = np.count_nonzero(d2 <= (0.7 * r) ** 2) / len(d2)
    coverage = n_in / n_sectors
    sigma_rim = max(1.5, 0.08 * r)  # a rim found from sparse texture scatters by a few % of r
    score = coverage * inside * float(np.exp(-0.5 * (rms / sigma_rim) ** 2))
    return CircleFit(cx, cy, r, float(score), centre_sigma_px(dilution, rms), n, float(coverage), float(disc_fill))


def centre_sigma_px(dilution: float, rms_px: float) -> float:
    """Sigma (px) of a rim fit's centre from its points' ``rms_px`` scatter about the circle (at least 0.3 px:
    the pixel grid) and its ``dilution`` (the centre's error per px of scatter: ``sqrt(2 / n)`` for ``n``
    points round the whole rim, more on a shorter arc; at most 10)."""
    return float(min(dilution, 10.0) * max(rms_px, 0.3))


SIGMA_FIT_SCALE = 1.5
"""The circle's uncertainty (:func:`circle_sigma_px`) holds the rim fit's own centre sigma (from its
points' scatter, :func:`centre_sigma_px`) times this, ..."""
SIGMA_RIM_ONLY_SCALE, SIGMA_RIM_ONLY_FILL = 0.3, 0.25
"""... for a ball whose events fill less than ``SIGMA_RIM_ONLY_FILL`` of its disc (``disc_fill``: a
plain ball, seen only at its rim), this times the radius times the share it lacks (its shading pulls
the rim towards the light: up to 5-9 % of the radius, 90th percentile, on the benchmark's plain balls), ..."""
SIGMA_ARC_SCALE, SIGMA_ARC_FULL = 0.1, 0.8
"""... for a rim that shows on less than ``SIGMA_ARC_FULL`` of its sectors (``coverage``: an unlit
limb, a ball partly hidden), this times the radius times the share it lacks, ..."""
SIGMA_FLOOR_PX = 0.22
"""... and this (px: the pixel grid's limit, and the rim's outward bias of a few tenths of a pixel
that the radius shows on most textured balls), all four in quadrature."""


def circle_sigma_px(fit: CircleFit) -> float:
    """Uncertainty (1 sigma, px) of a fitted circle's centre and radius: the true centre lies within
    ``2 sigma`` of ``(fit.cx, fit.cy)``, and the true radius within ``2 sigma`` of ``fit.r``, on 95 %
    of fits.

    The rim fit's own sigma (:func:`centre_sigma_px`) counts only its points' scatter. A ball that
    fires only at its rim is lit on one side: the rim on its shaded side fires less and later, and the
    fit leans towards the light by more than the scatter says; so does a fit on part of its rim.
    Neither shows in the fit's residuals (an inset on one side is a shifted, smaller circle), so both
    are bounded by a share of the radius. Constants (:data:`SIGMA_FIT_SCALE`,
    :data:`SIGMA_RIM_ONLY_SCALE`, :data:`SIGMA_ARC_SCALE`, :data:`SIGMA_FLOOR_PX` and their
    thresholds) calibrated on ``bench/detect_bench.py``'s rows, seeds 1-10 (held out: 101, 102, 11-16).
    """
    rim_only = SIGMA_RIM_ONLY_SCALE * fit.r * max(0.0, SIGMA_RIM_ONLY_FILL - fit.disc_fill)
    arc = SIGMA_ARC_SCALE * fit.r * max(0.0, SIGMA_ARC_FULL - fit.coverage)
    return float(math.sqrt((SIGMA_FIT_SCALE * fit.sigma_px) ** 2 + rim_only ** 2 + arc ** 2 + SIGMA_FLOOR_PX ** 2))


def hough_circles(x: np.ndarray, y: np.ndarray, *, r_range: tuple[float, float], max_circles: int = 3,
                  blur_px: float = 2.0, vote: float = 0.5) -> list[tuple[float, float, float]]:
    """Round blobs in the image of a cluster's events (OpenCV ``HOUGH_GRADIENT_ALT``).

    Used where a cluster holds the ball and something touching it (an arm, a racket, a
    second ball): the rim fit of the whole cluster fails, but the ball's disk (a textured
    ball) or ring (a plain one) is still a circle in the event-count image.

    Parameters
    ----------
    x, y : ndarray of float, shape (N,)
        Event positions (px), motion-compensated.
    r_range : (float, float)
        Radius range, px.
    blur_px : float
        Gaussian blur of the count image (sigma, px).
    vote : float
        Least circle "perfectness" (``param2`` of ``HOUGH_GRADIENT_ALT``, 0..1).

    Returns
    -------
    list of (cx, cy, r)
        In px, best first.
    """
    if len(x) < 20:
        return []
    pad = int(np.ceil(3 * blur_px)) + 2
    img, _, (x0, y0) = _count_image(x, y, pad)
    img = cv2.GaussianBlur(img, (0, 0), blur_px)
    peak = float(img.max())
    if peak <= 0:
        return []
    u8 = np.clip(img * (255.0 / peak), 0, 255).astype(np.uint8)
    found = cv2.HoughCircles(u8, cv2.HOUGH_GRADIENT_ALT, dp=1.5, minDist=max(2.0, r_range[0]), param1=60,
                             param2=vote, minRadius=max(1, int(np.floor(r_range[0]))),
                             maxRadius=int(np.ceil(r_range[1])))
    if found is None:
        return []
    return [(float(cx) + x0, float(cy) + y0, float(r)) for cx, cy, r in found.reshape(-1, 3)[:max_circles]]


def find_candidates(x: np.ndarray, y: np.ndarray, *, width: int, height: int, cell_px: int = 4,
                    r_range: tuple[float, float] = (5.0, 100.0), min_events: int = 30,
                    max_candidates: int = 4) -> list[tuple[int, int, int, int]]:
    """Dense event clusters that could be a ball.

    Parameters
    ----------
    x, y : ndarray of int, shape (N,)
        Pixel coordinates of one slice's events (hot pixels already removed); events outside the
        ``width`` x ``height`` sensor are not counted.
    width, height : int
        Sensor size, px.
    cell_px : int
        Cell size of the density map, px.
    r_range : (float, float)
        Expected ball radius range, px (the cluster's extent must fit it).
    min_events : int
        Least events in a cluster.
    max_candidates : int
        Most clusters returned (densest first).

    Returns
    -------
    list of (x0, y0, x1, y1)
        Cluster bounding boxes in pixels (x1, y1 exclusive), densest first.
    """
    if len(x) < min_events:
        return []
    gw, gh = -(-width // cell_px), -(-height // cell_px)
    dens = cell_counts(np.asarray(x), np.asarray(y), cell_px, gw, gh)
    sm = cv2.blur(dens, (3, 3))
    lam = len(x) / (gw * gh)
    thr = lam + 4.0 * np.sqrt(lam) + 1.0
    mask = sm > thr
    if not mask.any():  # nothing dense
        return []
    n, labels = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    if n <= 1:
        return []
    sums, stats = cluster_stats(labels, dens, n)
    out = []
    for lab in np.argsort(-sums[1:]) + 1:
        if sums[lab] < min_events:
            break
        x0, y0, w, h = stats[lab, :4]
        ext_px = max(w, h) * cell_px
        if ext_px < 1.2 * r_range[0] or min(w, h) * cell_px > 2.0 * r_range[1] + 4 * cell_px + 2:
            continue
        out.append((int(x0 * cell_px), int(y0 * cell_px), int(min((x0 + w) * cell_px, width)),
                    int(min((y0 + h) * cell_px, height))))
        if len(out) >= max_candidates:
            break
    return out


MIN_VELOCITY_SPAN_S = 1e-4
"""Least time (s) between the mean times of a cluster's two halves for :func:`estimate_velocity` to measure a
velocity: 2,000 events within a microsecond, split in space, gave 10^10 px/s, and the motion-compensated
events then a density grid of gigabytes."""


def estimate_velocity(x: np.ndarray, y: np.ndarray, t_us: np.ndarray) -> tuple[float, float]:
    """Centroid velocity (px/s) from the first and second halves (in time) of a cluster's events."""
    if len(t_us) < 20:
        return 0.0, 0.0
    mid = len(t_us) // 2
    dt_s = (t_us[mid:].mean() - t_us[:mid].mean()) * 1e-6
    if dt_s < MIN_VELOCITY_SPAN_S:  # a burst: its halves' centroids tell no motion (and would give any speed)
        return 0.0, 0.0
    return float((x[mid:].mean() - x[:mid].mean()) / dt_s), float((y[mid:].mean() - y[:mid].mean()) / dt_s)
