"""Per-flight results: spin in the flight's frame, uncertainty, yield, speed, CSV, the report CLI."""

import numpy as np
import pandas as pd
import pytest

import sim
from capture.events import SPIN_COLUMNS, Track, empty_table
from capture.report import main as report_main
from capture.results import (PERIOD_SIGMA_FLOOR_PCT, PERIOD_SIGMA_REPEATS_PCT, flight_table, flight_velocity,
                             format_flight_table, period_rate, tilt_clock, window_table, write_csv, write_parquet)
from capture.session import create_session
from detect import spin_windows, track_ball


def _track(velocity, t_us=(0, 100_000), flight=0, r=20.0):
    t = np.arange(*t_us, 2000)
    return Track(t_us=t, cx=100 + velocity[0] * t * 1e-6, cy=100 + velocity[1] * t * 1e-6, r=np.full(len(t), r),
                 vx=np.full(len(t), velocity[0]), vy=np.full(len(t), velocity[1]), score=np.ones(len(t)),
                 flight=np.full(len(t), flight))


def _spin(axis, rps, velocity, n=8, t0=0, conf=1.0, rps_noise=0.0, seed=0, flight=-1):
    rng = np.random.default_rng(seed)
    s = empty_table(SPIN_COLUMNS, n)
    s["flight"][:] = flight  # -1: the flight whose track rows span the window
    s["t_start_us"] = t0 + 10_000 * np.arange(n)
    s["t_end_us"] = s["t_start_us"] + 2000
    s["axis"][:] = np.asarray(axis, float) / np.linalg.norm(axis)
    s["rps"] = rps + rps_noise * rng.standard_normal(n)
    s["omega_rad_s"] = 2 * np.pi * s["rps"]
    s["velocity_px_s"][:] = velocity
    s["confidence"][:] = conf
    s["axis_sigma_deg"][:] = 1.0
    s["rps_sigma_pct"][:] = 0.5
    return s


@pytest.mark.parametrize("velocity, axis, top, side, gyro, tilt", [
    ((3000, 0), (0, 0, -1), 1, 0, 0, "6:00"),     # flying right, top of the ball forward: topspin
    ((-3000, 0), (0, 0, -1), -1, 0, 0, "12:00"),  # the same axis flying left: backspin
    ((-3000, 0), (0, 0, 1), 1, 0, 0, "6:00"),
    ((3000, 0), (0, -1, 0), 0, 1, 0, "3:00"),     # axis up: sidespin, counter-clockwise from above
    ((3000, 0), (0, 1, 0), 0, -1, 0, "9:00"),
    ((3000, 0), (1, 0, 0), 0, 0, 1, None),        # axis along the flight: rifle spin
    ((3000, -3000), (0, 0, -1), 1, 0, 0, "6:00"),  # rising at 45 deg: still topspin
    ((0, -3000), (1, 0, 0), 1, 0, 0, "6:00"),     # straight up: "up" is towards the camera
    ((0, 3000), (1, 0, 0), -1, 0, 0, "12:00"),    # straight down, same axis: backspin
])
def test_spin_components_in_the_flight_frame(velocity, axis, top, side, gyro, tilt):
    rps = 25.0
    t = flight_table(_track(velocity), _spin(axis, rps, velocity))
    assert t["rpm"][0] == pytest.approx(60 * rps)
    assert t["topspin_rpm"][0] == pytest.approx(60 * rps * top, abs=1e-6)
    assert t["sidespin_rpm"][0] == pytest.approx(60 * rps * side, abs=1e-6)
    assert t["gyro_rpm"][0] == pytest.approx(60 * rps * gyro, abs=1e-6)
    assert t["efficiency"][0] == pytest.approx(1.0 - abs(gyro), abs=1e-6)
    if tilt:
        assert t["tilt"][0] == tilt


def test_tilt_clock_turns_with_the_axis():
    assert tilt_clock(-1.0, 0.0) == "12:00" and tilt_clock(1.0, 0.0) == "6:00"
    assert tilt_clock(-1.0, 1.0) == "1:30" and tilt_clock(0.0, 0.0) == "-"


