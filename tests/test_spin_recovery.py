"""Recovery of a known spin from simulated events, both methods.

The tolerances (a few degrees, a few percent) fail for a flipped axis sign (180 deg)
or a mirrored handedness (the axis (0.3, -0.5, 0.81) mirrors far away).  The paper
method runs 400 Adam iterations here instead of 1,500 (time); its start is the
shared coarse search.  A contrast threshold of 0.6 gives ~1 rad of rotation in
8,000 events so that the paper's joint velocity estimate is well posed.
"""

from types import SimpleNamespace

import numpy as np
import pytest

import sim
import spin

AXIS = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])


@pytest.fixture(scope="module")
def ball():
    return sim.spinning_ball("volleyball", rps=40, axis=AXIS, radius_px=40, n_events=8000, seed=1, threshold=0.6)


def _errors(est, truth):
    axis_deg = np.degrees(np.arccos(np.clip(np.dot(est.axis, truth["axis"]), -1, 1)))
    return axis_deg, abs(est.omega_rad_s - truth["omega_rad_s"]) / truth["omega_rad_s"]


def test_fast_recovers_known_spin(ball):
    events, truth = ball
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=truth["velocity_px_s"])
    axis_deg, omega_rel = _errors(est, truth)
    assert axis_deg < 2.0 and omega_rel < 0.03
    assert est.omega_rad_s >= 0 and est.rps == pytest.approx(est.omega_rad_s / (2 * np.pi))
    assert np.linalg.norm(est.axis) == pytest.approx(1.0)
    assert est.confidence > 0.5 and est.converged and est.method == "fast"
    assert est.t_start_us >= events["t"][0] and est.t_end_us <= events["t"][-1] + 1
    assert 0 < est.n_events <= len(events)


def test_fast_without_velocity_prior(ball):
    events, truth = ball
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"])
    axis_deg, omega_rel = _errors(est, truth)
    # the centre motion is estimated too (rough): looser, and never fully confident
    assert axis_deg < 5.0 and omega_rel < 0.05
    assert est.confidence <= 0.5


def test_paper_recovers_known_spin(ball):
    events, truth = ball
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=truth["velocity_px_s"],
                             method="paper", iterations=400)
    axis_deg, omega_rel = _errors(est, truth)
    assert axis_deg < 6.0 and omega_rel < 0.05
    assert est.method == "paper"


def test_estimate_windows_along_a_track(ball):
    from capture.events import Track, spin_table
    from detect.track import spin_windows

    events, truth = ball
    t0, t1 = int(events["t"][0]), int(events["t"][-1])
    (cx, cy), (vx, vy) = truth["center"], truth["velocity_px_s"]
    track = Track(t_us=[t0, t1], cx=[cx, cx + vx * (t1 - t0) * 1e-6], cy=[cy, cy + vy * (t1 - t0) * 1e-6],
                  r=[truth["radius_px"]] * 2, vx=[vx, vx], vy=[vy, vy], score=[1, 1], flight=[0, 0])
    window_us = (t1 - t0) // 2 + 1
    windows = list(spin_windows(events, track, window_us=window_us, min_events=1000))
    estimates = spin.estimate_windows(windows)
    assert len(estimates) == len(windows) == 2
    for est, win in zip(estimates, windows):
        axis_deg, omega_rel = _errors(est, truth)
        assert axis_deg < 3.0 and omega_rel < 0.03
        assert win.t_start_us <= est.t_start_us < est.t_end_us <= win.t_end_us
    cols = spin_table(estimates)
    assert np.allclose(cols["rps"], [e.rps for e in estimates]) and cols["axis"].shape == (2, 3)


def test_unstructured_events_give_low_confidence():
    from capture.events import make_events

    rng = np.random.default_rng(0)
    n = 6000
    ang = rng.uniform(0, 2 * np.pi, n)
    rad = 40 * np.sqrt(rng.uniform(0, 1, n))
    noise = make_events(np.sort(rng.integers(0, 3000, n)), 200 + rad * np.cos(ang), 150 + rad * np.sin(ang),
                        rng.integers(0, 2, n))
    est = spin.estimate_spin(noise, (200, 150), 40, velocity=(0, 0))
    assert est.confidence < 0.2


