"""The unlit limb (#16): a ball whose rim fires on its lit side only is fitted on that side.

Synthetic events first (a sharp ring on the lit directions, shading that stops inside the rim on
the others; a textured disc), then the tracker on a simulated plain ball whose shaded limb is as
bright as the background.
"""

import numpy as np
import pytest

import sim
from detect import _kernels, track_ball
from detect.event_detector import fit_circle
from detect.limb import N_SECTORS, LimbModel, sharp_directions

CX, CY, R = 60.0, 50.0, 25.0


def _direction_sector(a_rad):
    """Sector (of N_SECTORS) of the direction ``a_rad`` (atan2 convention, image y down)."""
    return (np.floor((a_rad + np.pi) * N_SECTORS / (2 * np.pi)).astype(int)) % N_SECTORS


def _half_lit(rng, n=1500, lit_from=-2.6, lit_to=0.6):
    """Events of a ball lit on directions ``lit_from .. lit_to`` (rad): there a ring 0.3 px wide at the
    rim (plus shading inside it), elsewhere only shading that ends 1.5 px inside the rim."""
    a = rng.uniform(-np.pi, np.pi, n)
    lit = (a >= lit_from) & (a <= lit_to)
    ring = lit & (rng.random(n) < 0.6)
    rho = np.where(ring, R + rng.normal(0.0, 0.3, n), (R - 1.5) - rng.uniform(0.0, 6.0, n) ** 1.3)
    return CX + rho * np.cos(a), CY + rho * np.sin(a), lit


def _flight_of_half_lit_windows(rng, n=8):
    """A LimbModel that has seen ``n`` windows of a half-lit ball, each refined then observed."""
    limb = LimbModel()
    for _ in range(n):
        x, y, _ = _half_lit(rng)
        fit = fit_circle(x, y, center0=(CX, CY))
        limb.observe(x, y, limb.refine(x, y, fit, (5.0, 60.0)))
    return limb


def _error(fit):
    return float(np.hypot(fit.cx - CX, fit.cy - CY))


def test_lit_rim_fit_uses_the_sharp_directions_only():
    rng = np.random.default_rng(0)
    x, y, _ = _half_lit(rng)
    centres = np.arange(N_SECTORS) * (2 * np.pi / N_SECTORS) - np.pi + np.pi / N_SECTORS
    lit_dirs = (centres >= -2.6 + 0.2) & (centres <= 0.6 - 0.2)
    start = fit_circle(x, y, center0=(CX + 1, CY - 1))
    found, cx, cy, r, rms, dilution = _kernels.lit_rim_fit(x, y, lit_dirs, start.cx, start.cy, start.r, 3, 1.0, 8, 4)
    # an arc of half the circle: the centre's error per px of scatter is above a whole circle's
    assert found and np.sqrt(2.0 / np.count_nonzero(lit_dirs)) < dilution < 10.0
    assert np.hypot(cx - CX, cy - CY) < 0.15 and abs(r - R) < 0.15
    # every direction: the shading's edge pulls the circle towards the lit side
    found, cx, cy, r, *_ = _kernels.lit_rim_fit(x, y, np.ones(N_SECTORS, bool), start.cx, start.cy, start.r, 3, 1.0,
                                                8, 4)
    assert found and np.hypot(cx - CX, cy - CY) > 0.5


def test_a_flight_learns_its_lit_directions_and_its_fits_move_to_the_rim():
    rng = np.random.default_rng(1)
    limb = _flight_of_half_lit_windows(rng)
    sharp, unlit = sharp_directions(limb.profile)
    assert np.array_equal(limb.rim, sharp)
    x, y, lit = _half_lit(rng)
    # the directions well inside the lit arc are sharp, those well inside the dark one are not
    centres = np.arange(N_SECTORS) * (2 * np.pi / N_SECTORS) - np.pi + np.pi / N_SECTORS
    assert sharp[(centres > -2.3) & (centres < 0.3)].all()
    assert not sharp[(centres > 0.9) | (centres < -2.9)].any() and unlit[(centres > 0.9) | (centres < -2.9)].all()
    fit = fit_circle(x, y, center0=(CX, CY))
    refined = limb.refine(x, y, fit, (5.0, 60.0))
    assert _error(fit) > 0.6 and _error(refined) < 0.25 and abs(refined.r - R) < 0.25
    assert refined.score == fit.score and refined.coverage == fit.coverage