def test_uncertainty_from_the_spread_and_windows_never_overconfident():
    v = (3000, 0)
    noisy = flight_table(_track(v), _spin((0, 0, -1), 30.0, v, n=400, rps_noise=1.0))
    # standard error of the median of 400 windows with 1 rps spread: 1.2533 / 20 rps
    assert noisy["rpm_sigma"][0] == pytest.approx(60 * 1.2533 / 20, rel=0.15)
    one = flight_table(_track(v), _spin((0, 0, -1), 30.0, v, n=1))
    assert one["rpm_sigma"][0] == pytest.approx(60 * 0.005 * 30.0)  # its own sigma (0.5 %)
    same = flight_table(_track(v), _spin((0, 0, -1), 30.0, v, n=4))
    assert same["rpm_sigma"][0] == pytest.approx(60 * 0.005 * 30.0 / 2)  # no spread: the windows' own / sqrt(n)
    # windows whose sigma (3 %) is mostly the sensor's lag (2.5 %): a bias they share, which averaging
    # 100 of them does not shrink
    lagging = _spin((0, 0, -1), 30.0, v, n=100)
    lagging["rps_sigma_pct"][:] = 3.0
    lagging["rps_lag_pct"][:] = 2.5
    assert flight_table(_track(v), lagging)["rpm_sigma"][0] == pytest.approx(60 * 0.025 * 30.0)
    lagging["rps_lag_pct"][:] = np.nan  # not measured (an older session): the windows' own / sqrt(n)
    assert flight_table(_track(v), lagging)["rpm_sigma"][0] == pytest.approx(60 * 0.03 * 30.0 / 10)


def test_flights_without_a_trusted_window_are_listed_as_such():
    v = (3000, 0)
    track = Track.concat([_track(v), _track(v, (200_000, 300_000), flight=1)])
    spin = {k: np.concatenate([a[k], b[k]]) for k, a, b in
            ((k, _spin((0, 0, -1), 30.0, v), _spin((0, 0, -1), 30.0, v, t0=200_000, conf=0.2)) for k in SPIN_COLUMNS)}
    t = flight_table(track, spin)
    assert list(t["flight"]) == [0, 1] and list(t["n_trusted"]) == [8, 0] and list(t["n_windows"]) == [8, 8]
    assert np.isfinite(t["rpm"][0]) and np.isnan(t["rpm"][1])
    text = format_flight_table(t)
    assert "no trusted estimate" in text and "yield: 1 of 2 flight(s)" in text
    w = window_table(track, spin)
    assert list(np.unique(w["flight"])) == [0, 1] and w["trusted"].sum() == 8


def test_a_flight_without_a_trusted_window_gets_its_rate_from_its_image_period():
    """The untrusted windows' rates (about 30 rps: the axes of a sparse ball are what they miss) pick
    which fold of the image's period is one turn; the period gives the rate, not the axis."""
    v = (3000, 0)
    track = Track.concat([_track(v), _track(v, (200_000, 300_000), flight=1)])
    spin = {k: np.concatenate([a[k], b[k]]) for k, a, b in
            ((k, _spin((0, 0, -1), 30.0, v), _spin((0, 1, 0), 31.0, v, t0=200_000, conf=0.2, rps_noise=0.5))
             for k in SPIN_COLUMNS)}
    # flight 0's image repeats once a turn, flight 1's five times (a soccer ball about a five-fold axis)
    periods = {0: (1 / 30.01, 0.9, 0.1), 1: (1 / 150.0, 0.8, 0.1)}
    t = flight_table(track, spin, periods=periods)
    assert np.isnan(t["rpm"][1]) and t["period_rpm"][1] == pytest.approx(1800.0)
    assert t["period_rpm"][0] == pytest.approx(60 * 30.01)
    # (its sigma: over the turns, not the repeats, five times that of one repeat a turn)
    assert t["period_rpm_sigma"][1] == pytest.approx(1800.0 * 5 * PERIOD_SIGMA_REPEATS_PCT * (1 / 150) / 0.1 / 100)
    text = format_flight_table(t)
    assert "period rpm" in text.splitlines()[0] and f"1800 ± {t['period_rpm_sigma'][1]:.0f}" in text.splitlines()[2]
    assert "no trusted axis: rate from the period" in text.splitlines()[2]
    assert "1 of 2 flight(s) with a trusted spin, 2 with a rate from" in text and "marked" not in text
    assert not t["period_contradicts"].any()
    # no period found, or windows that single out no fold: NaN, and no column
    for bad in ({}, {0: None, 1: (1 / 40.0, 0.9, 0.1)}):
        t = flight_table(track, spin, periods=bad)
        assert np.isnan(t["period_rpm"]).all() and "period rpm" not in format_flight_table(t)
    # trusted windows whose rate lies 6 % from the period's (one fold within 7 % of them): not trusted
    t = flight_table(track, spin, periods={0: (1 / 28.3, 0.9, 0.1)})
    assert t["period_contradicts"][0] and np.isnan(t["rpm"][0]) and np.isnan(t["axis_x"][0])
    assert t["period_rpm"][0] == pytest.approx(60 * 28.3)
    assert "contradicted by the period" in format_flight_table(t).splitlines()[1]
    t = flight_table(track, spin, periods={0: (1 / 29.0, 0.9, 0.1)})  # 3.4 % apart: both stand
    assert not t["period_contradicts"][0] and np.isfinite(t["rpm"][0])
    # three trusted windows right, seven untrusted at half the rate (an alias): the trusted ones pick the
    # fold, and the period, once a turn, allows their rate
    mixed = {k: np.concatenate([a[k], b[k]]) for k, a, b in
             ((k, _spin((0, 0, -1), 30.0, v, n=3), _spin((0, 1, 0), 15.0, v, n=7, t0=30_000, conf=0.1))
              for k in SPIN_COLUMNS)}
    t = flight_table(_track(v), mixed, periods={0: (1 / 30.0, 0.9, 0.1)})
    assert not t["period_contradicts"][0] and t["rpm"][0] == pytest.approx(1800.0)
    assert t["period_rpm"][0] == pytest.approx(1800.0)


