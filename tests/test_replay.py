"""Offline replay's units: flights streamed out of a stored session, and work shared with worker processes."""

import os
import time

import numpy as np
import pytest

import capture.replay as replay_mod
import sim
from capture.replay import ReplayOptions, iter_flights, spin_units
from capture.session import create_session
from capture.workers import SharedWork
from detect import track_ball
from detect.track import spin_windows
from sim.esim import merge

W, H = 480, 320


@pytest.fixture(scope="module")
def two_flights(tmp_path_factory):
    """A session in which the ball crosses the sensor twice (two flights), and its events."""
    a = sim.flight(radius_px=12, width=W, height=H, duration_s=0.04, start_px=(-6.0, 150.0),
                   velocity_px_s=(13_000.0, -1500.0), rps=20, distractors=(), noise_rate_hz=1.0, hot_pixels=10,
                   seed=11)
    b = sim.flight(radius_px=12, width=W, height=H, duration_s=0.04, start_px=(-6.0, 220.0),
                   velocity_px_s=(13_000.0, -2500.0), rps=20, distractors=(), noise_rate_hz=1.0, hot_pixels=10,
                   seed=12, t0_us=70_000)
    events = merge(a.events, b.events)
    path = tmp_path_factory.mktemp("replay") / "session"
    with create_session(path, width=W, height=H) as w:
        w.append_events(events)
    return path, events


OPTIONS = ReplayOptions(window_us=2000, max_window_us=8000, step_us=4000, min_events=300)


@pytest.mark.parametrize("batch_events", [1 << 20, 7_000])
def test_flights_stream_out_in_order_with_the_whole_track(two_flights, monkeypatch, batch_events):
    path, events = two_flights
    monkeypatch.setattr(replay_mod, "BATCH_EVENTS", batch_events)  # small batches: flights end mid-stream
    flights = list(iter_flights(path, OPTIONS, progress=False))
    whole = track_ball(events, width=W, height=H)
    assert len(flights) == 2 == len(whole.flight_ids())
    assert [int(f.track.flight[0]) for f in flights] == whole.flight_ids().tolist()
    for f in flights:
        part = whole.select(whole.flight == f.track.flight[0])
        for name, col in f.track.columns().items():
            np.testing.assert_array_equal(col, getattr(part, name), err_msg=name)
        # only events near the ball are kept, all of them time-sorted
        assert 0 < len(f.events) < len(events) // 2
        assert np.all(np.diff(f.events["t"].astype(np.int64)) >= 0)


@pytest.mark.parametrize("batch_events", [1 << 20, 7_000])
def test_flight_events_give_the_same_spin_windows_as_all_events(two_flights, monkeypatch, batch_events):
    path, events = two_flights
    monkeypatch.setattr(replay_mod, "BATCH_EVENTS", batch_events)
    opts = dict(window_us=OPTIONS.window_us, step_us=OPTIONS.step_us, min_events=OPTIONS.min_events,
                max_events=OPTIONS.max_events, max_window_us=OPTIONS.max_window_us)
    n_windows = 0
    for f in iter_flights(path, OPTIONS, progress=False):
        mine = list(spin_windows(f.events, f.track, **opts))
        full = list(spin_windows(events, f.track, **opts))
        assert len(mine) == len(full) >= 2
        for a, b in zip(mine, full):
            assert (a.t_start_us, a.t_end_us, a.center, a.radius_px) == (b.t_start_us, b.t_end_us, b.center,
                                                                          b.radius_px)
            np.testing.assert_array_equal(a.events, b.events)
        n_windows += len(mine)
        # the flight's units cover all its windows, each with the events of its windows' span
        units = spin_units(f, OPTIONS)
        assert {w.t_start_us for w in full} <= {int(s) for u in units for s in u[2]}
        for ev, _, starts, _ in units:
            span = (f.events["t"] >= starts[0]) & (f.events["t"] < starts[-1] + OPTIONS.max_window_us)
            np.testing.assert_array_equal(ev, f.events[span])
    assert n_windows >= 4


def _slow_square(x):
    time.sleep(0.05)
    if x < 0:
        raise ValueError(f"negative unit {x}")
    return x * x, os.getpid()


def test_shared_work_returns_every_result_in_order_from_both_processes():
    with SharedWork(_slow_square, 2) as work:
        for i in range(60):
            work.add(i)
        out = work.results()
    assert [r for r, _ in out] == [i * i for i in range(60)]
    pids = {p for _, p in out}
    assert os.getpid() in pids and len(pids) == 2  # the caller and one worker process shared it


def test_shared_work_in_one_process_and_errors():
    with SharedWork(_slow_square, 1) as work:
        for i in range(3):
            work.add(i)
        assert [r for r, _ in work.results()] == [0, 1, 4]
        assert {p for _, p in work.results()} == {os.getpid()}
    with SharedWork(_slow_square, 2) as work:
        work.add(2)
        work.add(-1)
        with pytest.raises(ValueError, match="negative unit -1"):
            work.results()
    with pytest.raises(ValueError, match="workers must be positive"):
        SharedWork(_slow_square, 0)
