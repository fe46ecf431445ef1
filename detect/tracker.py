"""Ball tracker: event-slice and frame detections fused by a Kalman filter.

Events are processed in time blocks (``block_us``, for the hot-pixel map) cut
into slices (``slice_us``, 1-2 ms) on a fixed time grid, so the result does not
depend on how the stream is batched. Where events are few (a small sensor, a dim
scene, a plain ball that fires only at its rim), slices are joined into a longer
window until it holds enough of them: ``search_events`` over the sensor while
searching, ``track_events`` around the prediction while tracking, at most
``max_window_us``; the thresholds thus follow the event rate. In each window:

* each ball being tracked (a flight) has its own Kalman filter and window:
  the prediction gives the search region, the velocity for motion compensation
  and the gate; a gated fit updates the filter, weighted by its centre sigma
  (larger where its rim points cover a shorter arc). A plain ball lit from one
  side is fitted on the directions where its rim shows (``detect.limb``), a ball
  that something touches (a racket's head, an arm) on the directions where nothing
  does (:func:`_touched`). The flight ends when the ball leaves the sensor, after
  ``max_misses`` slices without a fit (not counted for up to ``CLUTTER_COAST_US``
  while the ball is hidden in clutter), or when confident fits fall outside the gate
  twice in a row (hit or bounce: those fits start the next flight's detections);
* the search looks for balls not yet tracked: the density map of the window's
  events (those near a tracked ball left out) gives candidate clusters; each is
  motion-compensated with its own centroid velocity and fitted with a circle;
  each circle-like one (score >= ``min_score``, radius in ``r_range``) not on a
  stem (a racket's or a bat's head on its handle: :func:`_on_a_stem`) is a
  tentative detection, and ``confirm_slices`` consistent detections in a row
  start a new flight. With no flight it runs every slice; while balls are
  tracked, one slice in ``SEARCH_STRIDE_TRACKING`` (every slice while a
  detection waits for confirmation), so two balls in view at once are two
  flights, tracked side by side.

Frames (already on the event clock) are searched with Hough circles around each
prediction and fused as measurements with ``frame_sigma_px``. ``update()``
returns the causal (filtered) rows as they come; the track's final rows are
Rauch-Tung-Striebel smoothed (the best velocity for spin estimation) with a fixed
lag: each ``block_us`` of a flight once ``smooth_lag_us`` of later updates exist
(or the flight has ended), so that they can be used while tracking goes on
(``take_final()``) and never change afterwards. ``finish()`` returns them all. A flight found to be
no ball in its first updates (a racket's head whose handle shows, :data:`STEM_DROP_UPDATES`; one lost
young, :data:`LOST_YOUNG_UPDATES`) ends with no final rows.
"""

from __future__ import annotations

import bisect
import heapq
import itertools
import math

import numpy as np

from capture.events import EVENT_DTYPE, Track, concatenate
from detect import _kernels
from detect.event_detector import (CircleFit, circle_sigma_px, density_filter, estimate_velocity, find_candidates,
                                   fit_circle, hough_circles)
from detect.frame_detector import FrameDetector
from detect.flicker import FLICKER_SAMPLE_EVENTS, FLICKER_SAMPLE_US, FlickerFilter, find_flicker_hz, flicker_mask
from detect.hot_pixels import HotPixelMap
from detect.kalman import CircleKalman
from detect.limb import LimbModel

_MAX_FIT_EVENTS = 4000
"""Events per circle fit (an even subsample in time of the candidate's events)."""

_NO_MASK = np.zeros(0, bool)
"""An empty mask for the compiled selections: no hot-pixel map, or every event kept."""

_T_MIN = int(np.iinfo(np.int64).min)
"""The time before a stream's first event, µs."""

_HOT_EVERY = 4
"""The hot-pixel map is refreshed from one block in this many (hot pixels persist)."""

_SPARSE_FIT_EVENTS = 1000
"""Tracking windows with fewer events than this drop isolated events before the fit."""

_REJECT_SKIP = 3
"""Search windows in which a cluster like one just rejected (not circle-like) is not refitted; each
further rejection in a row doubles it, up to ``_REJECT_SKIP_MAX`` (a player walking in view)."""

_REJECT_SKIP_MAX = 12

_MAX_SURROUND_EVENTS = 20_000
"""Events (evenly thinned) that measure whether a ball is surrounded by others."""


MAX_SURROUNDED = 0.5
"""A ball found by telling it apart from what touches it has events around it on at most this share
of its sides (more: it is a round part of something bigger)."""

MAX_SURROUNDED_TRACKING = 0.75
"""A ball measured while tracking has events around it on at most this share of its sides (more: it
is lost in clutter, e.g. a flickering light, and the window is no measurement)."""

SPLIT_MIN_COVERAGE = 0.7
"""A ball told apart from what touches it, or found while another ball is tracked, shows its rim on
at least this share of its sides (the rounded end of an arm or a racket handle shows half of it, a
player's head a third: second balls on the detection benchmark show 0.8-0.97)."""

SPLIT_MIN_SPEED_R_S = 25.0
"""A flight found only by telling a ball apart from what touches it, or found while another ball is
tracked, must move at least this many radii per second (2.5 m/s for a ball of 10 cm radius, a
volleyball or a soccer ball): a round thing at rest against a body (a head on a player, a ball held
in a hand) is no flight."""


