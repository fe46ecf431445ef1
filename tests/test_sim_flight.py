"""Flights, frames, sync box, distractors, noise, files on disk, dataset CLI."""

import json

import numpy as np
import pytest

import sim
from capture.events import EVENT_DTYPE, is_sorted
from sim.dataset import main as dataset_main

W, H = 240, 160


def small_flight(**kw):
    params = dict(texture="volleyball", rps=10.0, axis=(0.0, 0.0, -1.0), radius_px=14.0, width=W, height=H,
                  duration_s=0.04, distractors=(), noise_rate_hz=0.0, hot_pixels=0, seed=4)
    params.update(kw)
    return sim.flight(**params)


def ballistic(truth, t_us):
    dt = (np.asarray(t_us) - truth["t0_us"]) * 1e-6
    x = truth["start_px"][0] + truth["velocity0_px_s"][0] * dt
    y = truth["start_px"][1] + truth["velocity0_px_s"][1] * dt + 0.5 * truth["gravity_px_s2"] * dt * dt
    return x, y


@pytest.fixture(scope="module")
def clean():
    return small_flight()


def test_flight_events_follow_the_true_circle(clean):
    ev, tr = clean.events, clean.truth
    assert ev.dtype == EVENT_DTYPE and is_sorted(ev) and ev.size > 10000
    assert ev["x"].max() < W and ev["y"].max() < H
    cx, cy = ballistic(tr, ev["t"])
    d = np.hypot(ev["x"] - cx, ev["y"] - cy)
    assert d.max() <= tr["radius_px"] + 1.5
    # the ball crosses the whole sensor, left to right
    assert ev["x"].min() < 10 and ev["x"].max() > W - 10


def test_ground_truth_track_is_the_ballistic_circle(clean):
    tr = clean.truth
    track = tr["track"]
    cx, cy = ballistic(tr, track["t_us"])
    np.testing.assert_allclose(track["cx"], cx, atol=1e-6)
    np.testing.assert_allclose(track["cy"], cy, atol=1e-6)
    np.testing.assert_allclose(track["vy"], tr["velocity0_px_s"][1] + tr["gravity_px_s2"] * (track["t_us"] - tr["t0_us"]) * 1e-6, rtol=1e-6)
    assert np.all(np.diff(track["t_us"]) == 1000)
    gt = clean.truth_track()
    assert len(gt) == int(np.sum(track["visible"])) > 0
    assert np.all(gt.cx + gt.r > 0) and np.all(gt.cx - gt.r < W)
    # a volleyball at 9.81 m/s^2: gravity in px/s^2 follows the ball's pixel scale
    assert tr["gravity_px_s2"] == pytest.approx(9.81 * 14.0 / 0.105)


def test_flight_spin_sign_by_warping():
    # with the (known) translation removed, warping the ball's events at the true spin
    # is sharper than with the opposite spin or no spin
    from tests.test_sim_core import warp_sharpness

    rec = small_flight(rps=40.0, radius_px=20.0, axis=(0.3, 0.2, -1.0))
    ev, tr = rec.events, rec.truth
    t_mid = 0.5 * (ev["t"][0] + ev["t"][-1])
    win = ev[(ev["t"] > t_mid - 1000) & (ev["t"] < t_mid + 1000)]
    cx, cy = ballistic(tr, win["t"])
    cx0, cy0 = ballistic(tr, t_mid)
    moved = win.copy()
    moved["x"] = np.rint(win["x"] - (cx - cx0) + 100).astype(np.uint16)
    moved["y"] = np.rint(win["y"] - (cy - cy0) + 100).astype(np.uint16)
    c, r, w, t_ref = (cx0 + 100, cy0 + 100), tr["radius_px"], tr["omega_rad_s"], t_mid * 1e-6
    good = warp_sharpness(moved, c, r, tr["axis"], w, t_ref)
    assert good > 2.0 * warp_sharpness(moved, c, r, -tr["axis"], w, t_ref)
    assert good > 1.3 * warp_sharpness(moved, c, r, tr["axis"], 0.0, t_ref)


def test_noise_hot_pixels_and_distractors_add_events_elsewhere(clean):
    noisy = small_flight(noise_rate_hz=2.0, hot_pixels=3, hot_rate_hz=3000.0, distractors=("player", "ball"))
    ev, tr = noisy.events, noisy.truth
    assert is_sorted(ev) and ev.size > clean.events.size
    cx, cy = ballistic(tr, ev["t"])
    far = np.hypot(ev["x"] - cx, ev["y"] - cy) > tr["radius_px"] + 2
    assert far.sum() > 0.05 * ev.size
    kinds = [d["kind"] for d in tr["distractors"]]
    assert kinds == ["player", "ball"]
    flat = ev["y"].astype(int) * W + ev["x"]
    counts = np.bincount(flat, minlength=W * H)
    hot = tr["hot_pixels"].astype(int)
    assert np.all(counts[hot[:, 1] * W + hot[:, 0]] > 60)  # ~120 each in 40 ms


