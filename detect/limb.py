"""The unlit limb: which sides of a tracked ball show its rim.

A plain ball lit from one side fires at its rim only where the rim stands out from the background.
Where its shaded limb is about as bright as the background (the lower limb under a ceiling light)
nothing fires at the rim; the outermost events there come from the shading inside it, 1-3 px inside
the rim, and a circle through every side's outermost events sits too far towards the lit side. Where
the rim does fire, its events pile up in a ring about a pixel wide; the outermost few lie outside it,
so the rim is where that ring is, not where its outermost events are.

The light does not move during a flight, so which directions (in the image) show a sharp rim is
learnt over the flight's fits: :class:`LimbModel` keeps, per direction, how many events lie at the
fitted rim against how many lie 2-4 px inside it. Where some directions show a sharp rim and others
fire without one, each fit is refined on the sharp directions alone (:func:`detect._kernels.lit_rim_fit`),
and the refit is kept where the other directions' outermost events lie well inside it. A ball that fires
over its whole disc (a textured one), or at its whole rim, shows no such contrast and its fits are
left as they are.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from detect._kernels import lit_rim_fit, limb_profile, sector_tops
from detect.event_detector import centre_sigma_px

N_SECTORS = 16
# the rings of the profile, px from the fitted rim: inside it, and at it
INNER_PX = (4.0, 2.0)
EDGE_PX = 1.0
# a direction shows a sharp rim where its edge ring holds this many times the events per px of width
# of the inner ring, with at least MIN_EVENTS events in the two rings (averaged over recent fits)
SHARP_RATIO = 1.8
MIN_EVENTS = 5.0
# the refinement needs this many sharp directions and MIN_UNLIT that fire (MIN_EVENTS) without a sharp
# rim, with no run of more than MAX_GAP directions in a row without one (a shorter arc leaves the
# circle ill-defined); directions that fire little (where the rim moves along itself) are neither
MIN_SHARP = 4
MIN_UNLIT = 3
MAX_GAP = N_SECTORS // 2 - 1
# ... and this many fits of the flight observed (its first fits, a bounce's included, are left alone)
MIN_FITS = 5
# each fit's profile enters the flight's with this weight (about the last 10 fits), from an even
# subsample of at most about PROFILE_EVENTS of its events (its counts scaled back up)
UPDATE_WEIGHT = 0.1
PROFILE_EVENTS = 1000
# the rim's events lie within this of the k-th outermost of a direction (px); k and the least events
BAND_PX = 1.0
K_OUTER = 3
MIN_SECTOR_EVENTS = 8
# a refit that moves the centre by more than 0.1 of the radius, or changes the radius by more than this
# share of it, is not taken (the tuning seeds' refits change it by -5.7 to +3 % at the 1st / 99th
# percentiles; a refit on too few points once took 10 % off and lost the ball)
REFIT_MAX_DR = 0.08
# a refit is taken where the unlit directions' k-th outermost events lie at least this deep inside it
# (px, their median): their edge is shading inside the rim, not the rim. A textured ball fires out to
# its rim everywhere (its unlit directions' depth at most -0.1 px on the bench's rows at the 90th
# percentile); after a refit found no such edge, the next RETRY_AFTER fits are left as they are
INSET_PX = 0.5
RETRY_AFTER = 8
INSET_WEIGHT = 0.3
# a flight refitted within the last HOLD_FITS fits keeps its lit directions where its profile
# briefly singles out none (a sparse window's lit arc shows gaps): a track alternating between
# refits and fits leaning toward the light jitters by a pixel or more, and may be lost
HOLD_FITS = 10


def _longest_gap(sharp: np.ndarray) -> int:
    """Most directions in a row (around the circle) that are not ``sharp`` (bool, at least one True)."""
    at = np.flatnonzero(sharp)
    return int(np.max(np.diff(at, append=at[0] + len(sharp)))) - 1


def sharp_directions(profile: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bool per direction of a flight's ``profile`` (see :class:`LimbModel`): a sharp rim, and firing
    (``MIN_EVENTS`` in the two rings) without one."""
    inner, edge = profile[:, 0], profile[:, 1]
    firing = inner + edge >= MIN_EVENTS
    sharp = (edge / (2.0 * EDGE_PX) >= SHARP_RATIO * inner / (INNER_PX[0] - INNER_PX[1])) & firing
    return sharp, firing & ~sharp


