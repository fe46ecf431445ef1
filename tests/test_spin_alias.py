"""Aliased spins: the estimate is right or reported with low confidence.

A pattern with 12-fold symmetry about the spin axis (+Z, camera forward) seen by a
strobe: events only in short bursts every ``gap``.  Between bursts the ball turns
unseen, so a spin faster by ``2 pi / (12 gap)`` (one symmetry step per gap) moves
every burst onto the same pattern: omega and about 2 omega (and a slow spin about
the opposite axis) align the events equally well.  The same pattern under steady
light (events spread over the window) has no alias, but its sparse rings of dots are
hard for the coarse search: right or not trusted there too.
"""

import numpy as np
import pytest

import spin
from capture.events import make_events
from spin.estimate import prepare
from spin.objective import IweGeometry, contrast

K = 12  # pattern symmetry order about the spin axis
CENTER = (160.0, 120.0)
RADIUS = 40.0
OMEGA_SLOW = 2 * np.pi * 100.0
GAP_US = 0.5 / OMEGA_SLOW * 1e6  # half a radian per gap at 100 rps
ALIAS_STEP = 2 * np.pi / (K * GAP_US * 1e-6)  # rad/s; 2 pi / K per gap


def _pattern_events(omega_rad_s, seed, *, strobe):
    """Dots of a K-fold symmetric pattern on a ball spinning about +Z; strobed bursts or steady."""
    rng = np.random.default_rng(seed)
    radii = RADIUS * np.sqrt(rng.uniform(0.05, 0.8, 4))
    angles = (rng.uniform(0, 2 * np.pi / K, 4)[None, :] + 2 * np.pi / K * np.arange(K)[:, None]).ravel()
    radii = np.tile(radii, K)
    n_bursts, per_dot = 9, (6 if strobe else 30)
    if strobe:
        t_us = 20 + np.arange(n_bursts)[:, None, None] * GAP_US + rng.integers(-6, 7, (n_bursts, len(radii), per_dot))
    else:
        t_us = rng.uniform(14, 26 + (n_bursts - 1) * GAP_US, (n_bursts, len(radii), per_dot))
    t_us = np.round(t_us).astype(np.int64)
    rad = radii[None, :, None] + rng.normal(0, 0.4, t_us.shape)
    ang = angles[None, :, None] + omega_rad_s * t_us * 1e-6 + rng.normal(0, 0.4, t_us.shape) / rad
    t, x, y = t_us.ravel(), (CENTER[0] + rad * np.cos(ang)).ravel(), (CENTER[1] + rad * np.sin(ang)).ravel()
    order = np.argsort(t, kind="stable")
    return make_events(t[order], np.round(x[order]), np.round(y[order]), np.ones(len(t), dtype=np.int64))


def _right(est, omega_rad_s):
    axis_deg = np.degrees(np.arccos(np.clip(est.axis[2], -1.0, 1.0)))
    return axis_deg < 5.0 and abs(est.omega_rad_s - omega_rad_s) / omega_rad_s < 0.05


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("omega_rad_s, alias_rad_s", [(OMEGA_SLOW, OMEGA_SLOW + ALIAS_STEP),
                                                      (OMEGA_SLOW + ALIAS_STEP, OMEGA_SLOW)])
def test_strobed_symmetric_pattern_is_right_or_not_trusted(omega_rad_s, alias_rad_s, seed):
    events = _pattern_events(omega_rad_s, seed, strobe=True)
    # the construction really is aliased: the alias (about 2x or 1/2x) scores like the truth,
    # clearly above a spin 30 % off
    ev, _ = prepare(events, CENTER, RADIUS, velocity_px_s=(0.0, 0.0), rim_fraction=0.95)
    geometry = IweGeometry(RADIUS, 2.0, 1.1)
    c_true, c_alias, c_off = (contrast(ev, np.array([0.0, 0.0, om]), (0.0, 0.0), geometry, gradient=False)
                              for om in (omega_rad_s, alias_rad_s, 1.3 * omega_rad_s))
    assert abs(c_alias - c_true) < 0.02 * c_true and c_off < 0.5 * c_true
    est = spin.estimate_spin(events, CENTER, RADIUS, velocity=(0.0, 0.0))
    assert _right(est, omega_rad_s) or est.confidence < 0.2


@pytest.mark.parametrize("omega_rad_s", [OMEGA_SLOW, OMEGA_SLOW + ALIAS_STEP])
def test_same_pattern_under_steady_light_is_right_or_not_trusted(omega_rad_s):
    # the sparse rings of dots can defeat the coarse search even without a strobe; a wrong answer
    # (its contrast does not beat that of no rotation) must then not be trusted
    events = _pattern_events(omega_rad_s, 0, strobe=False)
    est = spin.estimate_spin(events, CENTER, RADIUS, velocity=(0.0, 0.0))
    assert _right(est, omega_rad_s) or est.confidence < 0.2