def test_frames_show_the_ball_where_the_truth_says(tmp_path):
    shift = np.array([[1.0, 0, 12.0], [0, 1.0, -6.0], [0, 0, 1.0]])  # frame px -> event px
    rec = small_flight(duration_s=0.05, fps=240.0, frame_to_event=shift, frame_noise_dn=0.0)
    fr = rec.truth["frames"]
    assert rec.frames.dtype == np.uint8 and rec.frames.shape[1:] == (H, W)
    np.testing.assert_allclose(np.diff(rec.frame_times_us), 1e6 / 240, atol=1)
    bg = np.median(rec.frames.astype(float), axis=0)
    hits = 0
    for img, t in zip(rec.frames, rec.frame_times_us):
        cx, cy = ballistic(rec.truth, t)
        fx, fy = cx - 12.0, cy + 6.0  # where the frame camera sees the ball
        if not (20 < fx < W - 20 and 20 < fy < H - 20):
            continue
        diff = np.abs(img - bg)
        yy, xx = np.nonzero(diff > 8)
        assert np.hypot(xx.mean() - fx, yy.mean() - fy) < 3.0
        hits += 1
    assert hits >= 4
    assert fr["exposure_s"] == pytest.approx(0.5 / 240)
    np.testing.assert_allclose(fr["frame_to_event"], shift)


def test_sync_box_triggers_match_the_led_in_frames():
    box = sim.SyncBox(period_s=0.02, pulse_s=0.008, phase_s=0.003, led_box_px=(2, 2, 8, 8))
    rec = small_flight(duration_s=0.06, fps=480.0, sync=box, frame_noise_dn=0.0)
    trig = rec.triggers
    rises = trig["t"][trig["p"] == 1]
    falls = trig["t"][trig["p"] == 0]
    np.testing.assert_array_equal(rises, [3000, 23000, 43000])
    np.testing.assert_array_equal(falls, [11000, 31000, 51000])
    led = rec.frames[:, 4, 4].astype(float)
    exp = rec.truth["frames"]["exposure_s"] * 1e6
    t = rec.frame_times_us
    on = np.zeros(t.size, bool)
    off = np.ones(t.size, bool)
    for a, b in zip(rises, falls):
        on |= (t - exp / 2 >= a) & (t + exp / 2 <= b)
        off &= (t + exp / 2 <= a) | (t - exp / 2 >= b)
    assert on.sum() >= 5 and off.sum() >= 5
    assert led[on].min() > 240 and led[off].max() < 80


def test_save_and_load_round_trip(tmp_path):
    rec = small_flight(duration_s=0.02, fps=120.0, sync=True)
    paths = rec.save(tmp_path / "rec", session=True)
    assert {"raw", "video", "truth", "session"} <= set(paths)
    back = sim.Recording.load(tmp_path / "rec")
    assert np.array_equal(back.events, rec.events)
    assert np.array_equal(back.triggers, rec.triggers)
    assert back.frames.shape == rec.frames.shape
    assert np.abs(back.frames.astype(int) - rec.frames).mean() < 4  # lossy MP4
    np.testing.assert_allclose(back.truth["axis"], rec.truth["axis"])
    np.testing.assert_array_equal(back.truth["frames"]["t_us"], rec.frame_times_us)
    from capture.session import open_session

    s = open_session(paths["session"])
    assert s.n_events == rec.events.size
    np.testing.assert_array_equal(s.frames()["t_us"], rec.frame_times_us)


def test_one_frame_recording_round_trips(tmp_path):
    rec = small_flight(duration_s=0.02, fps=120.0)
    one = sim.Recording(rec.events, rec.triggers, W, H, rec.truth, rec.frames[:1], rec.frame_times_us[:1])
    one.truth["frames"]["t_us"] = one.frame_times_us
    back = sim.Recording.load(one.save(tmp_path / "one")["truth"].parent)
    assert back.frames.shape == (1, H, W)
    np.testing.assert_array_equal(back.frame_times_us, one.frame_times_us)


def test_dataset_cli_paper_preset(tmp_path, capsys):
    assert dataset_main([str(tmp_path), "--preset", "paper", "--n", "1", "--n-events", "1500", "--seed", "2"]) == 0
    index = json.loads((tmp_path / "index.json").read_text())["sequences"]
    assert len(index) == 9
    assert sorted({(s["texture"], s["rps"]) for s in index}) == sorted(
        [("volleyball", float(r)) for r in (10, 20, 30, 50, 100, 200, 300, 500)] + [("soccer", 100.0)])
    one = sim.Recording.load(tmp_path / index[0]["name"])
    assert one.events.size == 1500 and one.width == 640 and one.height == 480
    assert one.truth["threshold"] == 0.15
    np.testing.assert_allclose(np.linalg.norm(one.truth["axis"]), 1.0)
    assert "volleyball_010rps_00" in capsys.readouterr().err  # progress lines


