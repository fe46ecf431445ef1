"""Tracking on simulated (ESIM-rendered) balls: accuracy against the simulator's truth."""

import numpy as np
import pytest

import sim
from capture.events import Track
from detect import BallTracker, track_ball
from sim.esim import noise_events

W, H = 480, 320


def _truth_xy(truth, t_us):
    dt = (np.asarray(t_us) - truth["t_first_us"]) * 1e-6
    c0, v = np.asarray(truth["center"]), np.asarray(truth["velocity_px_s"])
    return c0[0] + v[0] * dt, c0[1] + v[1] * dt


@pytest.fixture(scope="module")
def spinning_flight():
    return sim.spinning_ball(radius_px=14, rps=40.0, axis=(0.3, 1.0, 0.2), center=(30.0, 200.0),
                             velocity_px_s=(4000.0, -800.0), width=W, height=H, n_events=None,
                             duration_s=0.08, background="court", noise_rate_hz=1.0, hot_pixels=15, seed=3)


@pytest.mark.parametrize("rps", [40.0, 0.0])
def test_tracks_a_simulated_ball_within_tolerance(rps, spinning_flight):
    if rps:
        ev, truth = spinning_flight
    else:  # translation only: events mostly at the rim
        ev, truth = sim.spinning_ball(radius_px=20, rps=0.0, center=(40.0, 100.0), velocity_px_s=(5000.0, 1500.0),
                                      width=W, height=H, n_events=None, duration_s=0.06, background="court",
                                      noise_rate_hz=1.0, hot_pixels=15, seed=4)
    tr = track_ball(ev, width=W, height=H)
    assert len(tr.flight_ids()) == 1
    span_us = ev["t"][-1] - ev["t"][0]
    assert len(tr) >= 0.9 * span_us / 2000  # a row for (nearly) every 2 ms slice
    ex, ey = _truth_xy(truth, tr.t_us)
    err = np.hypot(tr.cx - ex, tr.cy - ey)
    assert np.median(err) < 0.5 and np.percentile(err, 95) < 1.0
    assert np.median(np.abs(tr.r - truth["radius_px"])) < 0.7
    v = np.asarray(truth["velocity_px_s"])
    verr = np.hypot(tr.vx - v[0], tr.vy - v[1]) / np.hypot(*v)
    assert np.median(verr) < 0.02


def test_streaming_matches_batch_on_simulated_ball(spinning_flight):
    ev, _ = spinning_flight
    batch = track_ball(ev, width=W, height=H)
    trk = BallTracker(W, H)
    rng = np.random.default_rng(0)
    cuts = np.sort(rng.integers(0, len(ev), 25))
    t_live = np.concatenate([trk.update(chunk).t_us for chunk in np.split(ev, cuts)])
    live = trk.finish()
    # rows come out as soon as their 20 ms block is complete; only the last block waits for finish()
    assert len(t_live) >= len(live) - trk.block_us // trk.slice_us
    assert np.isin(t_live, live.t_us).all()
    np.testing.assert_array_equal(live.t_us, batch.t_us)
    np.testing.assert_allclose(live.cx, batch.cx, atol=1e-6)
    np.testing.assert_allclose(live.vy, batch.vy, atol=1e-6)


def test_final_rows_stream_out_during_the_flight_and_never_change(spinning_flight):
    ev, _ = spinning_flight
    trk = BallTracker(W, H, smooth_lag_us=20_000)
    parts, during_flight = [], 0
    for chunk in np.array_split(ev, 30):
        trk.update(chunk)
        parts.append(trk.take_final())
        during_flight += len(parts[-1]) if trk.active_flights else 0
    whole = trk.finish()
    parts.append(trk.take_final())
    assert during_flight >= len(whole) // 5  # rows become final while the flight goes on
    streamed = {k: np.concatenate([p.columns()[k] for p in parts]) for k in whole.columns()}
    for name, col in whole.columns().items():
        np.testing.assert_array_equal(streamed[name], col, err_msg=name)  # final means unchanged
    # a 20 ms lag already gives nearly the rows of smoothing the whole flight at once
    ref = track_ball(ev, width=W, height=H, smooth_lag_us=10 ** 9)
    np.testing.assert_array_equal(whole.t_us, ref.t_us)
    assert np.max(np.hypot(whole.cx - ref.cx, whole.cy - ref.cy)) < 0.1
    assert np.max(np.hypot(whole.vx - ref.vx, whole.vy - ref.vy)) < 0.01 * np.hypot(ref.vx, ref.vy).min()
    assert np.max(np.abs(whole.cx - ref.cx)) > 0  # and it is a different (fixed-lag) smoother