def test_a_ball_firing_over_its_disc_or_its_whole_rim_is_left_as_it_is():
    rng = np.random.default_rng(2)
    for kind in ("disc", "ring"):
        limb = LimbModel()
        for _ in range(8):
            a = rng.uniform(-np.pi, np.pi, 2000)
            rho = R * np.sqrt(rng.random(2000)) if kind == "disc" else R + rng.normal(0.0, 0.3, 2000)
            x, y = CX + rho * np.cos(a), CY + rho * np.sin(a)
            fit = fit_circle(x, y, center0=(CX + 1, CY))
            assert limb.refine(x, y, fit, (5.0, 60.0)) is fit
            limb.observe(x, y, fit)


def test_a_narrow_lit_arc_is_not_refitted():
    """Sharp directions over less than half the circle leave the circle ill-defined: no refit."""
    rng = np.random.default_rng(3)
    limb = LimbModel()
    for _ in range(8):
        x, y, _ = _half_lit(rng, lit_from=-2.0, lit_to=-0.6)
        fit = fit_circle(x, y, center0=(CX, CY))
        assert limb.refine(x, y, fit, (5.0, 60.0)) is fit
        limb.observe(x, y, fit)
    assert sharp_directions(limb.profile)[0].any() and limb.rim is None


def test_a_ball_whose_unsharp_side_fires_out_to_its_rim_is_not_refitted():
    """A textured ball with a sharper rim on one side: the lit arc is found, but no side's edge lies
    inside the rim, so no refit is taken."""
    rng = np.random.default_rng(5)
    limb = LimbModel()
    for _ in range(8):
        a = rng.uniform(-np.pi, np.pi, 3000)
        ring = (a > -2.6) & (a < 0.6) & (rng.random(3000) < 0.5)
        rho = np.where(ring, R + rng.normal(0.0, 0.3, 3000), R * np.sqrt(rng.random(3000)))
        x, y = CX + rho * np.cos(a), CY + rho * np.sin(a)
        fit = fit_circle(x, y, center0=(CX + 1, CY))
        assert limb.refine(x, y, fit, (5.0, 60.0)) is fit
        limb.observe(x, y, fit)
    assert limb.rim is not None


@pytest.fixture(scope="module")
def dark_limb_flight():
    """A plain ball crossing a 160x120 realistic sensor, lit from the upper left in front of a background
    as bright as its unlit limb (which then fires no rim events)."""
    return sim.flight("plain", rps=0.0, radius_px=24.0, width=160, height=120, duration_s=0.12,
                      start_px=(30.0, 60.0), velocity_px_s=(800.0, 0.0), gravity_px_s2=0.0, background="plain",
                      sensor="realistic", distractors=(), noise_rate_hz=0.0, hot_pixels=0, seed=4)


def _centre_errors(rec, track):
    truth = rec.truth_track(visible_only=False)
    cx, cy = (np.interp(track.t_us, truth.t_us, getattr(truth, k)) for k in ("cx", "cy"))
    return np.hypot(track.cx - cx, track.cy - cy)


def test_the_tracker_fits_a_ball_with_an_unlit_limb_on_its_lit_side(dark_limb_flight, monkeypatch):
    rec = dark_limb_flight
    with_limb = _centre_errors(rec, track_ball(rec.events, width=rec.width, height=rec.height))
    monkeypatch.setattr(LimbModel, "refine", lambda self, x, y, fit, r_range: fit)
    without = _centre_errors(rec, track_ball(rec.events, width=rec.width, height=rec.height))
    assert len(with_limb) >= 0.8 * len(without) > 10
    assert np.median(with_limb) < 0.6 * np.median(without)
    assert np.median(with_limb) < 0.8


