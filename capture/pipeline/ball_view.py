"""The ball's events of one spin window, as recorded and turned back by the estimated spin.

A reviewer judges a spin estimate by eye: the events of the ball over a window, with the ball's
image motion taken out, are a smear; turned back by the estimated rotation (the same warp the
estimator maximises the sharpness of) they show the ball's texture sharp when the spin is right.
Used by the HTML report (:mod:`capture.pipeline.html_report`) and, passed to
:func:`capture.review.write_rrd`, by the Rerun review.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture.events import Track


@dataclass
class BallView:
    """Event counts around the ball's centre over one spin window.

    Attributes
    ----------
    recorded, turned : ndarray of float64, shape (bins, bins)
        Events per cell (rows: image y, columns: image x), with the ball's image motion taken out,
        as recorded and turned back by the estimated spin.
    r_px : float
        The ball's radius, px.
    half_px : float
        Half the side of the square both cover, centred on the ball, px.
    axis : ndarray, shape (3,)
        The estimated spin axis (camera frame).
    """

    recorded: np.ndarray
    turned: np.ndarray
    r_px: float
    half_px: float
    axis: np.ndarray


def ball_view(session, track: Track, spin: dict, i: int, *, flight: int | None = None, bins: int = 96,
              max_events: int = 30_000) -> BallView | None:
    """The :class:`BallView` of spin window ``i`` of ``spin`` (:data:`capture.events.SPIN_COLUMNS`),
    its events read from ``session``; None when the window's events cannot be used (too few, no
    ball). ``half_px`` is 1.15 ball radii."""
    from spin.estimate import SpinInputError, prepare
    from spin.objective import warp

    t0, t1 = int(spin["t_start_us"][i]), int(spin["t_end_us"][i])
    cx, cy, r, vx, vy = track.at(t0, flight=flight)
    events = session.events(t_start_us=t0, t_end_us=t1)
    try:
        ev, _ = prepare(events, (cx, cy), r, t0_us=t0, velocity_px_s=(vx, vy), max_events=max_events)
    except SpinInputError:
        return None
    axis = np.asarray(spin["axis"][i], np.float64)
    q = warp(ev, axis * float(spin["omega_rad_s"][i]), (vx, vy))
    half = 1.15 * r
    edges = [[-half, half], [-half, half]]
    recorded = np.histogram2d(ev.y_px - vy * ev.s_s, ev.x_px - vx * ev.s_s, bins=bins, range=edges)[0]
    turned = np.histogram2d(q[1], q[0], bins=bins, range=edges)[0]
    return BallView(recorded=recorded, turned=turned, r_px=float(r), half_px=float(half), axis=axis)
