"""A flight's spin from all its events at its image period's speed (spin.flight)."""

import math

import numpy as np
import pytest

import sim
from spin.flight import TRUST_EXCESS, TRUST_FOLD_RATIO, TRUST_RATIO, TRUST_TURNS, flight_spin
from spin.lens import centring_rotation
from spin.period import flight_period, on_track_disc


def _sparse_flight(texture, rps, axis, seed, radius_px=18.0, size=(320, 240), duration_s=0.3):
    """A simulated flight falling on its arc (by default 320x240, 0.3 s, r = 18 px; realistic sensor), its
    events on the truth track's inner disc (as the analysis takes them) and the truth."""
    rec = sim.flight(texture, rps=rps, axis=axis, radius_px=radius_px, width=size[0], height=size[1],
                     duration_s=duration_s, distractors=(), sensor="realistic", seed=seed)
    track = rec.truth_track()
    ev = rec.events
    idx, cx, cy, r = on_track_disc(ev["t"], ev["x"], ev["y"], track.t_us, track.cx, track.cy, track.r)
    columns = (ev["t"][idx], ev["x"][idx], ev["y"][idx], ev["p"][idx], cx, cy, r)
    return columns, rec.truth


def _axis_error_deg(a, b):
    return math.degrees(math.acos(np.clip(np.dot(a, b), -1.0, 1.0)))


@pytest.mark.parametrize("texture, axis", [("tennis", (0.5, -0.6, 0.62)), ("baseball", (-0.3, 0.8, 0.5))])
def test_a_sparse_ball_s_axis_comes_from_its_whole_flight(texture, axis):
    """Two seams: a window sees them from one side and its search mostly misses the axis; over the
    flight's nine turns, placed on the ball's surface at the period's speed, they give the axis
    within a few degrees (and the rate of one turn per period), trusted."""
    columns, truth = _sparse_flight(texture, 30.0, axis, seed=4)
    period_s = flight_period(*columns)[0]
    found = flight_spin(*columns, period_s, period_sigma_pct=0.1)
    assert found.trusted and found.ratio >= TRUST_RATIO and found.excess >= TRUST_EXCESS and found.fold == 1
    assert _axis_error_deg(found.axis, truth["axis"]) < 5.0
    assert found.rps == pytest.approx(30.0, rel=0.01)
    # told half the period (as a texture whose image repeats twice a turn gives it): two repeats make the
    # turn, the same answer, and the rate's sigma counts turns, twice the period's
    halved = flight_spin(*columns, period_s / 2, period_sigma_pct=0.1)
    assert halved.fold == 2 and halved.rps == pytest.approx(found.rps, rel=1e-3)
    assert halved.rps_sigma_pct == pytest.approx(0.2) and found.rps_sigma_pct == pytest.approx(0.1)


def test_a_slow_ball_s_rate_comes_from_its_three_turns_but_its_axis_is_not_trusted():
    """At 10 rps a 0.3 s flight turns three times, enough for a period (spin.period) and so for the
    whole flight's spin, which refines the period's speed (1-2 % short on this steep arc). The axis comes
    out near the truth here, but three turns pin it less than it needs to be trusted; the rate stands (the
    map tells its fold from the others)."""
    columns, truth = _sparse_flight("logo", 10.0, (0.5, -0.6, 0.62), seed=4)
    period_s = flight_period(*columns)[0]
    found = flight_spin(*columns, period_s, period_sigma_pct=0.7)
    assert found.fold == 1 and found.rps == pytest.approx(10.0, rel=0.01)
    assert _axis_error_deg(found.axis, truth["axis"]) < 5.0
    assert found.ratio >= TRUST_RATIO and found.excess >= TRUST_EXCESS
    assert found.turns == pytest.approx(3.0, abs=0.2) and not found.trusted
    assert found.fold_ratio >= TRUST_FOLD_RATIO and found.rate_trusted
    assert found.rps_sigma_pct == 0.7  # (one repeat a turn: the period's own)


def test_a_slow_ball_whose_map_misleads_is_not_trusted():
    """A soccer ball at 10 rps drifting across a 640x480 sensor, 3.5 turns in 0.4 s (the flight of held-out
    seed 3 of ``bench/spin_bench.py --flights``): an edge's polarity changes through a turn, the signed map
    cancels it at the right axis and is sharpest 18 deg away, where the map and its shuffled twin pass it;
    the flight holds too few turns to trust it. Its rate, one turn per period, stands."""
    columns, truth = _sparse_flight("soccer", 10.0, (-0.35189291, 0.01616852, 0.93590062), seed=3,
                                    radius_px=22.08, size=(640, 480), duration_s=0.4)
    period_s = flight_period(*columns)[0]
    found = flight_spin(*columns, period_s, period_sigma_pct=0.7)
    assert _axis_error_deg(found.axis, truth["axis"]) > 10.0 and found.rps == pytest.approx(10.0, rel=0.01)
    assert found.ratio >= TRUST_RATIO and found.excess >= TRUST_EXCESS  # (the map's own checks pass)
    assert found.turns < TRUST_TURNS and not found.trusted and found.fold == 1 and found.rate_trusted


