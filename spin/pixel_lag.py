"""The sensor's lag seen on the ball: how far its surface turns between the events of one pixel's burst.

An ideal pixel fires all the events of one edge (a seam, a panel's border) while the edge crosses
it.  A real one cannot follow a fast edge: its photoreceptor's bandwidth falls with the light, its
refractory period holds it after each event, and its readout adds delay; so the events of one edge
at one pixel come spread over tens to hundreds of µs, and on a ball at hundreds of revolutions per
second the surface turns many pixels meanwhile.  Contrast maximisation then aligns trails behind
the edges, not the edges, and its rate comes out biased (low, by up to 20-30 % at 800-1,200 rps on
the benchmark's realistic sensor, ``sim.SensorModel``).  The shading that sets each pixel's lag is
fixed in the image, so every part of the window shares the bias and the cross-check of its halves
cannot see it.

The trail is measured from the data: consecutive events of one pixel, both of one polarity (a burst),
their time apart times the speed, under the estimated spin, of the ball's surface at that pixel.
Its median against the distance the surface travels in the window (:func:`rate_bias_pct`) corrects part
of the rate's bias and gives its systematic uncertainty (``spin.fast.LAG_RATE_GAIN``, ``LAG_SIGMA_SCALE``):
an ideal sensor gives trails of about 0.1 px, the realistic one 2-20 px at 200-1,200 rps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spin import lens

MAX_BURST_EVENTS = 10_000
"""Events on the ball searched for bursts, about: those of a pseudo-random share of the pixels, so
that every pixel kept keeps all its bursts (thousands of pairs, plenty for a median)."""

MIN_PAIRS = 20
"""Fewest burst pairs that give a trail (fewer: no measurement, no bias term)."""


@dataclass(frozen=True)
class Bursts:
    """Pairs of consecutive events of one pixel on the ball, both of one polarity.

    Attributes
    ----------
    dt_s : ndarray (M,)
        Time between the two events, s.
    x, y : ndarray (M,)
        Position of the later event relative to the ball's centre at its time, in the coordinates
        of :class:`spin.objective.BallEvents` (px for an orthographic camera, ball units through a
        :class:`spin.lens.BallView`).
    radius : float
        The ball's radius in the same units.
    """

    dt_s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    radius: float

    def __len__(self) -> int:
        return len(self.dt_s)


def _mixed(key: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser of ``key`` (uint64): every bit of the result depends on every bit of the key
    (a plain multiplicative hash's low bits follow the key's low bits, here a pixel's column)."""
    h = key.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return h


def bursts(events, center, radius_px: float, *, t0_us: int, velocity_px_s, view: lens.BallView | None = None,
           rim_fraction: float = 0.9, max_events: int = MAX_BURST_EVENTS) -> Bursts:
    """The burst pairs of the events inside the moving circle (see :class:`Bursts`).

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        The window's events (sorted by time here if they are not).
    center : (float, float)
        Circle centre at ``t0_us``, px.
    radius_px : float
        Circle radius, px.
    t0_us : int
        Time of ``center``, µs.
    velocity_px_s : (float, float)
        Image velocity of the centre, px/s.
    view : spin.lens.BallView, optional
        The ball seen through a calibrated camera: positions are then ball coordinates
        (:func:`spin.lens.ball_coordinates`).
    rim_fraction : float
        Events within this share of the radius count (the rim's own events are left out).
    max_events : int
        About this many events inside the circle are searched: all those of every k-th pixel
        (thinning in time would break the bursts).
    """
    t_us = np.asarray(events["t"], dtype=np.int64)
    if (t_us[1:] < t_us[:-1]).any():
        order = np.argsort(t_us, kind="stable")
        events, t_us = events[order], t_us[order]
    f32 = np.float32
    s = (t_us - int(t0_us)).astype(f32)
    s *= f32(1e-6)
    vx, vy = (float(c) for c in velocity_px_s)
    x, y = events["x"], events["y"]
    dx = x.astype(f32)
    dx -= f32(center[0]) + f32(vx) * s
    dy = y.astype(f32)
    dy -= f32(center[1]) + f32(vy) * s
    reach = rim_fraction * float(radius_px)
    idx = np.flatnonzero(dx * dx + dy * dy <= f32(reach * reach))
    pixel = y[idx].astype(np.int64) * 65536 + x[idx]
    if len(idx) > max_events:  # every k-th pixel, pseudo-randomly (a lattice could follow the texture)
        keep = _mixed(pixel) % np.uint64(-(-len(idx) // max_events)) == 0
        idx, pixel = idx[keep], pixel[keep]
    order = np.argsort(pixel, kind="stable")  # stable: each pixel's events stay in time order
    on = events["p"][idx[order]] > 0
    # consecutive events of one pixel with one polarity: an event of the other polarity between them
    # is another edge
    same = np.flatnonzero((pixel[order[1:]] == pixel[order[:-1]]) & (on[1:] == on[:-1]))
    later, earlier = idx[order[same + 1]], idx[order[same]]
    dt_s = (t_us[later] - t_us[earlier]) * 1e-6
    if view is None:
        return Bursts(dt_s, dx[later].astype(np.float64), dy[later].astype(np.float64), float(radius_px))
    uv = np.stack([x[later], y[later]], axis=1).astype(np.float64)
    xy, hit = lens.ball_coordinates(view, uv, s[later].astype(np.float64), (vx, vy))
    return Bursts(dt_s[hit], xy[0, hit], xy[1, hit], float(view.radius))


def trail(pairs: Bursts, w_rad_s) -> float:
    """Median distance the surface moves between the two events of a burst pair, in the units of
    ``pairs`` (NaN with fewer than :data:`MIN_PAIRS` pairs).

    The surface's image velocity at a pair's position is that of the near-side sphere point under
    the angular velocity ``w_rad_s`` (rad/s, the frame of ``pairs``).  Pairs farther apart than
    the radius are two edges, not one burst, and are left out.
    """
    wx, wy, wz = (float(c) for c in np.asarray(w_rad_s, dtype=np.float64))
    r = pairs.radius
    z = -np.sqrt(np.maximum(r * r - pairs.x * pairs.x - pairs.y * pairs.y, 0.0))
    speed = np.hypot(wy * z - wz * pairs.y, wz * pairs.x - wx * z)
    moved = speed * pairs.dt_s
    moved = moved[moved < r]
    return float(np.median(moved)) if len(moved) >= MIN_PAIRS else float("nan")


def rate_bias_pct(pairs: Bursts | None, w_rad_s, window_s: float) -> float:
    """The trail (:func:`trail`) over the distance the ball's equator travels in the window, in %.

    0 without pairs or a trail: no term.  On the benchmark's realistic sensor the rate came out low by
    0.3-0.5 of this beyond a few % (``spin.fast.LAG_RATE_GAIN`` corrects it; ``LAG_SIGMA_SCALE`` of it is
    the rate's systematic uncertainty).
    """
    if pairs is None or len(pairs) < MIN_PAIRS:
        return 0.0
    travel = float(np.linalg.norm(w_rad_s)) * float(window_s) * pairs.radius
    moved = trail(pairs, w_rad_s)
    if not np.isfinite(moved) or travel <= 0:
        return 0.0
    return 100.0 * moved / travel
