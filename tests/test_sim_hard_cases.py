"""The simulator's hard cases for detection: plain ball, swinging arm, looming ball, flickering light."""

import numpy as np
import pytest

import sim
from sim.esim import flicker_events

W, H = 240, 160


def _plain(rps, velocity, texture="plain"):
    return sim.flight(texture=texture, rps=rps, axis=(0.2, 1.0, 0.1), radius_px=15.0, width=W, height=H,
                      duration_s=0.02, start_px=(60.0, 80.0), velocity_px_s=velocity, gravity_px_s2=0.0,
                      background="plain", distractors=(), noise_rate_hz=0.0, hot_pixels=0, seed=1)


def test_plain_ball_fires_from_its_rim_and_shading_never_from_its_spin():
    moving = _plain(0.0, (2000.0, 0.0))
    assert len(moving.events) > 500
    # spin changes nothing on a ball of one colour: as many events spinning or not (the render
    # steps differ, so the times do too)
    assert len(_plain(50.0, (2000.0, 0.0)).events) == pytest.approx(len(moving.events), rel=0.03)
    assert len(_plain(50.0, (0.0, 0.0)).events) == 0  # spinning in place: silent
    # a textured ball under the same motion fires several times more
    assert len(_plain(50.0, (2000.0, 0.0), texture="volleyball").events) > 3 * len(moving.events)
    cx = 60.0 + 2000.0 * moving.events["t"] * 1e-6
    d = np.hypot(moving.events["x"] - cx, moving.events["y"] - 80.0)
    assert np.all(d < 15.0 + 2.0)


def test_arm_swings_past_the_ball_a_few_pixels_away():
    rec = sim.flight(texture="volleyball", rps=5.0, radius_px=12.0, width=W, height=H, duration_s=0.04,
                     start_px=(40.0, 80.0), velocity_px_s=(1500.0, 0.0), gravity_px_s2=0.0, background="plain",
                     distractors=("arm",), noise_rate_hz=0.0, hot_pixels=0, seed=2)
    (arm,) = rec.truth["distractors"]
    assert arm["kind"] == "arm"
    scale = 12.0 / sim.balls.BALL_RADIUS_M["volleyball"]
    assert arm["length_px"] == pytest.approx(0.6 * scale) and arm["width_px"] == pytest.approx(0.09 * scale)
    # at mid-flight the arm points up and its edge is 2-6 px from the ball's rim
    tt = rec.truth_track()
    i = np.searchsorted(tt.t_us, 20_000)
    gap = abs(arm["pivot_px"][0] - tt.cx[i]) - tt.r[i] - 0.5 * arm["width_px"]
    assert 2.0 <= gap <= 6.0
    # and it fires: events beyond the ball, along the arm
    ev = rec.events
    cx = np.interp(ev["t"], tt.t_us, tt.cx)
    far = np.hypot(ev["x"] - cx, ev["y"] - 80.0) > 12.0 + 3
    assert far.sum() > 200
    assert np.all(np.abs(ev["x"][far] - arm["pivot_px"][0]) < 0.5 * arm["width_px"] + arm["length_px"] * 0.5)



@pytest.mark.parametrize("kind", ["racket", "paddle"])
def test_racket_head_is_swung_against_the_ball_and_passes_it_a_few_pixels_away(kind):
    rec = sim.flight(texture="tennis" if kind == "racket" else "tabletennis", rps=5.0, radius_px=8.0, width=W,
                     height=H, duration_s=0.03, start_px=(40.0, 80.0), velocity_px_s=(3000.0, 0.0),
                     gravity_px_s2=0.0, background="plain", distractors=(kind,), noise_rate_hz=0.0, hot_pixels=0,
                     seed=3)
    (rk,) = rec.truth["distractors"]
    assert rk["kind"] == kind
    scale = 8.0 / sim.balls.BALL_RADIUS_M["tennis" if kind == "racket" else "tabletennis"]
    head = (0.16, 0.125) if kind == "racket" else (0.08, 0.075)  # m: a tennis racket's, a bat's
    assert (rk["head_a_px"], rk["head_b_px"]) == pytest.approx((head[0] * scale, head[1] * scale))
    racket = sim.scene.Racket(**{k: (tuple(v) if k == "pivot_px" else v) for k, v in rk.items()})
    tt = rec.truth_track()
    i = np.searchsorted(tt.t_us, 15_000)  # mid-flight: the head beside the ball, its rim 2-6 px from the ball's
    hx, hy = racket.head_center(15_000e-6)
    assert hy == pytest.approx(tt.cy[i]) and 2.0 <= abs(hx - tt.cx[i]) - tt.r[i] - rk["head_b_px"] <= 6.0
    # swung to meet the ball: the head moves against it
    assert (racket.head_center(16_000e-6)[0] - hx) * tt.vx[i] < 0
    # and it fires, along its handle too (below the head, far from the ball)
    ev = rec.events
    mid = (ev["t"] > 14_000) & (ev["t"] < 16_000)
    handle = mid & (np.abs(ev["x"] - hx) < 10) & (ev["y"] > hy + rk["head_a_px"] + 5) & \
        (ev["y"] < hy + rk["head_a_px"] + rk["handle_px"] - 5)
    assert handle.sum() > 20
    with pytest.raises(ValueError, match="kind"):
        sim.scene.Racket(kind="bat")