def test_noise_and_hot_pixels_alone_give_an_empty_track():
    ev, _ = noise_events(W, H, 0, 200_000, np.random.default_rng(5), rate_hz_per_px=5.0, hot_pixels=40)
    tr = track_ball(ev, width=W, height=H)
    assert len(tr) == 0


def _scene_events(objects, duration_s, seed):
    from sim.esim import SensorState, merge, simulate
    from sim.scene import Camera, Scene, court_background

    rng = np.random.default_rng(seed)
    cam = Camera(W, H)
    scene = Scene(cam, objects(cam, rng), background=court_background(W, H, rng))
    ev = simulate(scene, SensorState.new(W, H, rng), 0.0, duration_s)
    noise, _ = noise_events(W, H, 0, int(duration_s * 1e6), rng, rate_hz_per_px=1.0, hot_pixels=15)
    return cam, scene, merge(ev, noise)


def _player():
    from sim.scene import Player

    return Player(x0=330.0, y0=310.0, vx=-400.0, height_px=220.0)


def test_ignores_a_player_like_distractor():
    from sim.balls import make_ball
    from sim.rotation import random_rotation

    def objects(cam, rng):
        ball = make_ball(cam, texture="volleyball", radius_px=12, center_px=(20.0, 90.0),
                         velocity_px_s=(5000.0, 1200.0), accel_px_s2=(0.0, 3000.0), axis=(0, 1, 0),
                         omega_rad_s=250.0, R0=random_rotation(rng))
        return [_player(), ball]

    cam, scene, ev = _scene_events(objects, 0.06, 6)
    tr = track_ball(ev, width=W, height=H)
    assert len(tr.flight_ids()) == 1 and len(tr) >= 25
    truth = scene.objects[1].circle(cam, tr.t_us * 1e-6)
    err = np.hypot(tr.cx - truth[:, 0], tr.cy - truth[:, 1])
    assert np.median(err) < 0.5 and err.max() < 1.5

    _, _, ev_player = _scene_events(lambda cam, rng: [_player()], 0.06, 7)
    assert len(track_ball(ev_player, width=W, height=H)) == 0


def _flight_truth(rec, t_us):
    tt = rec.truth_track(visible_only=False)
    return [np.interp(t_us, tt.t_us, getattr(tt, c)) for c in ("cx", "cy", "r", "vx", "vy")]


def test_ball_leaving_and_reentering_gives_two_flights(two_crossings):
    from sim.esim import merge

    # first pass: enters left, leaves right within 40 ms; second: re-enters 30 ms later
    a, b = two_crossings
    ev = merge(a.events, b.events)
    tr = track_ball(ev, width=W, height=H)
    ids = tr.flight_ids()
    assert len(ids) == 2
    for fid, rec in zip(ids, (a, b)):
        part = tr.select(tr.flight == fid)
        assert rec.truth["t0_us"] <= part.t_us.min() and part.t_us.max() <= rec.truth["t0_us"] + 40_000
        cx, cy, r, vx, vy = _flight_truth(rec, part.t_us)
        inside = (cx - r >= 0) & (cx + r <= W - 1)
        assert inside.sum() >= 8
        err = np.hypot(part.cx - cx, part.cy - cy)[inside]
        assert np.median(err) < 0.5 and err.max() < 1.5
        # every 2 ms slice with the ball fully on the sensor has a row
        assert inside.sum() >= np.sum(np.arange(rec.truth["t0_us"] + 1000, rec.truth["t0_us"] + 40_000, 2000)
                                      <= part.t_us.max()) - 6


def _follows(tr, rec):
    """Rows of the flight of ``tr`` that follows ``rec``'s ball (the one nearest to it at its first
    row), and their centre error against the truth where the ball is fully on the sensor (px)."""
    def error(part):
        cx, cy, r, _, _ = _flight_truth(rec, part.t_us)
        inside = (cx - r >= 0) & (cx + r <= W - 1) & (cy - r >= 0) & (cy + r <= H - 1)
        return np.hypot(part.cx - cx, part.cy - cy)[inside]

    parts = [tr.select(tr.flight == fid) for fid in tr.flight_ids()]
    part = min(parts, key=lambda p: error(p)[0] if len(error(p)) else np.inf)
    return part, error(part)