@pytest.mark.parametrize("period_s, window_rps, expected_rps", [
    (1 / 30.0, 29.0, 30.0),     # one repeat a turn
    (1 / 150.0, 30.5, 30.0),    # five (a soccer ball about a five-fold axis): the windows pick the fold
    (1 / 60.0, 31.0, 30.0),     # two
    (1 / 30.0, 22.0, None),     # the windows' rate lies 27 % from every fold: none is taken
    (1 / 30.0, float("nan"), None),
])
def test_the_windows_rate_picks_how_many_repeats_make_a_turn(period_s, window_rps, expected_rps):
    got = period_rate(period_s, 0.3, window_rps)
    if expected_rps is None:
        assert got is None
    else:
        rps, sigma_pct = got
        assert rps == pytest.approx(expected_rps)
        # over fewer repeats, a wider uncertainty; counted in turns where the image repeats more than once a
        # turn (a near-symmetry of the texture repeats less exactly)
        fold = round(1 / (period_s * rps))
        assert sigma_pct == pytest.approx(fold * max(PERIOD_SIGMA_FLOOR_PCT, PERIOD_SIGMA_REPEATS_PCT * period_s / 0.3))


def test_the_table_prints_no_negative_zero():
    # a pure topspin about an axis a hair off: sidespin and gyro round to 0, never "-0"
    v = (3000, 0)
    t = flight_table(_track(v), _spin((0.0, -0.001, -1.0), 30.0, v))
    t["sidespin_rpm"][0], t["gyro_rpm"][0] = -0.3, -0.2
    row = format_flight_table(t).splitlines()[1]
    assert " -0 " not in row + " " and row.split()[8:10] == ["0", "0"]


def test_two_balls_in_view_at_once_keep_their_own_spin():
    # two flights over the same 100 ms (two balls): only the spin table's flight column tells
    # their windows apart
    v = (3000, 0)
    track = Track.concat([_track(v), _track((-2000, 0), flight=1)])
    spin = {k: np.concatenate([a[k], b[k]]) for k, a, b in
            ((k, _spin((0, 0, -1), 30.0, v, flight=0), _spin((0, -1, 0), 80.0, (-2000, 0), t0=1000, flight=1))
             for k in SPIN_COLUMNS)}
    t = flight_table(track, spin)
    assert list(t["n_windows"]) == [8, 8]
    assert t["rps"][0] == pytest.approx(30.0) and t["rps"][1] == pytest.approx(80.0)
    assert t["topspin_rpm"][0] == pytest.approx(1800.0) and t["sidespin_rpm"][1] == pytest.approx(4800.0)
    unknown = {**spin, "flight": np.full(16, -1, np.int32)}  # a session written before the column existed
    assert list(flight_table(track, unknown)["n_windows"]) == [16, 0]  # by time: all to the first