def test_velocity_from_centroids_follows_a_moving_ball():
    from spin.estimate import velocity_from_centroids

    events, truth = sim.spinning_ball("volleyball", rps=20, axis=AXIS, radius_px=30, n_events=6000, seed=2,
                                      threshold=0.6, velocity_px_s=(3000.0, -1500.0))
    v = velocity_from_centroids(events, truth["center"], truth["radius_px"])
    vt = np.asarray(truth["velocity_px_s"])
    # a rough prior only (event rates differ between leading and trailing rim): direction and scale
    assert np.dot(v, vt) / (np.linalg.norm(v) * np.linalg.norm(vt)) > 0.9
    assert 0.5 < np.linalg.norm(v) / np.linalg.norm(vt) < 2.0
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"])
    assert est.confidence <= 0.5  # no tracker velocity: never fully confident


def test_ball_mostly_outside_the_sensor_gives_low_confidence():
    # a ball entering from the left edge: only a sliver of it fires, and the sensor edge sweeping
    # across the ball is a structure the warp can align; the estimate must not be trusted
    events, truth = sim.spinning_ball("volleyball", rps=40, axis=AXIS, radius_px=36, center=(-28.0, 120.0),
                                      velocity_px_s=(3000.0, 0.0), n_events=3000, seed=4, threshold=0.4)
    assert events["x"].min() >= 0 and np.median(events["x"]) < 20  # the sim clips at the sensor edge
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=truth["velocity_px_s"])
    assert est.confidence < 0.2


@pytest.mark.parametrize("prior_factor, prior_axis", [(3.0, (0.0, 0.0, 1.0)), (0.3, (1.0, 0.0, 0.0)), (1.0, -AXIS)])
def test_wrong_warm_start_prior_is_not_trusted_blindly(ball, prior_factor, prior_axis):
    # estimate_windows seeds a window with the previous window's estimate; a wrong seed (another
    # speed and axis, or the reversed spin) must still give the right spin or a low confidence
    events, truth = ball
    prior = prior_factor * truth["omega_rad_s"] * np.asarray(prior_axis)
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=truth["velocity_px_s"],
                             prior_w_rad_s=prior)
    axis_deg, omega_rel = _errors(est, truth)
    assert (axis_deg < 2.0 and omega_rel < 0.03) or est.confidence < 0.2


def test_axis_near_image_plane_on_a_short_window_is_not_pulled_by_the_pixel_lattice():
    # a soccer ball turning ~5 deg over the window about an axis near the image plane, centre on a
    # half pixel: without spreading events over their pixel the estimate sat 5.9 deg off (the IWE of
    # slow-moving events scores the integer lattice)
    axis = np.array([0.99617121, -0.06579411, 0.05756788])
    events, truth = sim.spinning_ball("soccer", rps=100, axis=axis, radius_px=100, n_events=50_000,
                                      seed=880154882, threshold=0.15)
    assert np.all(np.asarray(truth["center"]) % 1 == 0.5)
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=truth["velocity_px_s"])
    axis_deg, omega_rel = _errors(est, truth)
    assert axis_deg < 2.0 and omega_rel < 0.02


@pytest.mark.parametrize("texture, axis, radius_px, center, n_events, sim_seed", [
    ("basketball", (-0.1269332740830614, 0.9546790133771692, 0.26921353113792235), 40.674301855623234,
     (567.3919925874711, 292.3063220013809), 20_000, 832657776),
    ("basketball", (-0.985480732579137, -0.11804548606205705, 0.12203683433971987), 44.73515924099677,
     (550.2391115491555, 272.7539234702176), 60_000, 166275970)])