def test_a_speed_the_period_does_not_allow_gives_no_trusted_spin():
    """At 13 % off the period's speed (no fold of it) the events never pile up on the seams again: no
    axis stands out and the answer is not trusted, nor its rate: no fold is sharper than the others."""
    columns, _ = _sparse_flight("tennis", 30.0, (0.5, -0.6, 0.62), seed=4)
    period_s = flight_period(*columns)[0]
    found = flight_spin(*columns, period_s * 1.13 / 1.0, period_sigma_pct=0.1)
    assert found is not None and not found.trusted and found.ratio < TRUST_RATIO
    assert found.fold_ratio < TRUST_FOLD_RATIO and not found.rate_trusted


def test_events_that_keep_their_distance_from_the_centre_are_not_a_spin():
    """A ring of events round the ball's centre (mostly ON, at random times: the shading's edge, a
    highlight) piles up on the surface about an axis along the line of sight, whatever the ball does;
    shuffling the events' turns among them leaves it as sharp, so it shows no excess and is not trusted; it is
    as sharp at every fold, so its rate is not trusted either."""
    rng = np.random.default_rng(1)
    n = 40_000
    t = np.sort(rng.integers(0, 300_000, n)).astype(np.int64)
    angle, radius = rng.uniform(0, 2 * np.pi, n), rng.uniform(12.0, 13.0, n)
    cx, cy, r = np.full(n, 100.0), np.full(n, 80.0), np.full(n, 20.0)
    found = flight_spin(t, cx + radius * np.cos(angle), cy + radius * np.sin(angle), (rng.random(n) < 0.8).astype(np.int8),
                        cx, cy, r, 1 / 30.0, period_sigma_pct=0.5)
    assert abs(found.axis[2]) > 0.99 and found.excess < 1.5 and not found.trusted
    assert found.fold_ratio < TRUST_FOLD_RATIO and not found.rate_trusted


def test_events_at_random_places_and_times_are_not_a_spin():
    """Noise on the disc: no map is sharper than the shuffled one by much (its excess is small, not
    arbitrary where both score about 1), no axis stands out, nothing is trusted (the rate neither)."""
    rng = np.random.default_rng(0)
    n = 60_000
    t = np.sort(rng.integers(0, 300_000, n)).astype(np.int64)
    angle, radius = rng.uniform(0, 2 * np.pi, n), 20.0 * np.sqrt(rng.uniform(0, 0.7, n))
    cx, cy, r = np.full(n, 100.0), np.full(n, 80.0), np.full(n, 20.0)
    found = flight_spin(t, cx + radius * np.cos(angle), cy + radius * np.sin(angle), rng.integers(0, 2, n).astype(np.int8),
                        cx, cy, r, 0.03, period_sigma_pct=0.5)
    assert found.ratio < TRUST_RATIO and found.excess < TRUST_EXCESS and not found.trusted
    assert found.fold_ratio < TRUST_FOLD_RATIO and not found.rate_trusted


def test_too_few_events_or_no_period_give_none():
    columns, _ = _sparse_flight("tennis", 30.0, (0.5, -0.6, 0.62), seed=4)
    assert flight_spin(*(c[:50] for c in columns), 1 / 30.0, period_sigma_pct=0.1) is None
    assert flight_spin(*columns, 0.0, period_sigma_pct=0.1) is None


def test_an_axis_found_about_the_line_of_sight_turns_into_the_camera_frame():
    """With a line of sight, flight_spin's axis is the one found about it turned by the rotation taking
    (0, 0, 1) to the ray (``spin.lens.centring_rotation`` transposed): along the optical axis nothing
    turns; off it, the line of sight's own direction maps to the ray, and a direction across it stays
    across it."""
    def turned(axis, ray):
        return centring_rotation(ray / np.linalg.norm(ray)).T @ axis

    assert np.allclose(turned(np.array([0.3, 0.4, np.sqrt(0.75)]), np.array([0.0, 0.0, 1.0])), [0.3, 0.4, np.sqrt(0.75)])
    ray = np.array([0.3, -0.2, 1.0])
    assert np.allclose(turned(np.array([0.0, 0.0, 1.0]), ray), ray / np.linalg.norm(ray))
    across = turned(np.array([1.0, 0.0, 0.0]), ray)
    assert abs(np.dot(across, ray)) < 1e-9 and np.linalg.norm(across) == pytest.approx(1.0)
    columns, _ = _sparse_flight("tennis", 30.0, (0.5, -0.6, 0.62), seed=4)
    period_s = flight_period(*columns)[0]
    about = flight_spin(*columns, period_s, period_sigma_pct=0.1).axis
    assert np.allclose(flight_spin(*columns, period_s, period_sigma_pct=0.1, ray=ray).axis, turned(about, ray))