def test_a_refitting_flight_keeps_its_lit_directions_while_its_profile_briefly_shows_none(monkeypatch):
    """A sparse window's profile may now and then single out no lit arc (as a looming ball grows on a
    small sensor): a flight that refits keeps its lit directions for HOLD_FITS fits, so its track does
    not alternate between refits and fits leaning toward the light (which once lost the ball)."""
    import detect.limb as limb_mod
    rng = np.random.default_rng(6)
    limb = _flight_of_half_lit_windows(rng)
    lit = limb.rim.copy()
    monkeypatch.setattr(limb_mod, "_rim_directions", lambda profile: None)  # the profile shows none from now
    refits = []
    for _ in range(limb_mod.HOLD_FITS + 3):
        x, y, _ = _half_lit(rng)
        fit = fit_circle(x, y, center0=(CX, CY))
        out = limb.refine(x, y, fit, (5.0, 60.0))
        refits.append(out is not fit)
        limb.observe(x, y, out)
        if refits[-1]:
            assert np.array_equal(limb.rim, lit) and _error(out) < 0.3 < _error(fit)
    # held as long as it refits: every fit here is refitted
    assert all(refits)
    # a flight that has not refitted for HOLD_FITS fits lets go
    limb.wait = limb_mod.HOLD_FITS + 1
    for _ in range(limb_mod.HOLD_FITS + 1):
        x, y, _ = _half_lit(rng)
        fit = fit_circle(x, y, center0=(CX, CY))
        assert limb.refine(x, y, fit, (5.0, 60.0)) is fit
        limb.observe(x, y, fit)
    assert limb.rim is None


def test_a_refit_that_changes_the_radius_by_much_is_not_taken(monkeypatch):
    """A refit through too few points once took 10 % off the radius (within 0.1 r of the centre) and
    lost the ball: a refit that changes the radius by more than REFIT_MAX_DR of it is not taken (made
    larger here: a smaller one could also fail the unlit directions' inset)."""
    import detect.limb as limb_mod
    limb = _flight_of_half_lit_windows(np.random.default_rng(7))
    x, y, _ = _half_lit(np.random.default_rng(8))
    fit = fit_circle(x, y, center0=(CX, CY))
    real = limb_mod.lit_rim_fit
    for scale, taken in ((1.0 + 0.5 * limb_mod.REFIT_MAX_DR, True), (1.0 + 1.5 * limb_mod.REFIT_MAX_DR, False)):
        def scaled(*args, scale=scale):
            found, cx, cy, r, rms, dilution = real(*args)
            return found, cx, cy, scale * fit.r, rms, dilution
        monkeypatch.setattr(limb_mod, "lit_rim_fit", scaled)
        out = limb.refine(x, y, fit, (5.0, 60.0))
        assert (out is not fit) == taken


def _within_two_sigma(rec, track):
    """Shares of rows whose centre and radius lie within twice the row's ``sigma_px`` of the truth."""
    truth = rec.truth_track(visible_only=False)
    cx, cy, r = (np.interp(track.t_us, truth.t_us, getattr(truth, k)) for k in ("cx", "cy", "r"))
    return (np.mean(np.hypot(track.cx - cx, track.cy - cy) <= 2 * track.sigma_px),
            np.mean(np.abs(track.r - r) <= 2 * track.sigma_px))


def test_track_sigma_covers_the_lean_of_a_ball_seen_only_at_its_rim(dark_limb_flight, monkeypatch):
    """A plain ball's fit leans towards the light by more than its residuals say: the track's sigma
    still covers the centre and radius errors (its rim-only term does), and is larger than a textured
    ball's, whose sigma stays near the pixel grid's limit."""
    import detect.event_detector as ed
    rec = dark_limb_flight
    track = track_ball(rec.events, width=rec.width, height=rec.height)
    assert len(track) > 30 and np.isfinite(track.sigma_px).all()
    centre, radius = _within_two_sigma(rec, track)
    assert centre >= 0.9 and radius >= 0.9
    monkeypatch.setattr(ed, "SIGMA_RIM_ONLY_SCALE", 0.0)  # the fit's scatter and the floor alone
    assert _within_two_sigma(rec, track_ball(rec.events, width=rec.width, height=rec.height))[0] < 0.9
    monkeypatch.undo()
    textured = sim.flight("volleyball", rps=30.0, radius_px=24.0, width=320, height=240, duration_s=0.08,
                          start_px=(40.0, 120.0), velocity_px_s=(2500.0, 0.0), gravity_px_s2=0.0, seed=3)
    tex_track = track_ball(textured.events, width=textured.width, height=textured.height)
    assert min(_within_two_sigma(textured, tex_track)) >= 0.9
    assert np.median(tex_track.sigma_px) < 0.4 < 2 * np.median(tex_track.sigma_px) < np.median(track.sigma_px)
