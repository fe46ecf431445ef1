"""Simulated DVS pixel (sim.esim.SensorModel): bandwidth, leak, shot noise, refractory period, presets."""

import hashlib
import json
from dataclasses import replace

import numpy as np
import pytest

import sim
from sim.esim import SENSOR_PRESETS, SensorModel, SensorState, get_sensor_model, simulate
from sim.recording import jsonable
from sim.scene import LOG_EPS, Camera, Scene

REALISTIC = SENSOR_PRESETS["realistic"]
QUIET = SensorModel(threshold=0.2, mismatch_sigma=0.0, cutoff_hz=REALISTIC.cutoff_hz,
                    cutoff_max_hz=REALISTIC.cutoff_max_hz)
"""The realistic bandwidth without noise, mismatch, dead time or readout delay."""


class Flash:
    """A static square patch whose brightness steps from ``i0`` to ``i1`` at ``t_step_s`` (within 1 µs)."""

    def __init__(self, x0, y0, size, i0, i1, t_step_s):
        self.x0, self.y0, self.size, self.i0, self.i1, self.t_step_s = x0, y0, size, i0, i1, t_step_s

    def max_speed_px_s(self, cam, t_s):
        return 0.0

    def bbox(self, cam, t0_s, t1_s):
        return self.x0 - 0.5, self.y0 - 0.5, self.x0 + self.size - 0.5, self.y0 + self.size - 0.5

    def render(self, cam, u, v, t_s, light, ambient):
        t = np.atleast_1d(np.asarray(t_s, float))[:, None]
        inside = (u >= self.x0) & (u < self.x0 + self.size) & (v >= self.y0) & (v < self.y0 + self.size)
        a = np.clip((t - self.t_step_s) / 1e-6, 0.0, 1.0)
        I = np.broadcast_to(self.i0 + a * (self.i1 - self.i0), (t.shape[0], u.size))
        return I, np.broadcast_to(inside.astype(float), I.shape)


def flash_events(model, i1, step_log=0.9, size=4, seed=0):
    """Events of a ``size`` x ``size`` patch stepping up by ``step_log`` (log units) to brightness ``i1`` at 1 ms."""
    i0 = (i1 + LOG_EPS) * np.exp(-step_log) - LOG_EPS
    scene = Scene(Camera(10, 10), [Flash(2, 2, size, i0, i1, 1e-3)], background_level=0.3)
    return simulate(scene, SensorState.new(10, 10, np.random.default_rng(seed), model), 0.0, 3e-3, max_step_s=2e-6)


# (n_events, sha256 of the events' bytes) of the generator before the sensor model was added
# (commit 7dcf99b); the ideal preset must keep producing exactly these events
GOLDEN = [
    (dict(texture="volleyball", rps=80, axis=(1, 1, 0.3), radius_px=30, width=96, height=80, n_events=8000, seed=11),
     8000, "d0690ffa398ea78714ac96b390cd8b191979119e9d3538cf1d673fcf5093c2a8"),
    (dict(texture="soccer", rps=40, axis=(0, 1, 0), radius_px=25, width=90, height=70, n_events=5000, seed=2,
          velocity_px_s=(800, -300), refractory_us=20, noise_rate_hz=3.0, hot_pixels=2, background="court"),
     5000, "c2417a532321cefda708a617a1a8744c8848c9093db3e05917bdac0f33a00a52"),
]


@pytest.mark.parametrize("kw,n,digest", GOLDEN)
def test_ideal_preset_reproduces_the_plain_generator(kw, n, digest):
    ev, tr = sim.spinning_ball(**kw)
    assert ev.size == n and hashlib.sha256(ev.tobytes()).hexdigest() == digest
    ev2, tr2 = sim.spinning_ball(sensor="ideal", **kw)
    ev3, _ = sim.spinning_ball(sensor=SensorModel(), **kw)
    assert np.array_equal(ev, ev2) and np.array_equal(ev, ev3)
    assert tr2["sensor"]["preset"] == "ideal" and tr2["sensor"]["cutoff_hz"] is None


def test_unknown_sensor_names_the_choices():
    with pytest.raises(ValueError, match=r"'bogus'.*\['ideal', 'realistic'\]"):
        get_sensor_model("bogus")
    with pytest.raises(ValueError, match="realistic"):
        sim.spinning_ball(n_events=10, sensor="dvs")
    with pytest.raises(ValueError, match="realistic"):
        sim.flight(sensor="dvs")
    with pytest.raises(ValueError, match="cutoff_max_hz"):
        SensorModel(cutoff_max_hz=1000.0)
    with pytest.raises(ValueError, match="leak_rate_hz"):
        SensorModel(leak_rate_hz=-1.0)