def _camera(f=1000.0, cx=240.0, cy=160.0, dist=(0.0, 0.0, 0.0, 0.0, 0.0)):
    from calib import Intrinsics

    return Intrinsics(K=np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]]), dist=np.asarray(dist, float),
                      width=480, height=320)


def test_distance_and_speed_from_the_ball_size():
    v = (1000, 0)
    t = flight_table(_track(v, r=21.0), _spin((0, 0, -1), 30.0, v), camera=_camera(cx=149.0, cy=100.0),
                     ball_diameter_m=0.21, ball="volleyball")
    assert t["distance_m"][0] == pytest.approx(5.0)      # 1000 px * 0.105 m / 21 px, on the optical axis
    assert t["speed_m_s"][0] == pytest.approx(5.0)       # 1000 px/s at 5 m with f = 1000 px
    assert t["speed_across_m_s"][0] == pytest.approx(5.0) and t["speed_los_m_s"][0] == pytest.approx(0.0, abs=1e-9)
    assert t["speed_km_h"][0] == pytest.approx(18.0)
    text = format_flight_table(t)
    assert "km/h" in text and "volleyball" in text.splitlines()[1]
    plain = flight_table(_track(v), _spin((0, 0, -1), 30.0, v))
    assert np.isnan(plain["speed_m_s"][0]) and plain["ball"][0] == "-" and "ball" not in format_flight_table(plain)


def _flight_rows(p0_m, v_m_s, camera, diameter_m, *, n=120, dt_s=0.002, g_m_s2=(0.0, 9.81, 0.0), r_noise_px=0.0,
                 c_noise_px=0.0, rng=None):
    """Track rows of a ball flying from ``p0_m`` at ``v_m_s`` (camera frame) under gravity, seen by
    ``camera``: centre projected, radius f D / (2 Z), noise added."""
    t = np.arange(n) * dt_s
    p = np.asarray(p0_m) + np.outer(t, v_m_s) + 0.5 * np.outer(t ** 2, g_m_s2)
    uv = camera.project(p)
    r = camera.focal_px * 0.5 * diameter_m / p[:, 2]
    if rng is not None:
        r = r + r_noise_px * rng.standard_normal(n)
        uv = uv + c_noise_px * rng.standard_normal(uv.shape)
    mid = np.asarray(v_m_s) + np.asarray(g_m_s2) * t[-1] / 2  # velocity at the middle of the flight
    return (t * 1e6).astype(np.int64), uv[:, 0], uv[:, 1], r, mid


@pytest.mark.parametrize("v_m_s", [(12.0, -3.0, 0.0), (8.0, -2.0, 6.0), (-10.0, -4.0, -5.0), (0.5, -6.0, 4.0)])
def test_3d_velocity_from_the_track_and_the_ball_size(v_m_s):
    """Across the view, towards or away from the camera, straight up: the 3D velocity at mid-flight,
    through a lens with distortion, within its sigma."""
    cam = _camera(dist=(-0.12, 0.03, 0.0, 0.0, 0.0))
    t, cx, cy, r, mid = _flight_rows((-0.6, 0.3, 6.0), v_m_s, cam, 0.21, n=60, dt_s=0.002)
    out = flight_velocity(t, cx, cy, r, cam, 0.21)
    assert out["velocity_m_s"] == pytest.approx(mid, abs=1e-3)
    assert out["speed_m_s"] == pytest.approx(np.linalg.norm(mid), rel=1e-4)
    centre = np.array([-0.6, 0.3, 6.0]) + np.asarray(v_m_s) * 0.059 + 0.5 * np.array([0, 9.81, 0]) * 0.059 ** 2
    los = mid @ centre / np.linalg.norm(centre)
    assert out["speed_los_m_s"] == pytest.approx(los, abs=0.02)
    assert out["speed_across_m_s"] == pytest.approx(np.sqrt(mid @ mid - los ** 2), abs=0.02)