def _surrounded(x: np.ndarray, y: np.ndarray, fit: CircleFit, n_sectors: int = 12,
                max_events: int = _MAX_SURROUND_EVENTS) -> float:
    """Share of the directions around circle ``fit`` in which the ring just outside it
    (``1.15 r + 1`` to ``1.5 r + 2``) holds events at least 0.3 times as dense as the disk.

    Densities are ratios, so more than ``max_events`` events are thinned evenly first."""
    step = max(1, -(-len(x) // max_events))
    return _kernels.surrounded(np.asarray(x), np.asarray(y), fit.cx, fit.cy, fit.r, n_sectors, step)


STEM_SECTORS = 24
"""Directions round a circle in which :func:`_on_a_stem` looks for something thin reaching out, and
:func:`_touched` for something beside it."""


def _ring_densities(x: np.ndarray, y: np.ndarray, cx: float, cy: float, r: float,
                    max_events: int) -> tuple[np.ndarray, float, float]:
    """Event densities (events/px², from the events ``(x, y)``, more than ``max_events`` thinned
    evenly) round the circle ``(cx, cy, r)``: in the ring just outside it
    (:func:`detect._kernels.ring_counts`), per half (inner, outer) and direction (of
    :data:`STEM_SECTORS`), shape (2, STEM_SECTORS); in the disk; and in its outer band (``0.7 r`` to
    ``r``)."""
    step = max(1, -(-len(x) // max_events))
    counts, n_in, n_band = _kernels.ring_counts(np.asarray(x), np.asarray(y), cx, cy, r, STEM_SECTORS, step)
    r0, rm, r1 = _kernels.ring_radii(r)
    half_area = np.pi * np.array([[rm * rm - r0 * r0], [r1 * r1 - rm * rm]]) / STEM_SECTORS
    return counts / half_area, n_in / (np.pi * r * r), n_band / (np.pi * 0.51 * r * r)

STEM_MAX_SECTORS = 3
"""A stem is at most this many neighbouring directions wide (45 deg): a racket's handle is a fifth of its
head's width, a bat's two fifths; a ball's neighbours (an arm, a body, another ball) span more."""

STEM_MAX_RUNS = 2
"""A stem stands alone: a handle, or an arm's two edges leaving a hand; a ring holding more runs of
dense directions is patchy all round (a ball's own texture outside a circle fitted too small)."""

STEM_DENSITY = 0.2
"""A stem's events are at least this many times as dense as the disk's in the outer half of the ring
(by radius), and in the inner half too (a line reaching out from the rim, not a hot pixel or a blob
at one distance); its width is that of the outer half's run (the inner half also holds what is
beside the rim: an elliptical head's ends, an arm's nearest edge)."""


def _on_a_stem(x: np.ndarray, y: np.ndarray, fit: CircleFit, max_events: int = _MAX_SURROUND_EVENTS) -> bool:
    """Whether circle ``fit`` is a round thing on a stem: a racket's or a bat's head on its handle, a
    hand at the end of an arm. In the ring just outside it (:func:`detect._kernels.ring_counts`, with
    :data:`STEM_SECTORS` directions), some run of neighbouring directions at most
    :data:`STEM_MAX_SECTORS` wide holds events at least :data:`STEM_DENSITY` times as dense as the
    disk in the ring's outer half (and the directions on either side of it do not), and in its inner
    half too, with at most :data:`STEM_MAX_RUNS` such runs round it. A ball in flight has nothing
    attached: where flights started on the detection benchmark's arm, bounce, two-ball, still and
    volleyball rows, its ring held at most 0.1 of its disk's density in any direction."""
    ring, dens_in, _ = _ring_densities(x, y, fit.cx, fit.cy, fit.r, max_events)
    if dens_in == 0:
        return False
    inner, outer = ring >= STEM_DENSITY * dens_in
    if outer.all() or not outer.any():
        return False
    # from a sparse direction round to it again: each run of dense ones starts and ends in between
    shift = int(np.argmin(outer))
    inner = np.roll(inner, -shift)
    edges = np.flatnonzero(np.diff(np.append(np.roll(outer, -shift), False).astype(np.int8))) + 1
    if len(edges) > 2 * STEM_MAX_RUNS:  # patches all round: texture or clutter, not a handle
        return False
    return any(b - a <= STEM_MAX_SECTORS and inner[a:b].any() for a, b in zip(edges[::2], edges[1::2]))


STEM_DROP_UPDATES, STEM_DROP_WITHIN = 5, 12
"""A flight whose circle is on a stem (:func:`_on_a_stem`) in ``STEM_DROP_UPDATES`` tracking updates in a
row among its first ``STEM_DROP_WITHIN`` was a racket's or a bat's head whose handle was hidden (behind
the player, off the sensor) where it started: it ends, and its rows are dropped (those already
returned by ``update`` included: they never become final; the first final rows come 100 ms after an
update, and a flight with final rows is not checked again). A bat's face whose handle showed after it
started (``detect_bench`` row ``paddle``, seeds 6 and 22) was on one in every update from its 4th-5th
on; a ball beside an arm's end (a hand) or a racket's head in at most 3 in a row (rows ``arm-small``
and ``arm-large``, seeds 1-30; among its first 5 updates on seeds 24 and 26 of ``arm-small``)."""

LOST_YOUNG_UPDATES = 8
"""A flight lost (``max_misses`` windows without a fit, or two fits outside its gate) within this many
updates (its first detections included), none of its rows final, was no ball either: its rows are
dropped. Where a bat's face or a racket's head started a flight (its handle hidden), it was lost after
3-8 updates (``detect_bench`` rows ``paddle`` and ``racket``, seeds 1-16); of the balls' flights on
every row (seeds 1-16), one was: row ``still``, seed 9, a nearly still ball found only once, for 3
updates (its recall 4 % before, now none)."""


INTRUDED_DENSITY = 0.3
"""A direction round a tracked ball in which the ring just outside its predicted rim holds events at
least this many times as dense as the disk's outer band (``0.7 r`` to ``r``: a plain ball fires
there too, not inside), in both its inner and outer half (something reaching out from the rim, not
the ball itself a few pixels on after a bounce), is *touched* (a racket's head, an arm, another ball
beside it): the rim fit takes no boundary point there."""


TOUCHING_DENSITY, TOUCHING_MAX_SECTORS, TOUCHING_FILL = 0.1, 6, 0.8
"""Thin edges beside a ball that fires all over its disk (an arm's or a hand's two edges, a few lines of
events against a textured ball's dense disk: 0.13-0.28 of its outer band's density where a hand touched
a ball of r 10 px, ``detect_bench`` row ``arm-small``, seed 26) touch it too: in a ring that is otherwise
empty (at most ``TOUCHING_MAX_SECTORS`` directions hold events in both its halves, none as densely as
:data:`INTRUDED_DENSITY`: after a bounce the ball's own events lie there) round a ball whose disk is at
least ``TOUCHING_FILL`` times as dense as its band, a direction holding ``TOUCHING_DENSITY`` of the
band's density in both halves. (A plain ball, firing at its rim only, is left to :data:`INTRUDED_DENSITY`: the
128x128 sensor's trails and leak events beside one split its flights.)"""

TOUCHED_MAX = 2 / 3
"""A ball touched on more of its sides than this is hidden in clutter (the rest of its rim is too
short a fit: a third of it fits at a score of at most a third, about the least a fit needs)."""

CLUTTER_COAST_US = 40_000
"""A tracked ball hidden in clutter (touched on more than :data:`TOUCHED_MAX` of its sides) is not
counted missing for this long after its last update (µs): crossing in front of a racket's head
takes 10-20 ms on the benchmark, and a flight's circles are interpolated over gaps of up to 50 ms
(``detect.spin_windows``)."""


def _touched(xc: np.ndarray, yc: np.ndarray, cx: float, cy: float, r: float,
             max_events: int = _MAX_SURROUND_EVENTS) -> np.ndarray | None:
    """The directions (of :data:`STEM_SECTORS`) round the circle ``(cx, cy, r)`` in which something
    touches it (:data:`INTRUDED_DENSITY`, or thin edges beside a textured ball, :data:`TOUCHING_DENSITY`;
    each widened by a direction on either side), from the events ``(xc, yc)`` moved to the circle's
    time (more than ``max_events`` thinned evenly); None where nothing does."""
    ring, disk_density, band_density = _ring_densities(xc, yc, cx, cy, r, max_events)
    lowest = ring.min(axis=0)  # of the ring's two halves
    dense = lowest >= INTRUDED_DENSITY * band_density
    if (not dense.any() and disk_density >= TOUCHING_FILL * band_density
            and np.count_nonzero(lowest) <= TOUCHING_MAX_SECTORS):
        dense = lowest >= TOUCHING_DENSITY * band_density
    dense = dense | np.roll(dense, 1) | np.roll(dense, -1)
    return dense if dense.any() else None


def _in_clutter(fit: CircleFit, cx: float, cy: float, reach: float, x: np.ndarray, y: np.ndarray) -> bool:
    """Whether a tracking fit is no measurement: its rim reaches the edge of the selection within
    ``reach`` px of ``(cx, cy)``, or the events ``(x, y)`` (motion-compensated) lie all around it (a
    flickering light, a body behind the ball)."""
    return bool(fit.r + np.hypot(fit.cx - cx, fit.cy - cy) > reach - 0.5
                or _surrounded(x, y, fit) > MAX_SURROUNDED_TRACKING)


def _box_pixels(x0: float, x1: float, y0: float, y1: float, width: int, height: int) -> tuple[int, int, int, int]:
    """The whole pixels ``(lo_x, hi_x, lo_y, hi_y)`` of a ``width`` x ``height`` sensor with
    ``x0 < x < x1`` and ``y0 < y < y1`` (inclusive bounds; an empty box where a bound is NaN)."""
    if any(map(math.isnan, (x0, x1, y0, y1))):
        return 0, -1, 0, -1
    # bounds first held just outside the sensor (they may be infinite)
    return (math.floor(max(x0, -1.0)) + 1, math.ceil(min(x1, float(width))) - 1,
            math.floor(max(y0, -1.0)) + 1, math.ceil(min(y1, float(height))) - 1)


SEARCH_STRIDE_TRACKING = 4
"""While balls are tracked, a search window for another one starts this many slices after the last
(a player in view costs the search its fits in every window), or the next slice while a detection
waits for confirmation. A cluster that overlaps one rejected in the windows before is then taken
for the same (not only one that overlaps it by 30 %): parts of a player come and go."""

_MAX_CHAINS = 4
"""Chains of detections not yet confirmed as flights, at most."""

_END_PART_MIN_US = 200
_END_PART_MIN_EVENTS = 60
"""A tracking window's first and last parts (:meth:`BallTracker._track_ends`) last at least this long
(µs) and hold at least this many of the ball's events (at its recent rate)."""


def _velocity(a, b) -> tuple[float, float]:
    """Image velocity (px/s) from detection ``a`` to ``b``, each ``(t_us, CircleFit, ...)``."""
    dt_s = max((b[0] - a[0]) * 1e-6, 1e-9)
    return (b[1].cx - a[1].cx) / dt_s, (b[1].cy - a[1].cy) / dt_s


def _chain_start_us(chain) -> int:
    """Time (µs) of a chain's first event on the ball: its first row's, at the latest."""
    m, _, _, (ts, _, _), _ = chain[0]
    return min(m, int(ts[0])) if len(ts) else m


def _continues(chain, m: int, fit: CircleFit, width: int, height: int) -> bool:
    """Whether ``fit`` (a window centred at ``m`` µs) continues ``chain``, whose last detection is
    ``(t_us, fit, velocity px/s, ...)``: where that one's velocity predicts, same size.

    A chain of one detection of a ball coming in over the sensor's border (its circle crosses the
    border of a ``width`` x ``height`` sensor) is continued by a detection of the same size farther
    inside, within three radii: that detection's velocity came from the centroid of the ball's
    visible part, which moves at another speed than the ball."""
    tm, tf, tv = chain[-1][:3]
    # an older window continues nothing; one of the same time (a hit's seeds, then the search in the
    # same slice) continues a chain that already has a velocity
    if m < tm or (m == tm and len(chain) == 1) or abs(fit.r / tf.r - 1.0) > 0.25:
        return False
    dt_s = (m - tm) * 1e-6
    px, py = tf.cx + tv[0] * dt_s, tf.cy + tv[1] * dt_s
    if len(chain) == 1:
        # a first detection's velocity is its window's centroid's, wrong where the events are few
        # (a slow ball's shading drifts): the ball is anywhere from where it was to where that predicts
        sx, sy = px - tf.cx, py - tf.cy
        along = min(max(((fit.cx - tf.cx) * sx + (fit.cy - tf.cy) * sy) / max(sx * sx + sy * sy, 1e-12), 0.0), 1.0)
        px, py = tf.cx + along * sx, tf.cy + along * sy
    if np.hypot(fit.cx - px, fit.cy - py) <= 0.3 * tf.r + 3.0:
        return True
    depth, depth0 = _depth_px(fit, width, height), _depth_px(tf, width, height)
    return bool(len(chain) == 1 and depth0 < 0 and depth > depth0 + 1.0
                and np.hypot(fit.cx - tf.cx, fit.cy - tf.cy) <= 3.0 * tf.r)


def _depth_px(fit: CircleFit, width: int, height: int) -> float:
    """How far circle ``fit`` lies inside a ``width`` x ``height`` sensor, px (negative: it crosses the border)."""
    return min(fit.cx - fit.r, fit.cy - fit.r, width - 1 - fit.cx - fit.r, height - 1 - fit.cy - fit.r)


def _overlap(fit: CircleFit, circle: tuple[float, float, float]) -> bool:
    """Whether circle ``fit`` overlaps ``circle`` ``(cx, cy, r)`` (px)."""
    return bool(np.hypot(fit.cx - circle[0], fit.cy - circle[1]) < fit.r + circle[2])


def _same_ball(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two Kalman states (:mod:`detect.kalman`) at one time are the same ball: centres
    within half the smaller radius, radii within a quarter of the larger, and the same velocity to
    within a third of the faster (two balls crossing each other differ there) or 10 radii/s."""
    r = min(a[6], b[6])
    dv = np.hypot(a[2] - b[2], a[3] - b[3])
    return bool(np.hypot(a[0] - b[0], a[1] - b[1]) < 0.5 * r and abs(a[6] - b[6]) <= 0.25 * max(a[6], b[6])
                and dv <= max(np.hypot(a[2], a[3]), np.hypot(b[2], b[3])) / 3 + 10.0 * r)


def _by_time(track: Track) -> Track:
    """The rows of ``track`` sorted by time (rows of one time keep their order)."""
    if np.all(track.t_us[1:] >= track.t_us[:-1]):
        return track
    return track.select(np.argsort(track.t_us, kind="stable"))


def _inside(a: CircleFit, b: CircleFit) -> bool:
    """Whether circle ``a`` lies inside the larger circle ``b`` (to within a pixel)."""
    return a.r < b.r and np.hypot(a.cx - b.cx, a.cy - b.cy) + a.r <= b.r + 1.0


class DetectInputError(ValueError):
    """Events the tracker cannot take (out of time order, outside the sensor size given)."""


def _iou(a, b) -> float:
    """Intersection over union of two boxes ``(x0, y0, x1, y1)``."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


class _Window:
    """Slices joined into one detection window (the search's, or one flight's around its prediction)."""

    def __init__(self):
        self.pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.start_us: int | None = None  # start of the window being joined, µs (None: empty)
        self.n = 0

    def join(self, t, x, y, s0: int, s1: int, longest_us: int, need: int | None = None):
        """Add slice ``[s0, s1)``'s events; the whole window ``(t, x, y, start_us)`` once it holds
        ``need`` events or is ``longest_us`` long, else None (the slice is kept for the next)."""
        start = s0 if self.start_us is None else self.start_us
        self.pieces.append((t, x, y))
        self.n += len(t)
        if s1 - start < longest_us and (need is None or self.n < need):
            self.start_us = start
            return None
        pieces = self.pieces
        self.drop()
        if len(pieces) == 1:
            return (*pieces[0], start)
        return (np.concatenate([p[0] for p in pieces]), np.concatenate([p[1] for p in pieces]),
                np.concatenate([p[2] for p in pieces]), start)

    def drop(self) -> None:
        self.pieces, self.start_us, self.n = [], None, 0


class _Flight:
    """One ball being tracked: its filter and what the tracking windows learnt of it."""

    def __init__(self, number: int, kf: CircleKalman, ball_rate: float):
        self.number = number
        self.kf = kf
        self.ball_rate = ball_rate  # the ball's events per µs near the prediction (recent windows)
        self.window = _Window()
        self.scores: list[float] = []  # score of each update
        self.sigmas: list[float] = []  # circle sigma of each update, px (circle_sigma_px)
        self.misses = 0  # windows in a row without a gated fit
        self.outliers = 0  # fits in a row outside the gate
        self.outlier_fits: list = []  # those fits (a hit, a bounce?), as chain entries
        self.n_final = 0  # updates whose rows are final
        self.near = np.zeros(0, np.intp)  # indices of this slice's events around the ball (its surround too)
        self.circle = (math.nan, math.nan, 0.0)  # predicted (cx, cy, r) px this slice
        self.lead_us: int | None = None  # time of the row before the first update (a long first window)
        self.limb = LimbModel()  # the directions in which the ball shows a sharp rim
        self.checks = self.stems_in_a_row = 0  # updates checked for a stem, on one in a row


class BallTracker:
    """Streaming ball tracker over an event stream and optional frames.

    Parameters
    ----------
    width, height : int
        Sensor size, px.
    slice_us : int
        Detection slice length, µs.
    block_us : int
        Hot-pixel block length, µs (a multiple of ``slice_us``); also the
        latency of :meth:`update`.
    r_range : (float, float)
        Expected ball radius range, px.
    min_score : float
        Least circle score (0..1) of a detection.
    confirm_slices : int
        Consistent detections in a row that start a flight.
    max_misses : int
        Slices in a row without a detection that end a flight.
    model : {"ca", "cv"}
        Kalman motion model (see :mod:`detect.kalman`).
    gravity_px_s2 : (float, float)
        Image acceleration of gravity, px/s² (known for ``"cv"``, initial for ``"ca"``).
    q_px_s3 : float
        Kalman process-noise density.
    gate_chi2 : float
        Gate on the squared Mahalanobis distance of the centre.
    frame_sigma_px : float
        Standard deviation of a frame detection's centre, px.
    hot_pixels : bool
        Remove hot pixels (the map is refreshed from every 4th block: hot pixels persist).
    smooth : bool
        Whether the final rows are smoothed (RTS); else they are the filtered rows.
    smooth_lag_us : int
        Later updates, in µs, that smooth a row before it is final (at 100 ms the rows
        equal those of smoothing the whole flight to within 1e-4 px on simulated flights).
    search_events, track_events : int
        Least events of a search window (whole sensor, hot pixels removed) and of a tracking
        window (around the prediction); slices are joined until a window holds them.
    max_window_us : int
        Longest window, µs (a multiple of ``slice_us``).
    flicker_hz : float or "auto", optional
        A light flickering at this frequency (100 / 120 Hz: twice the mains) lights the scene:
        events of pixels that fired at the same phase one period earlier are left out of
        detection (:class:`detect.flicker.FlickerFilter`; the first period is not filtered).
        ``"auto"``: the frequency, if any, is found in the stream's first
        :data:`detect.flicker.FLICKER_SAMPLE_US` (or :data:`detect.flicker.FLICKER_SAMPLE_EVENTS`,
        :func:`detect.flicker.find_flicker_hz`; tracking starts once it is) and then kept in
        :attr:`flicker_hz`. None (default): no filtering.
    """

    def __init__(self, width: int, height: int, *, slice_us: int = 2000, block_us: int = 20000,
                 r_range=(5.0, 160.0), min_score: float = 0.3, confirm_slices: int = 3, max_misses: int = 3,
                 model: str = "ca", gravity_px_s2=(0.0, 0.0), q_px_s3: float = 3.0e4, gate_chi2: float = 25.0,
                 cell_px: int = 4, frame_sigma_px: float = 1.5, hot_pixels: bool = True, smooth: bool = True,
                 smooth_lag_us: int = 100_000, search_events: int = 600, track_events: int = 200,
                 max_window_us: int = 40_000, flicker_hz: float | None = None):
        if width <= 0 or height <= 0:
            raise ValueError(f"sensor size must be positive, got width={width}, height={height}")
        if slice_us <= 0 or block_us % slice_us:
            raise ValueError(f"block_us ({block_us}) must be a positive multiple of slice_us ({slice_us})")
        if max_window_us < slice_us or max_window_us % slice_us:
            raise ValueError(f"max_window_us ({max_window_us}) must be a positive multiple of slice_us ({slice_us})")
        if not 0 < r_range[0] < r_range[1]:
            raise ValueError(f"r_range must be (min, max) with 0 < min < max, got {r_range}")
        _kernels.load()  # here, not in the first fit (a live stream would wait for it)
        self.width, self.height = int(width), int(height)
        self.slice_us, self.block_us = int(slice_us), int(block_us)
        self.r_range = (float(r_range[0]), float(r_range[1]))
        self.min_score = float(min_score)
        self.confirm_slices = int(confirm_slices)
        self.max_misses = int(max_misses)
        self.kf_opts = dict(model=model, gravity_px_s2=tuple(gravity_px_s2), q_px_s3=q_px_s3)
        if model not in ("ca", "cv"):
            raise ValueError(f"model must be 'ca' or 'cv', got {model!r}")
        self.gate_chi2 = float(gate_chi2)
        if not 1 <= int(cell_px) <= max(width, height):
            raise ValueError(f"cell_px must be between 1 and the sensor's size ({max(width, height)} px), "
                             f"got {cell_px}")
        self.cell_px = int(cell_px)
        self.frame_sigma_px = float(frame_sigma_px)
        self.smooth = bool(smooth)
        self.smooth_lag_us = int(smooth_lag_us)
        self.search_events, self.track_events = int(search_events), int(track_events)
        self.max_window_us = int(max_window_us)
        self._search = _Window()  # search slices joined into a window
        self._search_stride = 1  # slices from the start of one search window to the next
        self._search_next_us = 0  # while balls are tracked, the next search window starts here
        self._hot = HotPixelMap(width, height) if hot_pixels else None
        self._hot_mask = _NO_MASK if self._hot is None else self._hot.hot  # (updated in place)
        self._probe: list[np.ndarray] | None = [] if flicker_hz == "auto" else None  # (non-empty) batches held meanwhile
        self.flicker_hz = None if flicker_hz in (None, "auto") else float(flicker_hz)
        """Frequency (Hz) of the flicker left out of detection; None: none (or not known yet)."""
        self._flicker = FlickerFilter(width, height, self.flicker_hz) if self.flicker_hz is not None else None
        self._frames = FrameDetector(self.r_range)
        self._frame_queue: list = []
        self._frame_seq = itertools.count()
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (t, x, y) of events to process
        self._block0: int | None = None
        self._last_t: int | None = None
        self._flights: list[_Flight] = []  # the balls being tracked, oldest first
        self._n_flights = 0
        # detections not yet confirmed as a flight, each a chain consistent in time:
        # [(window middle µs, fit, velocity px/s, (t, x, y) events, found by splitting a cluster)]
        self._chains: list[list[tuple[int, CircleFit, tuple[float, float], tuple, bool]]] = []
        # (box, windows skipped since its last fit, coarse, rejections in a row)
        self._rejected: list[tuple[tuple[int, int, int, int], int, bool, int]] = []
        self._final: list[Track] = []  # final rows, in chunks
        self._n_final_taken = 0
        self._t_processed: int | None = None
        self._new_rows: list[tuple] = []
        self.frames_skipped = 0
        """Frames that came after the events of their time had been processed."""

    # ------------------------------------------------------------------ public API
    def update(self, events: np.ndarray) -> Track:
        """Feed a time-sorted batch of events; returns the track rows completed by it (filtered).

        Raises
        ------
        DetectInputError
            Events out of time order, or outside the sensor size given.
        """
        events = np.asarray(events)
        if events.dtype != EVENT_DTYPE:
            raise TypeError(f"events must have EVENT_DTYPE, got {events.dtype}")
        t, x, y = self._check(events)
        if self._probe is not None:  # flicker_hz="auto": hold the events until the frequency is found
            if len(events):
                self._probe.append(events)
            held = self._probe
            if (not held or int(held[-1]["t"][-1]) - int(held[0]["t"][0]) < FLICKER_SAMPLE_US) \
                    and sum(map(len, held)) < FLICKER_SAMPLE_EVENTS:
                return self._take_rows()
            events = self._end_probe()
            t, x, y, *_ = _kernels.split_checked(events["t"], events["x"], events["y"], _T_MIN)
        if self._flicker is not None and len(t):
            keep = np.flatnonzero(~self._flicker.flags(t, x, y))
            t, x, y = t.take(keep), x.take(keep), y.take(keep)
        if len(t):
            if self._block0 is None:
                self._block0 = int(t[0]) // self.block_us * self.block_us
            self._pending.append((t, x, y))
            self._run(final=False)
        return self._take_rows()

    def _end_probe(self) -> np.ndarray:
        """Find the flicker frequency in the events held (``flicker_hz="auto"``); returns them."""
        events = concatenate(self._probe)
        self._probe = None
        self.flicker_hz = find_flicker_hz(events, self.width, self.height)
        if self.flicker_hz is not None:
            self._flicker = FlickerFilter(self.width, self.height, self.flicker_hz)
        return events

    def _check(self, events: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The events' columns ``(t, x, y)`` (int64 µs, int32 px), contiguous; refuses, with one line
        naming the first offence, events out of time order (within the batch or behind the previous
        one) and coordinates outside the sensor size."""
        t, x, y, back, x_max, y_max = _kernels.split_checked(
            events["t"], events["x"], events["y"], _T_MIN if self._last_t is None else self._last_t)
        if back == 0:
            raise DetectInputError(f"events out of time order: this batch starts at t={int(t[0])} µs, before the "
                                   f"previous batch's last event at {self._last_t} µs")
        if back > 0:
            raise DetectInputError(f"events out of time order: t goes back from {int(t[back - 1])} to "
                                   f"{int(t[back])} µs at index {back}; sort them by 't' first")
        if x_max >= self.width or y_max >= self.height:
            raise DetectInputError(f"events reach x={x_max}, y={y_max}, outside the {self.width}x{self.height} "
                                   "sensor size given")
        if len(t):
            self._last_t = int(t[-1])
        return t, x, y

    @property
    def last_t_us(self) -> int | None:
        """Time of the last event taken, µs (None before the first)."""
        return self._last_t

    def update_frame(self, image: np.ndarray, t_us: int) -> None:
        """Queue a frame (grey or BGR, the sensor's size: in the event camera's geometry) whose
        (mid-exposure) time on the event clock is ``t_us``."""
        shape = np.shape(image)
        if len(shape) not in (2, 3) or tuple(shape[:2]) != (self.height, self.width):
            raise DetectInputError(f"frame of shape {shape} is not the {self.width}x{self.height} sensor's size; map "
                                   "frames into the event camera's geometry first (calib.stereo.CameraPair)")
        heapq.heappush(self._frame_queue, (int(t_us), next(self._frame_seq), image))

    def finish(self) -> Track:
        """Process what is left and return the whole track (smoothed unless ``smooth=False``), its
        rows sorted by time (those of two balls in view at once interleave)."""
        if self._probe is not None:  # a stream shorter than the flicker sample
            self._last_t = None  # (its events were checked as they came)
            self.update(self._end_probe())
        self._run(final=True)
        self._frames_until(None)
        for fl in list(self._flights):
            self._end_flight(fl)
        self._take_rows()
        return _by_time(Track.concat(self._final))

    def take_final(self) -> Track:
        """Track rows that became final since the last call, sorted by time (see the module
        docstring; with two balls in view, a later call may return rows of one that are older than
        rows of the other returned before)."""
        out = Track.concat(self._final[self._n_final_taken:])
        self._n_final_taken = len(self._final)
        return _by_time(out)

    @property
    def active_flights(self) -> tuple[int, ...]:
        """Numbers of the flights being tracked (one per ball in view), oldest first."""
        return tuple(fl.number for fl in self._flights)

    @property
    def rows_final_before_us(self) -> int | None:
        """Time (µs) before which no further track rows will be emitted, ``None`` before any
        events were processed.

        Rows still to come lie at or after the start of each window being joined, the first
        tentative detection of each flight not yet confirmed (its rows are emitted when it is), the
        first fit outside a flight's gate since its last update (a hit: the next flight's first
        detection), and the middle of the last slice (a frame there may still be fused).
        """
        if self._t_processed is None:
            return None
        bound = self._t_processed - self.slice_us
        for w in (self._search, *(fl.window for fl in self._flights)):
            if w.start_us is not None:
                bound = min(bound, w.start_us)
        for chain in self._chains:
            bound = min(bound, _chain_start_us(chain))
        for fl in self._flights:  # fits outside the gate may become a new flight's first rows
            if fl.outlier_fits:
                bound = min(bound, _chain_start_us(fl.outlier_fits))
        return bound

    # ------------------------------------------------------------------ blocks and slices
    def _run(self, final: bool) -> None:
        """Process every complete block of the pending events (every block if ``final``)."""
        while self._pending:
            t0 = int(self._pending[0][0][0])
            b0 = self._block0 + (t0 - self._block0) // self.block_us * self.block_us
            b1 = b0 + self.block_us
            pieces, rest = [], []
            for k, (t, x, y) in enumerate(self._pending):
                j = int(np.searchsorted(t, b1, side="left"))
                pieces.append((t[:j], x[:j], y[:j]))
                if j < len(t):
                    rest = [(t[j:], x[j:], y[j:]), *self._pending[k + 1:]]
                    break
            else:
                if not final:
                    return  # the block goes on in events still to come
            self._pending = rest
            if len(pieces) == 1:  # a block within one batch: views, no copy
                t, x, y = pieces[0]
            else:
                t, x, y = (np.concatenate([p[i] for p in pieces]) for i in range(3))
            self._process_block(t, x, y, b0, end_us=int(t[-1]) + 1 if final and not rest and len(t) else None)
            self._t_processed = b1

    def _process_block(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, b0: int, end_us: int | None = None) -> None:
        """The slices of block ``[b0, b0 + block_us)`` (events ``t`` int64 µs, ``x, y`` int32 px); with
        ``end_us`` (the stream's end: its last event + 1 µs), its last slice ends there and the tracking
        windows being joined end with it (no window's row is stamped after the stream's last event;
        frames after it may still add rows)."""
        if self._hot is not None and (b0 - self._block0) // self.block_us % _HOT_EVERY == 0:
            self._hot.update(y * self.width + x)
        bounds = np.arange(b0, b0 + self.block_us + 1, self.slice_us)
        if end_us is not None:
            bounds = np.append(bounds[bounds < end_us], end_us)
        idx = np.searchsorted(t, bounds, side="left")
        for k in range(len(bounds) - 1):
            s0, s1 = int(bounds[k]), int(bounds[k + 1])
            self._frames_until((s0 + s1) // 2)
            i0, i1 = idx[k], idx[k + 1]
            self._process_slice(t[i0:i1], x[i0:i1], y[i0:i1], s0, s1, last=end_us is not None and s1 == end_us)

    def _process_slice(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, s0: int, s1: int,
                       last: bool = False) -> None:
        """One slice ``[s0, s1)``'s events (hot pixels not yet removed: tracking removes them from
        the few events near each ball only)."""
        for fl in list(self._flights):
            self._track_slice(fl, t, x, y, s0, s1, last)
        self._end_duplicates()
        if self._flights:
            # while balls are tracked, another is searched for among the events away from them, in
            # one slice of SEARCH_STRIDE_TRACKING while nothing waits for confirmation
            if self._search.start_us is None and s0 < self._search_next_us:
                return
            keep = np.ones(len(t), bool)
            for fl in self._flights:
                keep[fl.near] = False
        else:
            keep = _NO_MASK
        if self._flights or self._hot is not None:
            t, x, y = _kernels.kept_events(t, x, y, keep, self._hot_mask, self.width)
        self._search_slice(t, x, y, s0, s1)

    def _fit(self, t, x, y, m, center0, velocity, r_range, limb: LimbModel | None = None,
             touched: tuple | None = None) -> CircleFit | None:
        """Circle fit on events ``(t, x, y)`` moved to time ``m`` along ``velocity`` (px/s).

        Without ``center0`` (search), isolated events are dropped first and the
        centroid is the start; with it (tracking), the window around the
        prediction is small enough that noise hardly reaches it and the fit's
        k-th-outermost rule absorbs the few strays - unless the window is sparse
        (fewer than ``_SPARSE_FIT_EVENTS``: a dim ball, noise a large share), where
        isolated events are dropped too. With a flight's ``limb``, the fit is refined on the
        directions where the ball shows a sharp rim, and a fit of at least ``min_score`` adds to it.
        ``touched``, ``(cx, cy, r, directions)`` (:func:`_touched`): in those directions round that
        circle, events beyond ``0.8 r`` are no boundary points (they may be what touches the ball).
        """
        # even subsample in time; a search keeps more, for the density filter to see a big ball's
        # sparse disk as dense (fit_circle then takes _MAX_FIT_EVENTS of what is left)
        keep = _MAX_FIT_EVENTS if center0 is not None else 4 * _MAX_FIT_EVENTS
        if len(t) > keep:
            sub = np.linspace(0, len(t) - 1, keep).astype(np.int64)
            t, x, y = t[sub], x[sub], y[sub]
        dt_s = (t - m) * 1e-6
        xc = x - velocity[0] * dt_s
        yc = y - velocity[1] * dt_s
        border = (x == 0) | (y == 0) | (x == self.width - 1) | (y == self.height - 1)
        if touched is not None:
            tcx, tcy, tr, directions = touched
            dx, dy = xc - tcx, yc - tcy
            sector = ((np.arctan2(dy, dx) + np.pi) * (len(directions) / (2 * np.pi))).astype(np.int64) % len(directions)
            border = border | (directions[sector] & (dx * dx + dy * dy > (0.8 * tr) ** 2))
        if center0 is None or len(xc) < _SPARSE_FIT_EVENTS:
            good = density_filter(xc, yc, min_neighbours=1)
            if not good.any():
                return None
            xc, yc, border = xc[good], yc[good], border[good]
        if center0 is None:
            center0 = (float(xc.mean()), float(yc.mean()))
        fit = fit_circle(xc, yc, center0=center0, r_range=r_range, ignore=border)
        if limb is not None and fit is not None:
            fit = limb.refine(xc, yc, fit, r_range)
            if fit.score >= self.min_score:
                limb.observe(xc, yc, fit)
        return fit

    def _candidates(self, x, y) -> list[tuple[tuple[int, int, int, int], bool]]:
        """Candidate boxes of a search window, each with whether it comes from the coarse map: from
        the fine density map, and for big balls (whose events spread thin over a large disk) also
        from a map of 4x coarser cells."""
        boxes = find_candidates(x, y, width=self.width, height=self.height, cell_px=self.cell_px,
                                r_range=self.r_range)
        out = [(b, False) for b in boxes]
        coarse = 4 * self.cell_px
        if self.r_range[1] >= 6 * coarse:
            big = find_candidates(x, y, width=self.width, height=self.height, cell_px=coarse,
                                  r_range=(max(self.r_range[0], 1.5 * coarse), self.r_range[1]), max_candidates=2)
            out += [(b, True) for b in big if all(_iou(b, a) < 0.5 for a in boxes)]
        return out

    def _fit_split(self, t, x, y, m, velocity):
        """The ball in a cluster whose rim fit failed because something touches it (an arm, a
        racket, a second ball): round blobs of the cluster's event image (:func:`hough_circles`),
        each refitted on its own events with its own velocity; the best ``(fit, velocity,
        events)``, or ``(None, velocity, events)``."""
        dt_s = (t - m) * 1e-6
        xc, yc = x - velocity[0] * dt_s, y - velocity[1] * dt_s
        best = (None, velocity, (t, x, y))
        found = []
        for cx, cy, r in hough_circles(xc, yc, r_range=self.r_range):
            reach = 1.1 * r + 1.5  # Hough's radius is the blurred disk's: already a little large
            sel = np.flatnonzero((xc - cx) ** 2 + (yc - cy) ** 2 < reach * reach)
            if len(sel) < 40:
                continue
            ts, xs, ys = t.take(sel), x.take(sel), y.take(sel)
            v = estimate_velocity(xs.astype(np.float64), ys.astype(np.float64), ts)
            fit = self._fit(ts, xs, ys, m, (cx, cy), v, (max(self.r_range[0], 0.7 * r), min(self.r_range[1], 1.4 * r)))
            if (fit is not None and fit.score >= self.min_score and fit.coverage >= SPLIT_MIN_COVERAGE
                    and _surrounded(xc, yc, fit) <= MAX_SURROUNDED):
                found.append((fit, v, (ts, xs, ys)))
        # a circle inside another (a seam, the bright half of the ball) is not the ball
        found = [f for f in found if not any(_inside(f[0], g[0]) for g in found if g is not f)]
        return max(found, key=lambda f: f[0].score, default=best)

    def _track_slice(self, fl: _Flight, t, x, y, s0: int, s1: int, last: bool = False) -> None:
        kf = fl.kf
        start = s0 if fl.window.start_us is None else fl.window.start_us
        m = max((start + s1) // 2, kf.t_us)  # a frame may have updated the filter inside the window
        state, cov = kf.predict(m)
        cx, cy, vx, vy, r = state[0], state[1], state[2], state[3], state[6]
        if cx < -r or cy < -r or cx > self.width + r or cy > self.height + r:
            self._end_flight(fl)
            return
        sig = float(np.sqrt(cov[0, 0] + cov[1, 1]))
        reach = r + max(3.0, 0.15 * r) + 3.0 * sig  # the rim cannot be farther out
        # a box around the swept circle first (cheap on all events), then the moving circle
        around = max(reach, _kernels.ring_radii(r)[2])  # the ring around the ball too: is it in clutter?
        hx = around + abs(vx) * (s1 - start) * 0.5e-6
        hy = around + abs(vy) * (s1 - start) * 0.5e-6
        fl.near, tb, xb, yb = _kernels.box_select(t, x, y, *_box_pixels(cx - hx, cx + hx, cy - hy, cy + hy, self.width,
                                                                        self.height), self._hot_mask, self.width)
        fl.circle = (cx, cy, r)
        # the window lasts as long as the ball needs to fire track_events at its recent rate, so
        # that a ball lost from the prediction is missed after that time, not after max_window_us
        span = self.track_events / max(fl.ball_rate, 1e-9)
        slice_events = (t, x, y)
        win = fl.window.join(tb, xb, yb, s0, s1, 0 if last else min(int(span), self.max_window_us))
        if win is None:
            return
        t, x, y, start = win
        xc, yc, ts, xs, ys = _kernels.moved_near(t, x, y, m, vx, vy, cx, cy, reach)
        r_rng = (max(self.r_range[0], 0.6 * r), min(self.r_range[1], 1.6 * r))
        touched = _touched(xc, yc, cx, cy, r)
        hidden = touched is not None and touched.mean() > TOUCHED_MAX  # in clutter: no fit can tell
        fit = self._fit(ts, xs, ys, m, (cx, cy), (vx, vy), r_rng, fl.limb,
                        None if touched is None or hidden else (cx, cy, r, touched)) if len(ts) >= 12 else None
        if fit is not None and _in_clutter(fit, cx, cy, reach, xc, yc):
            fit = None
        if fit is None or fit.score < self.min_score:
            if not self._track_ends(fl, (t, x, y, start), slice_events, s1, around, r_rng):
                # a ball hidden in clutter (passing in front of a racket's strings or a body) is not
                # lost: the flight goes on along its prediction for up to CLUTTER_COAST_US
                if not (hidden and m - fl.kf.t_us <= CLUTTER_COAST_US):
                    fl.misses += 1
                if fl.misses >= self.max_misses:
                    self._end_flight(fl, drop=self._lost_young(fl))
            return
        if self._judge(fl, m, fit, (ts, xs, ys)):
            fl.ball_rate = 0.5 * fl.ball_rate + 0.5 * len(ts) / max(s1 - start, 1)
            if fl.checks < STEM_DROP_WITHIN and not fl.n_final:
                # a racket's or a bat's head whose handle was hidden when its flight started
                dt_s = (t - m) * 1e-6
                fl.checks += 1
                fl.stems_in_a_row = fl.stems_in_a_row + 1 if _on_a_stem(x - vx * dt_s, y - vy * dt_s, fit) else 0
                if fl.stems_in_a_row >= STEM_DROP_UPDATES:
                    self._end_flight(fl, drop=True)

    def _judge(self, fl: _Flight, m: int, fit: CircleFit, events) -> bool:
        """Update flight ``fl`` with ``fit`` (a window centred at ``m`` µs, its ``events`` ``(t, x, y)``)
        where the fit lies in the gate around the prediction, and say so; else count it as an
        outlier (two in a row: a hit or a bounce, the flight ends and its outliers seed the next)."""
        if self._in_gate(fl.kf, m, fit.cx, fit.cy, fit.sigma_px, fit.r):
            self._update(fl, m, fit)
            return True
        fl.outliers += 1
        fl.misses += 1
        ts, xs, ys = events
        # the velocity since the outlier before (a ball bounced off a wall), else the events' own
        prev = fl.outlier_fits[-1] if fl.outlier_fits else None
        v_own = (_velocity(prev, (m, fit)) if prev is not None and prev[0] < m
                 else estimate_velocity(xs.astype(np.float64), ys.astype(np.float64), ts))
        fl.outlier_fits.append((m, fit, v_own, (ts, xs, ys), False))
        if fl.outliers >= 2 or fl.misses >= self.max_misses:
            # hit or bounce: the outlying fits are the next flight's first detections
            seeds = fl.outlier_fits[-fl.outliers:] if fl.outliers >= 2 else []
            self._end_flight(fl, drop=self._lost_young(fl))
            if seeds:  # (the oldest chain makes room)
                self._chains = [*self._chains[-(_MAX_CHAINS - 1):], seeds]
        return False

    @staticmethod
    def _lost_young(fl: _Flight) -> bool:
        """Whether flight ``fl``, lost now, is no ball: :data:`LOST_YOUNG_UPDATES`."""
        return not fl.n_final and len(fl.scores) <= LOST_YOUNG_UPDATES

    def _update(self, fl: _Flight, m: int, fit: CircleFit) -> None:
        """Update flight ``fl`` with a gated ``fit`` (a window centred at ``m`` µs) and emit its row."""
        fl.kf.update(m, (fit.cx, fit.cy, fit.r), fit.sigma_px, 1.5 * fit.sigma_px)
        fl.scores.append(fit.score)
        fl.sigmas.append(circle_sigma_px(fit))
        self._emit(fl, m)
        fl.misses = fl.outliers = 0
        fl.outlier_fits = []

    def _in_gate(self, kf: CircleKalman, t_us: int, cx: float, cy: float, sigma_px: float,
                 r: float | None = None) -> bool:
        """Whether a circle centred at ``(cx, cy)`` px (at ``t_us``, centre sigma ``sigma_px``) lies in
        the gate around the prediction of ``kf`` (Mahalanobis, or within a tenth of the radius) and,
        given its radius ``r``, has about the predicted size."""
        d2, pred = kf.innovation(t_us, (cx, cy), sigma_px)
        px, py, pr = pred[0], pred[1], pred[6]
        return bool((d2 <= self.gate_chi2 or np.hypot(cx - px, cy - py) <= 0.1 * pr + 1.0)
                    and (r is None or abs(r - pr) <= 0.25 * pr + 2.0))

    def _track_ends(self, fl: _Flight, window, slice_events, s1: int, around: float, r_rng) -> bool:
        """Measure the ball on the first and the last part of a tracking window whose fit failed, each
        so short that the ball moves about a pixel in it (at least ``_END_PART_MIN_US``: a few pixels
        at 20,000 px/s); whether the flight took a measurement.

        A bounce or a hit inside the window changes the velocity: compensated with the predicted one,
        the ball's events smear and the window's fit fails (or looks like clutter).  The first part
        (of ``window``, ``(t, x, y, start_us)``) still follows the prediction: fitted with the
        predicted velocity within ``around`` px of it, it updates the flight if it lies in the gate.
        The last part shows where the ball is now: it is sought uncompensated among the slice's
        events (``slice_events``, ``(t, x, y)``) as far from the prediction as a bounce inside the
        window could take it (or from the last outlier, as far as since then), with the flight's
        size and its rim on most sides; it updates the flight or counts as an outlier, so that two
        windows after a bounce start the next flight from their last parts.  A part is not fitted
        where another tracked ball (with its surround) comes within its reach (two balls crossing:
        the other is what failed the fit, and would be taken for this one)."""
        t, x, y, start = window
        cx, cy, vx, vy, _, _, r = fl.kf.predict(max(start, fl.kf.t_us))[0]
        speed = float(np.hypot(vx, vy))
        others = [o.kf.predict(max(start, o.kf.t_us))[0] for o in self._flights if o is not fl]

        def crowded(px, py, reach):  # another ball within ``reach`` (px, each axis) of (px, py) this window
            return any(max(abs(px - o[0]), abs(py - o[1])) < reach + 1.5 * o[6] + 2.0
                       + np.hypot(vx - o[2], vy - o[3]) * (s1 - start) * 1e-6 for o in others)

        if crowded(cx, cy, around):
            return False
        part_us = int(np.clip(1e6 / max(speed, 1.0), _END_PART_MIN_US, (s1 - start) // 3))
        if part_us < _END_PART_MIN_US or fl.ball_rate * part_us < _END_PART_MIN_EVENTS:
            return False
        # the first part: the ball as predicted, before any change of motion
        took = False
        i0, i1 = np.searchsorted(t, (start, start + part_us))
        tm = max(start + part_us // 2, fl.kf.t_us)
        pred = fl.kf.predict(tm)[0]
        ts, xs, ys = t[i0:i1], x[i0:i1], y[i0:i1]
        dt_s = (ts - tm) * 1e-6
        dx = xs - pred[2] * dt_s - pred[0]
        dy = ys - pred[3] * dt_s - pred[1]
        sel = dx * dx + dy * dy < around * around
        if sel.sum() >= _END_PART_MIN_EVENTS:
            fit = self._fit(ts[sel], xs[sel], ys[sel], tm, (pred[0], pred[1]), (pred[2], pred[3]), r_rng)
            if (fit is not None and fit.score >= self.min_score
                    and not _in_clutter(fit, pred[0], pred[1], around, dx + pred[0], dy + pred[1])
                    and self._in_gate(fl.kf, tm, fit.cx, fit.cy, fit.sigma_px, fit.r)):
                self._update(fl, tm, fit)
                took = True
        # the last part: where the ball is now, however its motion changed
        tm = max(s1 - part_us // 2, fl.kf.t_us)
        pred = fl.kf.predict(tm)[0]
        last = fl.outlier_fits[-1] if fl.outlier_fits else None
        if last is None:  # a bounce inside this window: at most twice the speed since its start
            ox, oy, half = pred[0], pred[1], around + 2.0 * speed * (s1 - start) * 1e-6
        else:  # since the last outlier, at about the speed before
            ox, oy, half = last[1].cx, last[1].cy, around + 1.5 * speed * (tm - last[0]) * 1e-6
        if crowded(ox, oy, half):
            return took
        t, x, y = slice_events
        i0, i1 = np.searchsorted(t, (s1 - part_us, s1))
        ts, xs, ys = t[i0:i1], x[i0:i1], y[i0:i1]
        _, ts, xs, ys = _kernels.box_select(ts, xs, ys, *_box_pixels(ox - half, ox + half, oy - half, oy + half,
                                                                     self.width, self.height), self._hot_mask, self.width)
        if len(ts) < _END_PART_MIN_EVENTS:
            return took
        fit = self._fit(ts, xs, ys, tm, None, (0.0, 0.0), (max(r_rng[0], 0.8 * r), min(r_rng[1], 1.25 * r)))
        if (fit is None or fit.score < self.min_score or fit.coverage < SPLIT_MIN_COVERAGE
                or max(abs(fit.cx - ox), abs(fit.cy - oy)) + fit.r > half - 0.5
                or _surrounded(xs, ys, fit) > MAX_SURROUNDED_TRACKING):
            return took
        self._judge(fl, tm, fit, (ts, xs, ys))
        return True

    def _end_duplicates(self) -> None:
        """End the younger of two flights that have come to follow the same ball (after two balls
        passed close by each other, say): :func:`_same_ball` at the later of their last updates."""
        for a, b in itertools.combinations(list(self._flights), 2):
            if a in self._flights and b in self._flights:
                t = max(a.kf.t_us, b.kf.t_us)
                if _same_ball(a.kf.predict(t)[0], b.kf.predict(t)[0]):
                    self._end_flight(b)

    def _search_slice(self, t, x, y, s0: int, s1: int) -> None:
        win = self._search.join(t, x, y, s0, s1, self.max_window_us, need=self.search_events)
        if win is None:
            return
        t, x, y, start = win
        m = (start + s1) // 2
        span = max(s1 - start, self._search_stride * self.slice_us)  # from the last search window, at most
        found = []
        margin = 2 * self.cell_px
        rejected = []
        same_iou = 0.0 if self._flights else 0.3  # (SEARCH_STRIDE_TRACKING)
        # windows come SEARCH_STRIDE_TRACKING times rarer while tracking: skips as long in time
        skip_max = _REJECT_SKIP_MAX // SEARCH_STRIDE_TRACKING if self._flights else _REJECT_SKIP_MAX
        for box, coarse in self._candidates(x, y):
            # a cluster that was no ball in the last windows (a player...) is refitted only every few
            # windows, fewer the more often it was rejected: the search then stays cheap while such a
            # cluster is in view
            prev = max(((k, n) for b, k, c, n in self._rejected if c == coarse and _iou(b, box) > same_iou),
                       key=lambda e: (e[1], e[0]), default=None)
            edge = 2 * self.cell_px  # a ball coming in over the border is fitted every slice
            at_border = (box[0] <= edge or box[1] <= edge or box[2] >= self.width - edge
                         or box[3] >= self.height - edge)
            if prev is not None and prev[0] < min(_REJECT_SKIP << (prev[1] - 1), skip_max) and not at_border:
                rejected.append((box, prev[0] + 1, coarse, prev[1]))
                continue
            strikes = 1 if prev is None else prev[1] + 1
            x0, y0, x1, y1 = box
            _, ts, xs, ys = _kernels.box_select(t, x, y, *_box_pixels(x0 - margin - 0.5, x1 + margin - 0.5, y0 - margin - 0.5,
                                                                      y1 + margin - 0.5, self.width, self.height),
                                                _NO_MASK, self.width)
            v0 = estimate_velocity(xs.astype(np.float64), ys.astype(np.float64), ts)
            fit = self._fit(ts, xs, ys, m, None, v0, self.r_range)
            if (fit is None or fit.score < self.min_score) and s1 - start > self.slice_us and any(v0):
                # a long window (few events per second): a slow ball whose events' drift gave a
                # wrong velocity is a circle where they are not moved at all
                still = self._fit(ts, xs, ys, m, None, (0.0, 0.0), self.r_range)
                if still is not None and still.score >= self.min_score:
                    fit, v0 = still, (0.0, 0.0)
            # a cluster of the fine map that is no circle may be a ball touching something
            split = not coarse and (fit is None or fit.score < self.min_score)
            if split:
                fit, v0, (ts, xs, ys) = self._fit_split(ts, xs, ys, m, v0)
            if fit is None or fit.score < self.min_score:
                rejected.append((box, 0, coarse, strikes))
                continue
            # a round thing on a handle (a racket's or a bat's head) is no ball: its ring, from all the
            # window's events there (the handle may be a cluster of its own)
            reach = 1.5 * fit.r + 3.0 + 0.5e-6 * (s1 - start) * float(np.hypot(*v0))
            _, tr, xr, yr = _kernels.box_select(t, x, y, *_box_pixels(fit.cx - reach, fit.cx + reach, fit.cy - reach,
                                                                      fit.cy + reach, self.width, self.height),
                                                _NO_MASK, self.width)
            dt_s = (tr - m) * 1e-6
            if _on_a_stem(xr - v0[0] * dt_s, yr - v0[1] * dt_s, fit):
                rejected.append((box, 0, coarse, strikes))
                continue
            # a flight starts only on a ball (nearly) fully on the sensor: a partly visible one has a
            # moving centroid, so its velocity and compensation would be wrong; and not on a ball
            # already tracked (the edge of its surround); while one is, another shows its rim all
            # round (a player's head fits a circle on a third of its sides)
            inner = 0.8 * fit.r
            if (fit.cx - inner >= 0 and fit.cy - inner >= 0 and fit.cx + inner <= self.width - 1
                    and fit.cy + inner <= self.height - 1
                    and not any(_overlap(fit, fl.circle) for fl in self._flights)
                    and (not self._flights or fit.coverage >= SPLIT_MIN_COVERAGE)):
                found.append((fit, v0, (ts, xs, ys), split, (box, coarse)))
        self._rejected = rejected
        self._extend_chains(found, m, span)
        self._search_stride = 1 if self._chains or not self._flights else SEARCH_STRIDE_TRACKING
        self._search_next_us = s1 + (self._search_stride - 1) * self.slice_us

    def _extend_chains(self, found: list, m: int, span: int) -> None:
        """Add a search window's detections (``found``: ``(fit, velocity, events, split, (box,
        coarse))``, window middle ``m`` µs, ``span`` µs between windows) to the chains they continue,
        or start chains with them; start a flight from each chain ``confirm_slices`` long."""
        # one detection per ball: of two overlapping ones (two clusters of the same ball), the best
        kept = []
        for f in sorted(found, key=lambda f: -f[0].score):
            if not any(_overlap(f[0], (g[0].cx, g[0].cy, g[0].r)) for g in kept):
                kept.append(f)
        self._chains = [c for c in self._chains if m - c[-1][0] <= 2 * span]  # stale chains end
        extended = []
        for fit, v0, evs, split, key in kept:
            chain = min((c for c in self._chains if all(c is not e for e in extended)
                                                    and _continues(c, m, fit, self.width, self.height)),
                        key=lambda c: np.hypot(fit.cx - c[-1][1].cx, fit.cy - c[-1][1].cy), default=None)
            if chain is None:
                if len(self._chains) >= _MAX_CHAINS:
                    continue
                chain = []
                self._chains.append(chain)
            else:
                v0 = _velocity(chain[0], (m, fit))
            chain.append((m, fit, v0, evs, split))
            extended.append(chain)
            if len(chain) >= self.confirm_slices:
                self._chains.remove(chain)
                if (self._flights or all(entry[4] for entry in chain)) and self._slow(chain):
                    # a round part of something bigger moving with it (a head on a body), not a ball;
                    # and while a ball is in play, another one is found only in flight
                    self._rejected.append((key[0], 0, key[1], 1))
                    continue
                self._start_flight(chain)

    def _slow(self, chain) -> bool:
        """Whether a chain's detections moved less than ``SPLIT_MIN_SPEED_R_S`` radii/s."""
        return bool(np.hypot(*_velocity(chain[0], chain[-1])) < SPLIT_MIN_SPEED_R_S * chain[-1][1].r)

    def _start_flight(self, chain) -> None:
        # refit the chain's detections with the velocity of their displacement (better motion
        # compensation than each window's own centroid velocity)
        v = _velocity(chain[0], chain[-1])
        fits = []
        for tm, f, _, (ts, xs, ys), _ in chain:
            refit = self._fit(ts, xs, ys, tm, (f.cx, f.cy), v, self.r_range)
            fits.append((tm, refit if refit is not None and refit.score >= self.min_score else f))
        (t0, f0), *rest = fits
        rate = float(np.median([len(ts) / max(int(ts[-1]) - int(ts[0]), self.slice_us)
                                for _, _, _, (ts, _, _), _ in chain]))
        kf = CircleKalman(t0, (f0.cx, f0.cy, f0.r), velocity_px_s=v,
                          velocity_sigma_px_s=0.2 * np.hypot(*v) + 50.0 * f0.r, sigma_px=f0.sigma_px,
                          **self.kf_opts)
        fl = _Flight(self._n_flights, kf, rate)
        self._n_flights += 1
        self._flights.append(fl)
        fl.circle = (f0.cx, f0.cy, f0.r)
        fl.scores = [f0.score]
        fl.sigmas = [circle_sigma_px(f0)]
        lead_us = _chain_start_us(chain)
        if t0 - lead_us > self.slice_us:
            # a first window longer than a slice (few events per second): the ball was seen from
            # its first events on, half a window before the first update's time
            fl.lead_us = lead_us
            self._new_rows.append(self._row(fl, lead_us, kf.predict(lead_us)[0]))
        self._emit(fl, t0)
        for tm, f in rest:
            kf.update(tm, (f.cx, f.cy, f.r), f.sigma_px, 1.5 * f.sigma_px)
            fl.scores.append(f.score)
            fl.sigmas.append(circle_sigma_px(f))
            self._emit(fl, tm)
        # other chains on this ball (its surround, seen in a window before the flight existed) end
        last = chain[-1][1]
        self._chains = [c for c in self._chains if not _overlap(c[-1][1], (last.cx, last.cy, last.r))]

    def _end_flight(self, fl: _Flight, drop: bool = False) -> None:
        """End flight ``fl``: its rows become final, or with ``drop`` (no ball after all) none of
        those not final yet do."""
        if not drop:
            self._finalise(fl, ended=True)
        self._flights.remove(fl)
        # the search window being joined left this ball's events out: start a new one
        self._search.drop()
        self._search_stride, self._search_next_us = 1, 0

    # ------------------------------------------------------------------ frames
    def _frames_until(self, t_us: int | None) -> None:
        while self._frame_queue and (t_us is None or self._frame_queue[0][0] < t_us):
            tf, _, image = heapq.heappop(self._frame_queue)
            self._process_frame(image, tf)

    def _process_frame(self, image: np.ndarray, t_us: int) -> None:
        """Fuse a frame's circles near each tracked ball (a frame older than a flight's last update
        is skipped for it); every frame updates the frame detector's background model once."""
        live = [fl for fl in self._flights if t_us >= fl.kf.t_us]
        self.frames_skipped += bool(self._flights) and not live
        if not live:
            self._frames.detect(image, search=False)  # keeps the background model current
            return
        for k, fl in enumerate(live):
            kf = fl.kf
            state, cov = kf.predict(t_us)
            cx, cy, r = state[0], state[1], state[6]
            half = 1.5 * r + 8.0 + 3.0 * float(np.sqrt(cov[0, 0] + cov[1, 1]))
            circles = self._frames.detect(image, roi=(cx, cy, half), r_range=(0.7 * r, 1.3 * r + 1.0),
                                          learn=k == 0)
            if not circles:
                continue
            c = min(circles, key=lambda c: np.hypot(c.cx - cx, c.cy - cy))
            if self._in_gate(kf, t_us, c.cx, c.cy, self.frame_sigma_px):
                kf.update(t_us, (c.cx, c.cy, c.r), self.frame_sigma_px, 1.5 * self.frame_sigma_px)
                fl.scores.append(c.score)
                fl.sigmas.append(self.frame_sigma_px)
                self._emit(fl, t_us)

    # ------------------------------------------------------------------ rows
    def _emit(self, fl: _Flight, t_us: int) -> None:
        self._new_rows.append(self._row(fl, t_us, fl.kf.x))
        self._finalise(fl, ended=False)

    @staticmethod
    def _row(fl: _Flight, t_us: int, s: np.ndarray) -> tuple:
        """A track row of flight ``fl`` at ``t_us`` from filter state ``s``, with its last score and sigma."""
        return t_us, s[0], s[1], s[6], s[2], s[3], fl.scores[-1], fl.number, fl.sigmas[-1]

    def _take_rows(self) -> Track:
        rows, self._new_rows = self._new_rows, []
        if not rows:
            return Track.empty()
        cols = list(zip(*rows))
        return _by_time(Track(t_us=cols[0], cx=cols[1], cy=cols[2], r=cols[3], vx=cols[4], vy=cols[5],
                              score=cols[6], flight=cols[7], sigma_px=cols[8]))

    def _finalise(self, fl: _Flight, ended: bool) -> None:
        """Make rows of flight ``fl`` final: all once it has ended (or unsmoothed); else each
        ``block_us`` from its first update once an update ``smooth_lag_us`` after the block's end
        exists, smoothed with the updates before that time (so the result does not depend on
        when this runs)."""
        kf = fl.kf
        hist = kf.history
        n = len(hist)
        t_first = hist[0][0]
        while fl.n_final < n:
            start = fl.n_final
            if ended or not self.smooth:
                stop = final = n
            else:
                b_end = t_first + ((hist[start][0] - t_first) // self.block_us + 1) * self.block_us
                if kf.t_us < b_end + self.smooth_lag_us:
                    return
                stop = bisect.bisect_left(hist, b_end + self.smooth_lag_us, key=lambda h: h[0])
                final = bisect.bisect_left(hist, b_end, key=lambda h: h[0])
            if self.smooth:
                t, xs = kf.smoothed(start, stop)
                t, xs = t[:final - start], xs[:final - start]
            else:
                t = np.array([h[0] for h in hist[start:final]], np.int64)
                xs = np.array([h[4] for h in hist[start:final]])
            score, sigma = fl.scores[start:final], fl.sigmas[start:final]
            if start == 0 and fl.lead_us is not None:  # the row before the first update, from its state
                t = np.insert(t, 0, fl.lead_us)
                xs = np.vstack([kf.propagate(xs[0], t[1], fl.lead_us), xs])
                score, sigma = score[:1] + score, sigma[:1] + sigma
            self._final.append(Track(t_us=t, cx=xs[:, 0], cy=xs[:, 1], r=xs[:, 6], vx=xs[:, 2], vy=xs[:, 3],
                                     score=score, flight=np.full(len(t), fl.number), sigma_px=sigma))
            fl.n_final = final


def track_ball(events: np.ndarray, *, width: int, height: int, frames=None, frame_times_us=None,
               flicker_hz: float | None = None, **opts) -> Track:
    """Track the ball through a recording.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Time-sorted events.
    width, height : int
        Sensor size, px.
    frames : sequence of ndarray, optional
        Camera frames (grey or BGR) in the event camera's pixel geometry.
    frame_times_us : array_like of int, optional
        Mid-exposure time of each frame on the event clock, µs (required with ``frames``).
    flicker_hz : float or "auto", optional
        A light flickering at this frequency (100 / 120 Hz) lights the scene: events of pixels
        that fire at the same phase one period earlier or later are left out of detection
        (:func:`detect.flicker.flicker_mask`: the whole recording is filtered, its first period
        too). ``"auto"``: at the frequency :func:`detect.flicker.find_flicker_hz` finds, if any.
    **opts
        Options of :class:`BallTracker`.

    Returns
    -------
    Track
        One row per fused detection, smoothed; empty if no ball was found.
    """
    tracker = BallTracker(width, height, **opts)
    if frames is not None:
        if frame_times_us is None or len(frame_times_us) != len(frames):
            raise ValueError("frame_times_us must be given with frames, one time per frame")
        for image, t in zip(frames, frame_times_us):
            tracker.update_frame(image, int(t))
    events = np.asarray(events)
    if flicker_hz is not None and events.dtype == EVENT_DTYPE:  # (another dtype: update says so)
        tracker._check(events)  # order and bounds first (one line naming the problem)
        tracker._last_t = None
        if flicker_hz == "auto":
            flicker_hz = find_flicker_hz(events, tracker.width, tracker.height)
        if flicker_hz is not None:
            events = events[~flicker_mask(events, tracker.width, tracker.height, flicker_hz)]
    tracker.update(events)
    return tracker.finish()