def test_realistic_is_deterministic_per_seed_and_recorded_in_the_truth():
    kw = dict(rps=200, axis=(1, 0, 1), radius_px=25, width=80, height=60, n_events=4000, sensor="realistic")
    a, ta = sim.spinning_ball("soccer", seed=4, **kw)
    b, _ = sim.spinning_ball("soccer", seed=4, **kw)
    c, _ = sim.spinning_ball("soccer", seed=5, **kw)
    assert a.size == 4000 and np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.all(np.diff(a["t"]) >= 0)
    assert ta["sensor"] == {"preset": "realistic", **vars(REALISTIC)}
    assert ta["threshold"] == REALISTIC.threshold
    json.dumps(jsonable(ta))
    _, tb = sim.spinning_ball("soccer", seed=4, **dict(kw, sensor=replace(REALISTIC, leak_rate_hz=0.0)),
                              threshold=0.25)
    assert tb["sensor"]["preset"] is None and tb["sensor"]["threshold"] == 0.25 and tb["sensor"]["leak_rate_hz"] == 0


def test_step_response_follows_the_first_order_lowpass_and_dim_pixels_lag_more():
    # a step of 0.9 log units crosses 0.2, 0.4, 0.6, 0.8 at tau * ln(0.9 / (0.9 - 0.2 k))
    expected = np.log(0.9 / (0.9 - 0.2 * np.arange(1, 5)))
    spans = []
    for i1 in (0.8, 0.2, 0.05):
        ev = flash_events(QUIET, i1)
        assert ev.size == 16 * 4 and np.all(ev["p"] == 1)
        tau_us = float(QUIET.tau_s_at(i1)) * 1e6
        for x, y in ((2, 2), (5, 5)):
            t = ev["t"][(ev["x"] == x) & (ev["y"] == y)] - 1000
            np.testing.assert_allclose(t, tau_us * expected, atol=2.0)
        spans.append(tau_us * (expected[-1] - expected[0]))
    assert spans[0] < 0.5 * spans[1] < 0.25 * spans[2]  # the burst spreads out as the pixel gets dimmer
    assert 30 < QUIET.tau_s_at(1.0) * 1e6 < 60 and 150 < QUIET.tau_s_at(0.1) * 1e6 < 400
    # without a bandwidth limit the four events come within the 1 µs of the step
    ideal = flash_events(replace(QUIET, cutoff_hz=None, cutoff_max_hz=None), 0.05)
    assert ideal.size == 64 and np.ptp(ideal["t"]) <= 1


def test_readout_delay_has_the_set_mean():
    base = flash_events(QUIET, 0.5, size=8)
    late = flash_events(replace(QUIET, latency_jitter_us=5.0), 0.5, size=8, seed=1)
    assert base.size == late.size == 256  # the same crossings, each one timestamped later
    assert 4.0 < late["t"].mean() - base["t"].mean() < 6.0
    assert np.all(late["t"] >= base["t"])  # sorted: the k-th timestamp can only move later


def static_scene(level, width=100, height=80):
    return Scene(Camera(width, height), [], background_level=level)


def test_leak_events_on_a_static_scene_come_at_the_set_rate_with_jittered_intervals():
    model = SensorModel(threshold=0.2, leak_rate_hz=2.0, leak_jitter=0.1, cutoff_hz=REALISTIC.cutoff_hz,
                        cutoff_max_hz=REALISTIC.cutoff_max_hz)
    state = SensorState.new(100, 80, np.random.default_rng(0), model)
    # in two calls: the second continues from the state the first left (leak phase included)
    ev = np.concatenate([simulate(static_scene(0.3), state, 0.0, 0.7),
                         simulate(static_scene(0.3), state, 0.7, 2.0, init=False)])
    expected = 2.0 * 8000 * 2.0
    assert abs(ev.size - expected) < 4 * np.sqrt(expected)
    assert np.all(ev["p"] == 1)
    flat = ev["y"].astype(np.int64) * 100 + ev["x"]
    order = np.lexsort((ev["t"], flat))
    same = np.diff(flat[order]) == 0
    gaps = np.diff(ev["t"][order])[same] * 1e-6
    assert gaps.mean() == pytest.approx(0.5, rel=0.02)  # period 1 / (2 Hz)
    assert gaps.std() / gaps.mean() == pytest.approx(0.1, rel=0.15)  # 10 % jitter
    # the per-pixel rates spread log-normally around the set mean
    state = SensorState.new(400, 400, np.random.default_rng(1), SensorModel(leak_rate_hz=1.0, leak_spread_decades=0.2))
    rate = state.leak_drift / state.c_on
    assert rate.mean() == pytest.approx(1.0, rel=0.01)
    assert np.log10(rate).std() == pytest.approx(0.2, rel=0.03)