def test_two_balls_in_view_at_once_are_tracked_as_two_flights(two_balls_at_once):
    from sim.esim import merge

    a, b = two_balls_at_once  # crossing the sensor in opposite directions during the same 40 ms
    tr = track_ball(merge(a.events, b.events), width=W, height=H)
    assert len(tr.flight_ids()) == 2
    assert np.all(np.diff(tr.t_us) >= 0)  # one track sorted by time: the two flights' rows interleave
    (pa, ea), (pb, eb) = _follows(tr, a), _follows(tr, b)
    assert pa.flight[0] != pb.flight[0]
    for part, err, rec in ((pa, ea, a), (pb, eb, b)):
        assert len(err) >= 14  # a row for nearly every 2 ms slice with the ball on the sensor
        assert np.median(err) < 0.5 and err.max() < 1.5
        assert np.median(np.abs(part.r - rec.truth["radius_px"])) < 0.7
    assert min(pa.t_us[-1], pb.t_us[-1]) - max(pa.t_us[0], pb.t_us[0]) >= 30_000  # tracked at the same time


def test_a_fast_ball_coming_in_is_tracked_from_its_first_detection():
    """A 30 m/s ball (r 80 px, 22,000 px/s) coming in over the sensor's left border: its first
    detection, 0.9 r inside, has a wrong centroid velocity (its visible part grows); the detection
    after it continues it all the same, so the track has the ball before it is fully in view (it
    started a slice later, after the ball was fully in, before)."""
    rec = sim.flight("volleyball", rps=40.0, axis=(0.3, 1.0, 0.2), radius_px=80.0, width=640, height=480,
                     duration_s=0.01, start_px=(-40.0, 240.0), velocity_px_s=(22000.0, 0.0), gravity_px_s2=0.0,
                     distractors=(), noise_rate_hz=1.0, hot_pixels=0, seed=1)
    tr = track_ball(rec.events, width=640, height=480)
    truth = rec.truth_track(visible_only=False)
    assert len(tr.flight_ids()) == 1
    assert tr.t_us[0] < truth.t_us[np.argmax(truth.cx - truth.r >= 0)]  # before the ball is fully in
    cx, cy, r, _, _ = _flight_truth(rec, tr.t_us)
    assert np.max(np.hypot(tr.cx - cx, tr.cy - cy)) < 0.25 * 80.0
    assert np.median(np.hypot(tr.cx - cx, tr.cy - cy)) < 1.0


def test_a_player_s_head_is_no_second_ball():
    """While the ball is tracked, the search for another one does not take the head of a player
    walking in view (a circle on a third of its sides) for one."""
    rec = sim.rally(seed=3, rps=30.0, axis=(0.0, 0.0, -1.0), duration_s=0.15, fps=None, sync=False)
    tr = track_ball(rec.events, width=rec.width, height=rec.height)
    assert len(tr.flight_ids()) == 1
    cx, cy, r, _, _ = _flight_truth(rec, tr.t_us)
    assert np.max(np.hypot(tr.cx - cx, tr.cy - cy)) < 2.0



@pytest.mark.parametrize("seed", [1, 2])
def test_a_bat_swung_past_the_ball_is_no_ball_and_does_not_lose_it(seed):
    """A table-tennis bat (round, fires at its rim like a plain ball, four times the ball's size) swung
    past the ball at mid-flight, its handle in view: before the handle was looked for, it was tracked
    as a second ball (rows 260-280 px off the ball's, on seeds 1-3)."""
    rec = sim.flight("tabletennis", rps=40, axis=(0.3, 0.5, 0.8), radius_px=8.0, width=320, height=240,
                     duration_s=0.06, start_px=(-4.0, 120.0), velocity_px_s=(5000.0, 0.0), gravity_px_s2=0.0,
                     distractors=("paddle",), noise_rate_hz=0.5, hot_pixels=5, seed=seed)
    tr = track_ball(rec.events, width=320, height=240)
    tt = rec.truth_track()
    assert len(tr.flight_ids()) == 1 and tr.t_us.min() <= 5_000 and tr.t_us.max() >= 55_000
    err = np.hypot(tr.cx - np.interp(tr.t_us, tt.t_us, tt.cx), tr.cy - np.interp(tr.t_us, tt.t_us, tt.cy))
    assert np.median(err) < 1.0 and err.max() < 3.0


# detect_bench's row ``paddle`` to full precision: seed -> (rps, axis, start px, velocity px/s)
_PADDLE = {6: (28.58628962940386, (0.13241519356417, -0.37465527468539606, -0.9901891716954576),
               (-5.0, 286.1607563156428), (4865.001578646188, -1154.01890789107)),
           10: (74.09408408802187, (-1.3831430308174553, 1.7583409833157835, -2.167534910662094),
                (-5.0, 258.9064283252122), (4977.609050034943, -472.6607081303038))}