def test_the_first_levels_best_answers_are_refined_together(texture, axis, radius_px, center, n_events, sim_seed,
                                                           monkeypatch):
    # two windows of the benchmark's held-out seeds 2002 and 1002 (``bench/spin_cases.draw``; 30 rps, still,
    # 20 ms, ideal sensor): the search before (three coarse starts, two steps each, the best alone past the
    # first level) ends 80-95 deg off at 10-27 times the rate, flagged; eight starts, six steps, whose best
    # three go on together find the spin. (Such cases are knife-edged: the parameters rounded to six digits,
    # or the contrast's sums rounded otherwise, can turn either; the benchmark measures the rates.)
    from spin import fast

    ev, truth = sim.spinning_ball(texture, rps=30, axis=np.asarray(axis) / np.linalg.norm(axis), radius_px=radius_px,
                                  center=center, velocity_px_s=(0.0, 0.0), width=1280, height=720, n_events=n_events,
                                  duration_s=0.02, seed=sim_seed)
    kw = dict(velocity=(0.0, 0.0), sensor_size=(1280, 720), t0_us=int(ev["t"][0]))
    est = spin.estimate_spin(ev, truth["center"], truth["radius_px"], **kw)
    axis_deg, omega_rel = _errors(est, truth)
    assert axis_deg < 2.0 and omega_rel < 0.02 and est.confidence >= 0.5
    monkeypatch.setattr(fast, "FAR_SIDE_FROM_LEVEL", len(fast.LEVELS))  # one IWE on every level, as then
    before = spin.estimate_spin(ev, truth["center"], truth["radius_px"], n_candidates=3, n_carry=1,
                                levels=((1.5, 12.0, 1.2, 500, 2, 1e-4),) + fast.LEVELS[1:], **kw)
    axis_deg, omega_rel = _errors(before, truth)
    assert (axis_deg > 20.0 or omega_rel > 0.2) and before.confidence < 0.5


def test_a_window_after_a_trusted_one_starts_from_it_with_the_narrow_search(ball, monkeypatch):
    import spin.estimate as estimate_mod
    from spin.fast import NARROW_SEARCH

    events, truth = ball
    half = len(events) // 2
    windows = [SimpleNamespace(events=part, center=truth["center"], radius_px=truth["radius_px"],
                               t_start_us=int(part["t"][0]), t_end_us=int(part["t"][-1]) + 1,
                               velocity_px_s=truth["velocity_px_s"], flight=0)
               for part in (events[:half], events[half:])]
    seen = []
    fast = estimate_mod.estimate_fast

    def spy(ev, velocity, **kw):
        seen.append(kw)
        return fast(ev, velocity, **kw)

    monkeypatch.setattr(estimate_mod, "estimate_fast", spy)
    first, second = spin.estimate_windows(windows)
    assert first.confidence >= 0.5
    assert "prior_w_rad_s" not in seen[0] and "n_candidates" not in seen[0]  # the wide search
    np.testing.assert_allclose(seen[1]["prior_w_rad_s"], first.axis * first.omega_rad_s)
    assert {k: seen[1][k] for k in NARROW_SEARCH} == NARROW_SEARCH
    assert _errors(second, truth)[0] < 2.0


def test_points_turned_to_the_far_side_go_to_an_iwe_of_their_own(monkeypatch):
    # a baseball turning 0.6 turn over 20 ms: warped to the reference time, the stitches seen early lie on
    # the far side; drawn over the near side's (one IWE on every level) they pull the estimate 21 deg /
    # 38 % off; in an IWE of their own from the second level on it is within 5 deg / 5 %.  (Such cases are
    # knife-edged: prepared as `spin.estimate_spin` prepares them, or with the contrast's sums rounded
    # otherwise, a window can go the other way; over the benchmark's 2,912 windows the second IWE adds 2-4 %
    # of them right on every seed set.)
    from spin import fast
    from spin.estimate import prepare

    events, truth = sim.spinning_ball("baseball", rps=30, axis=(0.4, -0.3, 0.85), radius_px=30, n_events=None,
                                      duration_s=0.02, seed=5)
    ev, _ = prepare(events, truth["center"], truth["radius_px"], dither=True, thin_to=24_000)
    w_true = truth["axis"] * truth["omega_rad_s"]
    angle, log_ratio = fast._deviation(fast.estimate_fast(ev, (0.0, 0.0)).w_rad_s, w_true)
    assert angle < 5 and log_ratio < np.log(1.05)
    monkeypatch.setattr(fast, "FAR_SIDE_FROM_LEVEL", len(fast.LEVELS))
    angle, log_ratio = fast._deviation(fast.estimate_fast(ev, (0.0, 0.0)).w_rad_s, w_true)
    assert angle > 5 or log_ratio > np.log(1.05)