@pytest.mark.parametrize("level", [0.0, 1.0])
def test_shot_noise_rate_matches_and_is_higher_in_the_dark(level):
    model = SensorModel(threshold=0.2, mismatch_sigma=0.0, shot_noise_rate_hz=4.0, latency_jitter_us=2.0)
    ev = simulate(static_scene(level), SensorState.new(100, 80, np.random.default_rng(2), model), 0.0, 1.0)
    rate = float(model.shot_rate_hz_at(level))
    expected = rate * 8000 * 1.0
    assert abs(ev.size - expected) < 4 * np.sqrt(expected)
    assert abs(ev["p"].sum() - expected / 2) < 4 * np.sqrt(expected / 4)
    assert rate == pytest.approx(4.0 * (0.25 if level == 1.0 else 1 - 0.75 * 0.078 / 1.078))


def events_per_pixel(ev, width):
    flat = ev["y"].astype(np.int64) * width + ev["x"]
    order = np.lexsort((ev["t"], flat))
    return flat[order], ev["t"][order]


def test_refractory_period_is_respected():
    kw = dict(rps=300, axis=(1, 1, 0), radius_px=30, width=80, height=70, n_events=None, duration_s=1.5e-3, seed=3)
    dead = replace(REALISTIC, refractory_us=50.0)
    for model, must_hold in ((dead, True), (replace(dead, refractory_us=0.0), False)):
        ev, _ = sim.spinning_ball("volleyball", sensor=model, **kw)
        flat, t = events_per_pixel(ev, 80)
        gaps = np.diff(t)[np.diff(flat) == 0]
        assert (gaps.min() >= 49) == must_hold  # timestamps are floored to µs
    assert gaps.size > 1000


def test_moving_ball_leaves_a_trail_only_with_limited_bandwidth():
    kw = dict(rps=50, axis=(0, 1, 0), radius_px=20, center=(30.0, 40.0), velocity_px_s=(40000.0, 0.0),
              width=160, height=80, n_events=None, duration_s=2e-3, seed=1)
    quiet = replace(REALISTIC, leak_rate_hz=0.0, shot_noise_rate_hz=0.0)
    behind = {}
    for name, model in (("ideal", SENSOR_PRESETS["ideal"]), ("realistic", quiet)):
        ev, tr = sim.spinning_ball("soccer", sensor=model, **kw)
        cx = 30.0 + 40000.0 * ev["t"] * 1e-6
        d = np.hypot(ev["x"] - cx, ev["y"] - 40.0)
        out = d > 20 + 1.5
        behind[name] = np.mean(out & (ev["x"] < cx))
        assert np.mean(out & (ev["x"] > cx)) < 0.005  # nothing ahead of the ball
    assert behind["ideal"] < 0.005 and behind["realistic"] > 0.05


def test_realistic_ball_has_fewer_events_and_noise_everywhere():
    kw = dict(rps=300, axis=(1, 1, 0.3), radius_px=30, width=160, height=120, n_events=None, duration_s=1e-3, seed=0)
    ideal, tr = sim.spinning_ball("volleyball", **kw)
    real, _ = sim.spinning_ball("volleyball", sensor="realistic", **kw)
    assert 0.1 * ideal.size < real.size < 0.6 * ideal.size
    d = np.hypot(real["x"] - tr["center"][0], real["y"] - tr["center"][1])
    assert np.count_nonzero(d > 35) > 0  # leak and shot noise away from the ball
    assert real["t"].min() >= 0 and np.all(np.diff(real["t"]) >= 0)


def test_flight_takes_a_sensor():
    kw = dict(width=200, height=120, radius_px=12, duration_s=0.02, distractors=(), noise_rate_hz=0.0,
              hot_pixels=0, seed=3)
    ideal = sim.flight(**kw)
    real = sim.flight(sensor="realistic", **kw)
    assert real.truth["sensor"]["preset"] == "realistic" and ideal.truth["sensor"]["preset"] == "ideal"
    assert real.events.size < ideal.events.size and np.all(np.diff(real.events["t"]) >= 0)
    assert np.array_equal(sim.flight(threshold=0.15, mismatch_sigma=0.03, **kw).events, ideal.events)