def paddle_flight(seed: int):
    """``detect_bench``'s row ``paddle`` for ``seed`` (6 or 10): a table-tennis ball past a bat, with a
    walking player, 640x480, 80 ms."""
    rps, axis, start, velocity = _PADDLE[seed]
    return sim.flight("tabletennis", rps=rps, axis=axis, radius_px=10.0, width=640, height=480, duration_s=0.08,
                      start_px=start, velocity_px_s=velocity, distractors=("paddle", "player"), noise_rate_hz=1.0,
                      hot_pixels=30, seed=seed)


@pytest.mark.parametrize("seed", [6, 10])
def test_a_bat_whose_handle_was_hidden_where_its_flight_started_leaves_no_rows(seed):
    """A table-tennis bat's face (r 40 px, the ball's r 10 px) in view from the first event with its handle
    hidden behind the player (``detect_bench`` row ``paddle``): on seed 6 it was tracked as a ball for its
    whole swing (39 rows 8-400 px off the ball, until the recording ended), on seed 10 for 5 rows until it
    was lost. Now the first is dropped once its handle shows (on a stem in 5 updates in a row among its
    first 12), the second as lost young (within 8 updates); and the ball is tracked throughout."""
    rec = paddle_flight(seed)
    tracker = BallTracker(640, 480)
    causal = Track.concat([tracker.update(rec.events[i:i + 50_000]) for i in range(0, len(rec.events), 50_000)])
    tr = tracker.finish()
    tt = rec.truth_track(visible_only=False)
    off = lambda rows: np.hypot(rows.cx - np.interp(rows.t_us, tt.t_us, tt.cx),  # noqa: E731
                                rows.cy - np.interp(rows.t_us, tt.t_us, tt.cy))
    assert np.count_nonzero(off(causal) > 20.0) >= 5  # the bat was tracked a while (its rows, returned)
    assert len(tr.flight_ids()) == 1 and off(tr).max() < 3.0  # and is in no final row
    assert tr.t_us.min() <= 5_000 and tr.t_us.max() >= 75_000


def test_a_ball_a_slow_hand_touches_is_not_lost():
    """A small textured ball (r 10 px) flying past a slowly turning arm whose hand touches it from 45 ms
    to the end (``detect_bench`` row ``arm-small``, seed 26 of the extra set 17-30). The hand's thin
    edges beside a ball that fires all over its disk were never dense enough to count as touching it:
    the rim fit leant towards the hand, the filter's velocity drifted, and the flight was lost at 51 ms
    (recall 52.5 %)."""
    # the bench's values to full precision: a little off, the hand touches the ball at another moment
    rec = sim.flight("volleyball", rps=27.010925350847977,
                     axis=(-0.468441565236853, 1.0095247958837967, -0.8336305707142443), radius_px=10.0,
                     width=640, height=480, duration_s=0.08, start_px=(-5.0, 241.76154330617297),
                     velocity_px_s=(760.6309679804986, -44.038582654324536),
                     distractors=("arm",), noise_rate_hz=1.0, hot_pixels=30, seed=26)
    tr = track_ball(rec.events, width=640, height=480)
    tt = rec.truth_track()
    assert len(tr.flight_ids()) == 1 and tr.t_us.min() <= 25_000 and tr.t_us.max() >= 75_000
    err = np.hypot(tr.cx - np.interp(tr.t_us, tt.t_us, tt.cx), tr.cy - np.interp(tr.t_us, tt.t_us, tt.cy))
    assert np.median(err) < 1.0 and err.max() < 3.0


def test_two_balls_stream_as_they_track_in_one_batch(two_balls_at_once):
    from sim.esim import merge

    ev = merge(two_balls_at_once[0].events, two_balls_at_once[1].events)
    batch = track_ball(ev, width=W, height=H)
    trk = BallTracker(W, H, smooth_lag_us=10_000)
    cuts = np.sort(np.random.default_rng(1).integers(0, len(ev), 40))
    finals, bound = [], None
    for chunk in np.split(ev, cuts):
        rows = trk.update(chunk)
        if bound is not None:  # rows_final_before_us holds for both flights' rows
            assert np.all(rows.t_us >= bound)
        bound = trk.rows_final_before_us
        finals.append(trk.take_final())
    live = trk.finish()
    finals.append(trk.take_final())
    assert all(np.all(np.diff(p.t_us) >= 0) for p in finals)
    by_time = lambda tr: tr.select(np.lexsort((tr.flight, tr.t_us)))  # noqa: E731
    streamed, live = by_time(Track.concat(finals)), by_time(live)
    np.testing.assert_array_equal(streamed.t_us, live.t_us)
    np.testing.assert_array_equal(streamed.cx, live.cx)  # final rows never change
    batch = by_time(batch)
    np.testing.assert_array_equal(live.t_us, batch.t_us)
    np.testing.assert_array_equal(live.flight, batch.flight)
    np.testing.assert_allclose(live.cx, batch.cx, atol=0.05)  # 10 ms against whole-flight smoothing