def test_3d_speed_sigma_means_what_it_says():
    """Radius noise of 0.3 px on a 20 px ball: over 300 noisy flights the error is within 1 sigma
    (the fit's part) about 68 % of the time and within 3 sigma almost always; the scale's part
    (radius bias, ball size) adds to it."""
    cam, rng = _camera(), np.random.default_rng(7)
    z = []
    for _ in range(300):
        t, cx, cy, r, mid = _flight_rows((-0.8, 0.0, 5.0), (10.0, -2.0, 3.0), cam, 0.21, n=40, dt_s=0.004,
                                         r_noise_px=0.3, c_noise_px=0.1, rng=rng)
        out = flight_velocity(t, cx, cy, r, cam, 0.21, radius_sigma_px=0.0, diameter_sigma_rel=0.0)  # the fit's part
        z.append((out["speed_m_s"] - np.linalg.norm(mid)) / out["speed_sigma_m_s"])
    z = np.abs(np.array(z))
    assert 0.58 < np.mean(z < 1) < 0.78 and np.mean(z < 3) > 0.97
    both = flight_velocity(t, cx, cy, r, cam, 0.21)
    scale = np.hypot(0.6 / np.median(r), 0.015)
    assert both["speed_sigma_m_s"] == pytest.approx(np.hypot(out["speed_sigma_m_s"], both["speed_m_s"] * scale))
    assert both["distance_sigma_m"] == pytest.approx(both["distance_m"] * scale)


def test_csv_reads_back_with_pandas_and_keeps_units_in_the_names(tmp_path):
    v = (3000, 0)
    t = flight_table(_track(v), _spin((0, 0, -1), 30.0, v))
    df = pd.read_csv(write_csv(t, tmp_path / "flights.csv"))
    assert {"rpm", "rpm_sigma", "topspin_rpm", "duration_ms", "t_start_s", "image_speed_px_s", "speed_km_h"} <= set(df)
    assert df["rpm"][0] == pytest.approx(1800.0) and df["tilt"][0] == "6:00" and np.isnan(df["speed_m_s"][0])
    w = pd.read_csv(write_csv(window_table(_track(v), _spin((0, 0, -1), 30.0, v)), tmp_path / "w.csv"))
    assert len(w) == 8 and w["trusted"].dtype == np.int64 and (w["rpm"] == 1800.0).all()


def test_parquet_reads_back_with_pandas_with_the_same_values(tmp_path):
    v = (3000, 0)
    t = flight_table(_track(v), _spin((0, 0, -1), 30.0, v, rps_noise=0.3))
    df = pd.read_parquet(write_parquet(t, tmp_path / "flights.parquet"))
    assert list(df.columns) == list(t) and df["tilt"][0] == t["tilt"][0]
    assert df["rpm"][0] == t["rpm"][0] and df["n_trusted"].dtype == np.int64 and np.isnan(df["speed_km_h"][0])
    w = window_table(_track(v), _spin((0, 0, -1), 30.0, v))
    dw = pd.read_parquet(write_parquet(w, tmp_path / "w.parquet"))
    assert len(dw) == 8 and dw["trusted"].dtype == bool and np.allclose(dw["rpm"], w["rpm"])


@pytest.mark.parametrize("direction, rps", [(1, 20.0), (-1, -20.0)])
def test_simulated_flights_give_their_true_spin_in_coach_terms(direction, rps):
    # topspin flying right (axis -Z); flying left the same axis is backspin
    rec = sim.flight(texture="volleyball", rps=20.0, axis=(0, 0, -1), radius_px=30.0, width=480, height=320,
                     duration_s=0.06, start_px=(240 - direction * 150.0, 160.0),
                     velocity_px_s=(direction * 5000.0, 0.0), gravity_px_s2=0.0, distractors=(), noise_rate_hz=0.5,
                     hot_pixels=5, seed=3)
    track = track_ball(rec.events, width=480, height=320)
    from spin import estimate_windows
    from capture.events import spin_table

    spin = spin_table(estimate_windows(spin_windows(rec.events, track, window_us=4000, min_events=3000)))
    t = flight_table(track, spin)
    assert len(t["flight"]) == 1 and t["n_trusted"][0] >= 3
    assert t["rpm"][0] == pytest.approx(1200.0, rel=0.03)
    assert np.sign(t["topspin_rpm"][0]) == np.sign(rps) and t["efficiency"][0] > 0.95
    h, m = map(int, t["tilt"][0].split(":"))
    deg = ((h % 12) * 60 + m) * 0.5  # 12:00 = 0 deg (backspin), 6:00 = 180 deg (topspin)
    want = 180.0 if rps > 0 else 0.0
    assert abs((deg - want + 180.0) % 360.0 - 180.0) < 10.0