def _rim_directions(profile: np.ndarray) -> np.ndarray | None:
    """The directions to fit the rim on (bool, N_SECTORS) from a flight's ``profile``, or None where
    the profile does not single out a lit arc (too few sharp or unlit directions, or too short an arc)."""
    sharp, unlit = sharp_directions(profile)
    if (np.count_nonzero(sharp) < MIN_SHARP or np.count_nonzero(unlit) < MIN_UNLIT
            or _longest_gap(sharp) > MAX_GAP):
        return None
    return sharp


class LimbModel:
    """The directions in which one flight's ball shows a sharp rim, learnt from its fits.

    ``profile`` (N_SECTORS, 2): per direction (sector ``k`` of ``atan2(dy, dx) + pi``, image y down),
    the recent fits' mean counts of events 2-4 px inside the fitted rim and within 1 px of it.
    ``rim``: the sharp directions, where the profile singles out a lit arc after ``MIN_FITS`` fits
    (or did within ``HOLD_FITS`` of a refit taken); else None.
    """

    def __init__(self):
        self.profile: np.ndarray | None = None
        self.n_fits = 0  # fits observed
        self.rim: np.ndarray | None = None
        self.wait = 0  # fits to leave as they are before the next refit
        self.inset_px = np.nan  # the refits' mean depth of the unlit directions' edge inside them
        self.since_refit = HOLD_FITS + 1  # fits since the last refit taken

    def refine(self, x: np.ndarray, y: np.ndarray, fit, r_range: tuple[float, float]):
        """``fit`` (a :class:`~detect.event_detector.CircleFit` of events ``(x, y)``, px, float64) refitted
        on the directions ``rim``, where the flight has them and the others' edge lies ``INSET_PX``
        inside the refit; else ``fit``.

        The refit keeps ``fit``'s score and coverage; its ``sigma_px`` is that of its points on their arc.
        It is not taken where its radius leaves ``r_range`` (px), its centre moves more than 0.1 of it or its
        radius more than ``REFIT_MAX_DR`` of it.
        """
        self.since_refit += 1
        if self.wait > 0:
            self.wait -= 1
            return fit
        refit = self._refit(x, y, fit, r_range) if self.rim is not None else None
        if refit is None:
            return fit
        self.since_refit = 0
        return refit

    def _refit(self, x, y, fit, r_range):
        """The refit of :meth:`refine`, or None where there is none; where the unlit directions' edge is not
        (on average over the refits) ``INSET_PX`` inside it, the next ``RETRY_AFTER`` fits are not tried."""
        found, cx, cy, r, rms, dilution = lit_rim_fit(x, y, self.rim, fit.cx, fit.cy, fit.r, K_OUTER, BAND_PX,
                                                      MIN_SECTOR_EVENTS, 4)
        if (not found or not r_range[0] <= r <= r_range[1] or np.hypot(cx - fit.cx, cy - fit.cy) > 0.1 * fit.r
                or abs(r - fit.r) > REFIT_MAX_DR * fit.r):
            return None
        counts, _, kth_rho2, _ = sector_tops(x, y, cx, cy, N_SECTORS, K_OUTER, K_OUTER)
        unlit = ~self.rim & (counts >= MIN_SECTOR_EVENTS)
        if not unlit.any():
            return None
        inset = float(np.median(r - np.sqrt(kth_rho2[unlit])))
        w = 1.0 if np.isnan(self.inset_px) else INSET_WEIGHT
        self.inset_px = (1.0 - w) * np.nan_to_num(self.inset_px) + w * inset
        if self.inset_px < INSET_PX:
            self.wait = RETRY_AFTER
            return None
        return replace(fit, cx=float(cx), cy=float(cy), r=float(r), sigma_px=centre_sigma_px(dilution, rms))

    def observe(self, x: np.ndarray, y: np.ndarray, fit) -> None:
        """Add the profile of events ``(x, y)`` (px, float64) around ``fit`` (a fit of the ball)."""
        step = max(1, len(x) // PROFILE_EVENTS)
        xs, ys = (np.ascontiguousarray(a[::step]) for a in (x, y))
        new = step * limb_profile(xs, ys, fit.cx, fit.cy, fit.r, N_SECTORS, INNER_PX, EDGE_PX)
        self.n_fits += 1
        self.profile = new if self.profile is None else (1.0 - UPDATE_WEIGHT) * self.profile + UPDATE_WEIGHT * new
        rim = _rim_directions(self.profile) if self.n_fits >= MIN_FITS else None
        if rim is not None or self.since_refit > HOLD_FITS:
            self.rim = rim