def test_frames_detector_and_fusion_on_simulated_frames():
    from detect.frame_detector import FrameDetector

    rec = sim.flight(radius_px=16, width=W, height=H, duration_s=0.06, start_px=(30.0, 120.0),
                     velocity_px_s=(5000.0, -800.0), rps=20, distractors=("player",), noise_rate_hz=1.0,
                     hot_pixels=10, fps=240.0, exposure_s=0.0005, seed=13)
    fd = FrameDetector((8, 40))
    hits = n = 0
    for k, (img, t) in enumerate(zip(rec.frames, rec.frame_times_us)):
        circles = fd.detect(img)
        cx, cy, r, _, _ = _flight_truth(rec, t)
        if k >= 4 and cx + r < W - 1:  # background model warm, ball fully in view
            n += 1
            hits += bool(circles) and np.hypot(circles[0].cx - cx, circles[0].cy - cy) < 1.0
    assert n >= 8 and hits >= 0.7 * n
    tr = track_ball(rec.events, width=W, height=H, frames=rec.frames, frame_times_us=rec.frame_times_us)
    assert len(tr.flight_ids()) == 1
    assert np.isin(rec.frame_times_us, tr.t_us).sum() >= 3  # frame detections were fused
    cx, cy, *_ = _flight_truth(rec, tr.t_us)
    assert np.median(np.hypot(tr.cx - cx, tr.cy - cy)) < 0.5


def test_track_feeds_spin_windows(spinning_flight):
    from detect import spin_windows

    ev, truth = spinning_flight
    tr = track_ball(ev, width=W, height=H)
    wins = list(spin_windows(ev, tr, window_us=4000, min_events=500))
    assert len(wins) >= 0.8 * (tr.t_us[-1] - tr.t_us[0]) / 4000
    for w in wins:
        ex, ey = _truth_xy(truth, w.t_start_us)
        assert np.hypot(w.center[0] - ex, w.center[1] - ey) < 1.0
        assert np.hypot(*(np.asarray(w.velocity_px_s) - truth["velocity_px_s"])) < 0.03 * np.hypot(
            *truth["velocity_px_s"])
        # the window keeps the ball's events and little else
        d = np.hypot(w.events["x"] - (ex + truth["velocity_px_s"][0] * (w.events["t"] - w.t_start_us) * 1e-6),
                     w.events["y"] - (ey + truth["velocity_px_s"][1] * (w.events["t"] - w.t_start_us) * 1e-6))
        assert np.mean(d <= truth["radius_px"] + 1.5) > 0.99


def test_a_player_in_view_is_refitted_less_and_less_often(monkeypatch):
    # no ball: a walking player and a swinging arm; clusters rejected again and again are refitted at
    # doubling intervals (up to tracker._REJECT_SKIP_MAX windows), not every few windows
    import detect.tracker as tracker

    rec = sim.flight(radius_px=20, width=640, height=480, duration_s=0.3, start_px=(-1000.0, 240.0),
                     velocity_px_s=(0.0, 0.0), gravity_px_s2=0.0, rps=0, distractors=("player", "arm"),
                     noise_rate_hz=1.0, hot_pixels=10, seed=6)
    original = BallTracker._fit

    def fits_made(skip_max):
        fits = []

        def counting(self, t, x, y, m, *args, **kwargs):
            fits.append(m)
            return original(self, t, x, y, m, *args, **kwargs)

        monkeypatch.setattr(BallTracker, "_fit", counting)
        monkeypatch.setattr(tracker, "_REJECT_SKIP_MAX", skip_max)
        assert len(track_ball(rec.events, width=640, height=480)) == 0
        return len(fits)

    assert fits_made(tracker._REJECT_SKIP_MAX) < 0.6 * fits_made(tracker._REJECT_SKIP)  # no doubling