def test_dataset_cli_errors_are_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert dataset_main([str(blocker), "--n", "1", "--n-events", "100", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("sim.dataset: error: ") and err.count("\n") == 1
    with pytest.raises(SystemExit) as exc:
        dataset_main([str(tmp_path), "--n", "0"])
    assert exc.value.code == 2
    with pytest.raises(FileNotFoundError, match="truth.json"):
        sim.Recording.load(tmp_path)


def test_flight_rejects_bad_arguments():
    with pytest.raises(ValueError, match="distractor"):
        small_flight(distractors=("dog",))
    with pytest.raises(ValueError, match="duration_s"):
        small_flight(duration_s=0.0)


def test_hit_starts_a_new_flight_with_its_own_spin():
    hit = {"t_s": 0.02, "velocity_px_s": (-3000.0, -800.0), "rps": 30.0, "axis": (0.0, 1.0, 0.0)}
    rec = small_flight(start_px=(20.0, 80.0), velocity_px_s=(5000.0, 0.0), duration_s=0.04, hits=[hit])
    tr = rec.truth
    seg = tr["segments"]
    assert len(seg) == 2 and seg[1]["t_start_us"] == 20000
    np.testing.assert_allclose(seg[1]["axis"], [0, 1, 0])
    assert seg[1]["rps"] == pytest.approx(30.0) and seg[0]["rps"] == pytest.approx(10.0)
    np.testing.assert_allclose(seg[1]["velocity_px_s"], [-3000.0, -800.0])
    track = tr["track"]
    assert set(np.unique(track["flight"])) == {0, 1}
    assert np.all(track["flight"][track["t_us"] >= 20000] == 1)
    # the centre is continuous through the hit, then flies back left and up
    i = np.searchsorted(track["t_us"], 20000)
    assert abs(track["cx"][i] - track["cx"][i - 1]) < 6
    assert track["cx"][-1] < track["cx"][i] and track["vy"][i] == pytest.approx(-800.0)
    gt = rec.truth_track()
    assert list(gt.flight_ids()) == [0, 1]
    # events stay on the true (piecewise) circle
    ev = rec.events[rec.events["t"] <= track["t_us"][-1]]
    cx = np.interp(ev["t"], track["t_us"], track["cx"])
    cy = np.interp(ev["t"], track["t_us"], track["cy"])
    assert np.max(np.hypot(ev["x"] - cx, ev["y"] - cy)) < tr["radius_px"] + 2.5


def test_flight_is_deterministic_for_a_seed():
    kw = dict(duration_s=0.01, fps=240.0, noise_rate_hz=5.0, hot_pixels=2, distractors=("player",), sync=True)
    a, b, c = small_flight(seed=11, **kw), small_flight(seed=11, **kw), small_flight(seed=12, **kw)
    assert np.array_equal(a.events, b.events) and np.array_equal(a.frames, b.frames)
    assert np.array_equal(a.triggers, b.triggers)
    assert not np.array_equal(a.events, c.events)


def test_a_sync_box_with_jitter_blinks_at_pseudo_random_phases():
    box = sim.SyncBox(period_s=0.05, pulse_s=0.013, phase_s=0.007, jitter_s=0.03, seed=3)
    rise, fall = box.edges_s(0.0, 2.0)
    assert len(rise) == len(fall) == 40 and np.allclose(fall - rise, 0.013)
    phase = (rise - 0.007) % 0.05
    assert phase.min() >= 0 and phase.max() < 0.03 and np.std(phase) > 0.005  # not one phase
    # the LED is on exactly between its edges
    a = np.r_[rise - 1e-4, rise + 1e-4, fall - 1e-4, fall + 1e-4]
    np.testing.assert_allclose(box.on_fraction(a, a + 2e-5), np.r_[np.zeros(40), np.ones(40), np.ones(40), np.zeros(40)])
    assert np.array_equal(box.edges_s(0.0, 2.0)[0], rise)  # fixed by the seed
    assert not np.allclose(sim.SyncBox(period_s=0.05, pulse_s=0.013, phase_s=0.007, jitter_s=0.03, seed=4).edges_s(0, 2)[0], rise)
    with pytest.raises(ValueError, match="jitter_s"):
        sim.SyncBox(period_s=0.05, pulse_s=0.013, jitter_s=0.04)


def test_auto_exposure_frames_end_on_the_frame_cadence():
    rec = sim.flight(width=160, height=120, radius_px=10, duration_s=0.1, fps=240.0,
                     exposure_s=lambda t: (0.3 + 0.6 * t / 0.1) / 240.0, seed=1)
    fr = rec.truth["frames"]
    e = np.asarray(fr["exposure_s"])
    ends_us = fr["t_us"] + e / 2 * 1e6
    assert len(e) == len(fr["t_us"]) and np.ptp(e) > 0.4 / 240
    np.testing.assert_allclose(np.diff(ends_us), 1e6 / 240, atol=1.0)  # ends on the cadence (µs rounding)
    with pytest.raises(ValueError, match="one exposure per frame"):
        sim.flight(width=160, height=120, duration_s=0.05, fps=240.0, exposure_s=lambda t: np.full_like(t, 0.01))