def test_looming_ball_grows_as_its_distance_shrinks():
    f_px, r0 = 300.0, 12.0
    z0 = sim.balls.BALL_RADIUS_M["volleyball"] * f_px / r0
    rec = sim.flight(texture="volleyball", rps=5.0, radius_px=r0, width=W, height=H, duration_s=0.05,
                     start_px=(W / 2, H / 2), velocity_px_s=(0.0, 0.0), gravity_px_s2=0.0, projection="pinhole",
                     focal_px=f_px, depth_velocity_m_s=-0.5 * z0 / 0.05, background="plain", distractors=(),
                     noise_rate_hz=0.0, hot_pixels=0, seed=3)
    r = rec.truth["track"]["r"]
    assert r[0] == pytest.approx(r0, rel=1e-6)
    assert r[-1] == pytest.approx(2 * r0, rel=0.03)  # half the distance: twice the radius
    assert np.all(np.diff(r) > 0)
    # the rim's events follow the growing circle
    ev = rec.events
    rr = np.interp(ev["t"], rec.truth["track"]["t_us"], r)
    d = np.hypot(ev["x"] - (W - 1) / 2, ev["y"] - (H - 1) / 2)
    assert np.mean(d < rr + 2.0) > 0.95 and np.mean(d > rr - 3.0) > 0.3
    with pytest.raises(ValueError, match="pinhole"):
        sim.flight(radius_px=10.0, width=W, height=H, duration_s=0.01, depth_velocity_m_s=-1.0)


def test_flicker_fires_on_at_the_rise_off_at_the_fall_once_per_period():
    rng = np.random.default_rng(4)
    ev = flicker_events(40, 30, 0, 100_000, rng, freq_hz=100.0, depth=0.2, threshold=0.15, mismatch_sigma=0.0,
                        latency_us=0.0)
    assert len(ev) > 0 and np.all(np.diff(ev["t"]) >= 0)
    phase = 2 * np.pi * 100.0 * ev["t"] * 1e-6
    rising = np.cos(phase) >= -0.05  # d/dt sin >= 0 (one microsecond of rounding allowed)
    on = ev["p"] == 1
    assert np.all(rising[on]) and np.all(~rising[~on] | (np.abs(np.cos(phase[~on])) < 0.05))
    # every pixel fires at the same phases each period: ON times of a pixel repeat every 10 ms
    pix = ev["y"].astype(int) * 40 + ev["x"]
    k = np.flatnonzero(on & (pix == pix[on][0]))
    assert len(k) >= 9 and np.allclose(np.diff(ev["t"][k][::len(k) // len(np.unique(ev['t'][k] // 10_000))]), 10_000,
                                         atol=1)
    # ON and OFF balance; a swing below the threshold fires nothing; the box limits the lit area
    assert abs(on.sum() - (~on).sum()) <= 40 * 30
    assert len(flicker_events(40, 30, 0, 100_000, rng, depth=0.05, threshold=0.15, mismatch_sigma=0.0)) == 0
    boxed = flicker_events(40, 30, 0, 50_000, rng, depth=0.2, box=(10, 5, 20, 15))
    assert boxed["x"].min() >= 10 and boxed["x"].max() < 20 and boxed["y"].min() >= 5 and boxed["y"].max() < 15
    deeper = flicker_events(40, 30, 0, 100_000, rng, freq_hz=100.0, depth=0.5, threshold=0.15)
    assert len(deeper) > 2.5 * len(ev)
    with pytest.raises(ValueError, match="depth"):
        flicker_events(4, 4, 0, 1000, rng, depth=1.5)


def test_flight_with_flicker_records_it_in_the_truth():
    rec = sim.flight(radius_px=10.0, width=W, height=H, duration_s=0.03, distractors=(), noise_rate_hz=0.0,
                     hot_pixels=0, flicker_hz=120.0, flicker_depth=0.2, flicker_box=(0, 0, 60, 40), seed=5)
    assert rec.truth["flicker"] == {"freq_hz": 120.0, "depth": 0.2, "box": [0, 0, 60, 40]}
    box = (rec.events["x"] < 60) & (rec.events["y"] < 40)
    assert box.sum() >= 2 * 60 * 40 * 3  # every lit pixel fires ON and OFF in each of the 3.6 periods