def test_report_cli_prints_the_table_and_refuses_an_unanalysed_session(tmp_path, capsys):
    path = tmp_path / "s"
    with create_session(path, width=480, height=320):
        pass
    assert report_main([str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not analysed yet" in err[0] and "capture.replay" in err[0]
    v = (3000, 0)
    from capture.session import update_session

    with update_session(path) as w:
        w.write_track(_track(v))
        w.write_spin(_spin((0, 0, -1), 30.0, v))
    assert report_main([str(path), "--csv", str(tmp_path / "f.csv"), "--ball", "volleyball",
                        "--windows-parquet", str(tmp_path / "w.parquet")]) == 0
    out = capsys.readouterr().out
    assert "1800" in out and "6:00" in out and "yield: 1 of 1" in out and "no calibration" in out
    assert pd.read_csv(tmp_path / "f.csv")["n_trusted"][0] == 8
    assert len(pd.read_parquet(tmp_path / "w.parquet")) == 8
    assert report_main([str(path), "--ball-diameter", "-1"]) == 1
    capsys.readouterr()
    assert report_main([str(path)]) == 0
    assert "no calibration" not in capsys.readouterr().out  # no ball: no distances asked for
    with update_session(path) as w:
        w.set_attrs(ball={"type": "volleyball", "diameter_m": 0.21})  # as capture.run --ball records it
    assert report_main([str(path)]) == 0
    assert "no calibration" in capsys.readouterr().out  # the recorded ball asks for distances and speeds
    (path / "events.raw").write_bytes(b"")
    with update_session(path) as w:  # a recording that was never closed by its recorder
        w.set_attrs(raw_file="events.raw")
    assert report_main([str(path)]) == 0
    assert "note: the recording was cut short" in capsys.readouterr().out  # the table is of what was stored


def test_html_report_is_one_self_contained_file_with_the_table_and_plots(tmp_path):
    import base64
    import re

    from capture.pipeline.replay import ReplayOptions, replay

    rec = sim.flight(texture="volleyball", rps=20.0, axis=(0, 0, -1), radius_px=30.0, width=480, height=320,
                     duration_s=0.06, start_px=(90.0, 160.0), velocity_px_s=(5000.0, 0.0), gravity_px_s2=0.0,
                     distractors=(), noise_rate_hz=0.5, hot_pixels=5, seed=3)
    path = tmp_path / "s"
    with create_session(path, width=480, height=320) as w:
        w.append_events(rec.events)
    replay(path, options=ReplayOptions(workers=1), progress=False)
    out = tmp_path / "report.html"
    assert report_main([str(path), "--html", str(out), "--ball", "volleyball"]) == 0
    doc = out.read_text()
    assert "<td>volleyball</td>" in doc and "no calibration of the event camera" in doc  # the ball, and why no speed
    assert doc.startswith("<!DOCTYPE html>") and "</html>" in doc
    # nothing fetched from elsewhere: no scripts, no links, every image inline
    assert "<script" not in doc and "http://" not in doc and "https://" not in doc
    images = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", doc)
    assert len(images) == 3  # the track, the flight's spin, its ball events
    assert all(base64.b64decode(i)[:8] == b"\x89PNG\r\n\x1a\n" for i in images)
    from capture.results import session_results

    flights, _ = session_results(path)
    assert flights["rpm"][0] == pytest.approx(1200.0, rel=0.03)
    assert f"<td>{flights['rpm'][0]:.0f}</td>" in doc and f"<td>{flights['tilt'][0]}</td>" in doc
    assert "Flight 0" in doc
    assert "<th>period rpm</th>" in doc and "<th>contradicted by the period</th>" in doc


def test_the_ball_recorded_with_the_session_gives_distance_and_speed(tmp_path, capsys):
    """``capture.run --ball`` stores the ball; with the event camera's calibration the session's
    tables then have distances and speeds without asking again (an explicit diameter wins)."""
    from calib import CameraPair, store_calibration
    from capture.results import session_results
    from capture.session import update_session

    path, v = tmp_path / "s", (1000, 0)
    event = _camera(cx=149.0, cy=100.0)  # the ball's mid-flight on the optical axis
    with create_session(path, width=480, height=320) as w:
        store_calibration(w, cameras=CameraPair(frame=event, event=event, homography=np.eye(3)))
        w.write_track(_track(v, r=21.0))
        w.write_spin(_spin((0, 0, -1), 30.0, v))
    assert np.isnan(session_results(path)[0]["speed_m_s"][0])  # no ball known
    with update_session(path) as w:
        w.set_attrs(ball={"type": "volleyball", "diameter_m": 0.21})
    flights = session_results(path)[0]
    assert flights["distance_m"][0] == pytest.approx(5.0) and flights["speed_m_s"][0] == pytest.approx(5.0)
    assert flights["ball"][0] == "volleyball"
    assert session_results(path, ball_diameter_m=0.42)[0]["distance_m"][0] == pytest.approx(10.0)
    assert report_main([str(path), "--ball", "tennis"]) == 0  # an explicit ball wins, named in the table
    row = capsys.readouterr().out.splitlines()[1].split()
    assert row[0] == "tennis" and float(row[-4]) == pytest.approx(5.0 * 0.067 / 0.21, abs=0.05)


@pytest.mark.parametrize("depth_m_s", [-3.0, 4.0])
def test_3d_speed_of_a_simulated_looming_or_receding_flight_through_the_tracker(depth_m_s):
    """A volleyball flying across a pinhole camera's view and towards (-) or away from (+) it: the
    tracker's circles and the ball's size give its 3D velocity at mid-flight within 3 sigma."""
    rec = sim.flight(texture="volleyball", rps=10.0, radius_px=28.0, width=640, height=480, duration_s=0.2,
                     start_px=(120.0, 200.0), velocity_px_s=(1500.0, -300.0), projection="pinhole", focal_px=800.0,
                     depth_velocity_m_s=depth_m_s, distractors=(), noise_rate_hz=0.2, hot_pixels=0, seed=4)
    truth = rec.truth
    cam = _camera(f=800.0, cx=truth["principal_px"][0], cy=truth["principal_px"][1])
    track = track_ball(rec.events, width=640, height=480)
    (fl,) = track.flight_ids()
    sel = track.flight == fl
    out = flight_velocity(track.t_us[sel], track.cx[sel], track.cy[sel], track.r[sel], cam, 0.21)
    # the ball's 3D velocity in the simulator: image velocity at the start depth, gravity down, depth speed
    ray = np.r_[(np.asarray(truth["start_px"]) - truth["principal_px"]) / 800.0, 1.0]
    z0 = 0.105 / np.sin(np.arctan(28.0 / 800.0)) * ray[2] / np.linalg.norm(ray)
    t_mid_s = (np.mean(track.t_us[sel][[0, -1]]) - truth["t0_us"]) * 1e-6
    v = np.array([1500.0 * z0 / 800.0, (-300.0 + truth["gravity_px_s2"] * t_mid_s) * z0 / 800.0, depth_m_s])
    assert np.sign(out["speed_los_m_s"]) == np.sign(depth_m_s)
    assert abs(out["speed_m_s"] - np.linalg.norm(v)) < max(3 * out["speed_sigma_m_s"], 0.02 * np.linalg.norm(v))
    np.testing.assert_allclose(out["velocity_m_s"], v, atol=max(0.4, 3 * out["speed_sigma_m_s"]))


def test_the_flight_table_takes_a_trusted_whole_flight_spin_where_no_window_is_trusted():
    """No window trusted: the whole flight's spin (``spin.flight``) fills the spin columns, marked
    ``spin_from="flight"`` (and ``*`` in the printed table); as the session stores it too; an untrusted
    one gives nothing; trusted windows' spin stands over it."""
    import math
    from dataclasses import replace

    from spin.flight import FlightSpin

    v = (3000, 0)
    whole = FlightSpin(axis=np.array([0.0, 0.0, -1.0]), omega_rad_s=2 * math.pi * 40.0, fold=1, ratio=2.0,
                       excess=30.0, trusted=True, axis_sigma_deg=1.8, rps_sigma_pct=0.2,
                       turns=11.0, fold_ratio=3.0, rate_trusted=True)
    flagged = _spin((0, 0, -1), 30.0, v, conf=0.2)
    t = flight_table(_track(v), flagged, flight_spins={0: whole})
    assert t["spin_from"][0] == "flight" and t["rpm"][0] == pytest.approx(2400.0)
    assert t["rpm_sigma"][0] == pytest.approx(2400.0 * 0.002) and t["axis_sigma_deg"][0] == 1.8
    assert t["topspin_rpm"][0] == pytest.approx(2400.0) and t["tilt"][0] == "6:00"
    assert "*0/8" in format_flight_table(t)
    stored = {0: {"axis": [0.0, 0.0, -1.0], "omega_rad_s": whole.omega_rad_s, "fold": 1, "ratio": 2.0,
                  "excess": 30.0, "trusted": True, "axis_sigma_deg": 1.8, "rps_sigma_pct": 0.2}}
    assert flight_table(_track(v), flagged, flight_spins=stored)["rpm"][0] == pytest.approx(2400.0)
    untrusted = replace(whole, ratio=1.1, trusted=False, fold_ratio=1.0, rate_trusted=False)
    t = flight_table(_track(v), flagged, flight_spins={0: untrusted})
    assert t["spin_from"][0] == "-" and not np.isfinite(t["rpm"][0])
    t = flight_table(_track(v), _spin((0, 0, -1), 30.0, v), flight_spins={0: whole})
    assert t["spin_from"][0] == "windows" and t["rpm"][0] == pytest.approx(1800.0)


def test_a_slow_ball_s_rate_comes_from_the_whole_flight_s_fold_where_its_windows_single_out_none():
    """A slow ball (10 rps): its windows give no trusted spin and rates that single out no fold of its
    period; its whole-flight spin, whose axis is not trusted over few turns, tells its fold from the
    others (``rate_trusted``): the period's rate at that fold fills ``period_rpm``, marked
    ``period_fold_from="flight"`` (``*`` in the printed table), and the spin columns stay NaN. A
    whole-flight spin whose fold the map cannot tell gives nothing, and a fold the windows single out
    stands."""
    import math
    from dataclasses import replace

    from spin.flight import FlightSpin

    v = (3000, 0)
    windows = _spin((0, 1, 0), 13.0, v, conf=0.2)  # 30 % off: within 7 % of no fold of the period
    periods = {0: (1 / 10.0, 0.6, 0.35)}
    slow = FlightSpin(axis=np.array([0.0, 0.0, -1.0]), omega_rad_s=2 * math.pi * 10.02, fold=1, ratio=2.0,
                      excess=30.0, trusted=False, axis_sigma_deg=1.8, rps_sigma_pct=0.7, turns=3.5,
                      fold_ratio=1.8, rate_trusted=True)
    t = flight_table(_track(v), windows, periods=periods, flight_spins={0: slow})
    assert t["spin_from"][0] == "-" and np.isnan(t["rpm"][0]) and np.isnan(t["axis_x"][0])
    assert t["period_fold_from"][0] == "flight" and t["period_rpm"][0] == pytest.approx(600.0)
    assert t["period_rpm_sigma"][0] == pytest.approx(600.0 * PERIOD_SIGMA_REPEATS_PCT * 0.1 / 0.35 / 100)
    text = format_flight_table(t)
    assert "no trusted axis: rate from the period" in text.splitlines()[1]
    assert f"*600 ± {t['period_rpm_sigma'][0]:.0f}" in text.splitlines()[1] and "1 marked *: its turn" in text
    # the image repeats twice a turn (fold 2): the rate is half the period's
    t = flight_table(_track(v), windows, periods={0: (1 / 20.0, 0.6, 0.35)},
                     flight_spins={0: {"axis": [0.0, 0.0, -1.0], "omega_rad_s": slow.omega_rad_s, "fold": 2,
                                       "trusted": False, "rate_trusted": True}})
    assert t["period_rpm"][0] == pytest.approx(600.0) and t["period_fold_from"][0] == "flight"
    assert t["period_rpm_sigma"][0] == pytest.approx(600.0 * 2 * PERIOD_SIGMA_REPEATS_PCT * 0.05 / 0.35 / 100)
    # a fold the map cannot tell, or a spin stored before rate_trusted was and not trusted: no rate
    for unsure in ({0: replace(slow, fold_ratio=1.02, rate_trusted=False)},
                   {0: {"axis": [0.0, 0.0, -1.0], "omega_rad_s": slow.omega_rad_s, "fold": 1, "trusted": False}}):
        t = flight_table(_track(v), windows, periods=periods, flight_spins=unsure)
        assert np.isnan(t["period_rpm"][0]) and t["period_fold_from"][0] == "-"
        assert "no trusted estimate" in format_flight_table(t).splitlines()[1]
    # windows whose median singles out a fold: theirs stands, whatever the whole flight says
    t = flight_table(_track(v), _spin((0, 1, 0), 5.1, v, conf=0.2), periods=periods,
                     flight_spins={0: slow})
    assert t["period_fold_from"][0] == "windows" and t["period_rpm"][0] == pytest.approx(300.0)
