"""Offline replay's units: flights streamed out of a stored session into spin parts."""

import numpy as np
import pytest

import capture.pipeline.replay as replay_mod
from capture.pipeline.replay import ReplayOptions, track_session
from capture.session import Session, create_session, open_session
from detect import track_ball
from detect.track import spin_windows, window_starts_us
from sim.esim import merge

W, H = 480, 320


@pytest.fixture(scope="module", params=["one after the other", "at once"])
def two_flights(request, tmp_path_factory, two_crossings, two_balls_at_once):
    """A session with two flights, and its events: the ball crossing the sensor twice, or two balls
    crossing it at the same time."""
    a, b = two_crossings if request.param == "one after the other" else two_balls_at_once
    events = merge(a.events, b.events)
    path = tmp_path_factory.mktemp("replay") / "session"
    with create_session(path, width=W, height=H) as w:
        w.append_events(events)
    return path, events


OPTIONS = ReplayOptions(window_us=2000, max_window_us=8000, step_us=4000, min_events=300, windows_per_unit=3)
WINDOW_OPTS = dict(window_us=OPTIONS.window_us, step_us=OPTIONS.step_us, min_events=OPTIONS.min_events,
                   max_events=OPTIONS.max_events, max_window_us=OPTIONS.max_window_us)


def _track_with_parts(path, monkeypatch, batch_events):
    """Track the session in batches; returns the track, the parts and the batches read before each."""
    monkeypatch.setattr(replay_mod, "BATCH_EVENTS", batch_events)
    read = [0]
    iter_events = Session.iter_events

    def counting(self, *args, **kwargs):
        for batch in iter_events(self, *args, **kwargs):
            read[0] += 1
            yield batch

    monkeypatch.setattr(Session, "iter_events", counting)
    parts, when = [], []
    track = track_session(path, OPTIONS, progress=False, on_part=lambda p: (parts.append(p), when.append(read[0])))
    return track, parts, when, read[0]


@pytest.mark.parametrize("batch_events", [1 << 20, 7_000])
def test_parts_hold_every_window_of_every_flight_with_what_it_needs(two_flights, monkeypatch, batch_events):
    path, events = two_flights
    track, parts, when, n_batches = _track_with_parts(path, monkeypatch, batch_events)
    whole = track_ball(events, width=W, height=H)
    assert len(whole.flight_ids()) == 2
    for name, col in whole.columns().items():
        np.testing.assert_array_equal(getattr(track, name), col, err_msg=name)
    # every window start of every flight in exactly one part, in order, parts of windows_per_unit
    starts = window_starts_us(whole, OPTIONS.step_us)
    for fid, expected in starts.items():
        mine = [p for p in parts if p.flight == fid]
        np.testing.assert_array_equal(np.concatenate([p.starts_us for p in mine]), expected)
        assert all(len(p.starts_us) == OPTIONS.windows_per_unit for p in mine[:-1])
    # a part's windows are exactly those that all events and the whole track give
    n_windows = 0
    for p in parts:
        full = list(spin_windows(events, whole, starts_us={p.flight: p.starts_us}, **WINDOW_OPTS))
        assert len(p.windows) == len(full)
        for a, b in zip(p.windows, full):
            assert (a.t_start_us, a.t_end_us, a.center, a.radius_px, a.velocity_px_s, a.flight, a.sigma_px) == (
                b.t_start_us, b.t_end_us, b.center, b.radius_px, b.velocity_px_s, b.flight, b.sigma_px)
            np.testing.assert_array_equal(a.events, b.events)
        n_windows += len(full)
    assert n_windows >= 8
    # streamed: the parts of a flight that ended well before the session did came out while tracking went on
    if batch_events < len(events) and whole.spans()[2][0] < events["t"][-1] - 20_000:
        first = [w for p, w in zip(parts, when) if p.flight == whole.flight_ids()[0]]
        assert first[0] < n_batches and first[-1] < n_batches


def test_replay_of_parts_equals_spin_on_all_events(two_flights, monkeypatch):
    path, events = two_flights
    monkeypatch.setattr(replay_mod, "WORKERS_MIN_SPAN_S", 0.0)  # a worker process even for this short session
    options = ReplayOptions(**{**OPTIONS.__dict__, "workers": 2})
    parts = []
    track_session(path, options, progress=False, on_part=parts.append)
    result = replay_mod.replay(path, options=options, progress=False)
    whole = track_ball(events, width=W, height=H)
    # the same windows in the same units (a unit's windows warm-start from each other), cut from all events
    ref = [replay_mod.spin_flight(events, whole.select(whole.flight == p.flight), options, p.starts_us)
           for p in parts]
    ref = {k: np.concatenate([r[k] for r in ref]) for k in ref[0]}
    assert len(ref["t_start_us"]) >= 8
    mine = np.lexsort((result.spin["flight"], result.spin["t_start_us"]))  # rows by time, then flight
    theirs = np.lexsort((ref["flight"], ref["t_start_us"]))
    for name, col in ref.items():
        np.testing.assert_array_equal(result.spin[name][mine], col[theirs], err_msg=name)


def test_windows_starting_in_a_gap_between_track_rows_keep_their_events(tmp_path, monkeypatch, two_crossings):
    """A slice the tracker misses leaves a gap between rows longer than the longest window."""
    ev = two_crossings[0].events
    rows = track_ball(ev, width=W, height=H)
    s0 = int(rows.t_us[8]) + 1000  # thin out the slice after row 8: no fit there
    hole = (ev["t"] >= s0) & (ev["t"] < s0 + 2000)
    ev = ev[~hole | (np.random.default_rng(0).random(len(ev)) < 0.001)]
    whole = track_ball(ev, width=W, height=H)
    assert np.diff(whole.t_us).max() >= 4000
    path = tmp_path / "gap"
    with create_session(path, width=W, height=H) as w:
        w.append_events(ev)
    opts = ReplayOptions(window_us=1000, max_window_us=1000, step_us=2000, min_events=5, windows_per_unit=3)
    monkeypatch.setattr(replay_mod, "BATCH_EVENTS", 5000)
    parts = []
    track_session(path, opts, progress=False, on_part=parts.append)
    kw = dict(window_us=1000, step_us=2000, min_events=5, max_events=opts.max_events, max_window_us=1000)
    n = 0
    for p in parts:
        mine = {w.t_start_us: len(w.events) for w in p.windows}
        full = {w.t_start_us: len(w.events) for w in spin_windows(ev, whole, starts_us={p.flight: p.starts_us}, **kw)}
        assert mine == full
        n += len(full)
    assert n >= 10


def test_events_near_the_ball_are_those_of_the_rows_circles():
    from capture.events import EVENT_DTYPE, Track

    rng = np.random.default_rng(8)
    n, m, longest_us = 60_000, 40, 4000
    t_row = np.sort(rng.choice(np.arange(10_000, 80_000), m, replace=False))
    t_row[5] = t_row[4]  # two rows at one time: the later one counts
    rows = Track(t_us=t_row, cx=rng.uniform(100, 500, m), cy=rng.uniform(100, 400, m), r=rng.uniform(10, 60, m),
                 vx=rng.uniform(-3000, 3000, m), vy=rng.uniform(-3000, 3000, m), score=np.ones(m),
                 flight=np.zeros(m, np.int64))
    rows.cx[4], rows.cy[4] = 600.0, 450.0  # far from row 5's centre
    ev = np.zeros(n, EVENT_DTYPE)
    ev["t"] = rng.integers(0, 100_000, n)
    ev["x"], ev["y"] = rng.integers(0, 640, n), rng.integers(0, 480, n)
    # events on a row's centre at the boundaries: before the first row, at rows' times (row 5's
    # centre at the time rows 4 and 5 share), at the end of the last row's reach and just before it
    end = t_row[-1] + longest_us
    last_at = lambda t: (rows.cx[-1] + rows.vx[-1] * (t - t_row[-1]) * 1e-6, rows.cy[-1] + rows.vy[-1] * (t - t_row[-1]) * 1e-6)
    fixed = [(t_row[0] - 1, rows.cx[0], rows.cy[0]), (t_row[0], rows.cx[0], rows.cy[0]), (t_row[4], rows.cx[5], rows.cy[5]),
             (t_row[4], rows.cx[4], rows.cy[4]), (t_row[17], rows.cx[17], rows.cy[17]), (end - 1, *last_at(end - 1)),
             (end, *last_at(end))]
    for k, (t, cx, cy) in enumerate(fixed):
        ev[k] = (t, round(cx), round(cy), 1)
    ev = ev[np.argsort(ev["t"], kind="stable")]
    ev.setflags(write=False)  # (a batch read from the store may be read-only)
    got = replay_mod._near_ball(ev["t"], ev["x"], ev["y"], rows, longest_us)
    # each event against the last row at or before it, in NumPy
    t = ev["t"]
    i = np.searchsorted(t_row, t, side="right") - 1
    ends = np.append(t_row[1:], end)
    ic = np.clip(i, 0, None)
    dt_s = (t - t_row[ic]) * 1e-6
    dx = ev["x"] - (rows.cx[ic] + rows.vx[ic] * dt_s)
    dy = ev["y"] - (rows.cy[ic] + rows.vy[ic] * dt_s)
    reach = replay_mod.REACH_MARGIN[0] * rows.r[ic] + replay_mod.REACH_MARGIN[1]
    expect = np.flatnonzero((i >= 0) & (t < ends[ic]) & (dx * dx + dy * dy <= reach * reach))
    assert len(expect) > 500
    np.testing.assert_array_equal(got, expect)
    kept = {(int(a), int(b), int(c)) for a, b, c in zip(t[got], ev["x"][got], ev["y"][got])}
    on = [(int(tf), round(cx), round(cy)) in kept for tf, cx, cy in fixed]
    assert on == [False, True, True, False, True, True, False]


def test_parts_cut_mid_flight_carry_the_whole_track_s_circle_sigma(tmp_path, monkeypatch):
    """A flight longer than the tracker's smoothing lag is handed out while it goes on, a part's last
    window at times starting on the last final row: each window's circle sigma (which the spin's
    uncertainty and trust take in) is the one the whole track gives."""
    import sim

    rec = sim.flight(radius_px=14, width=W, height=H, duration_s=0.3, rps=20, start_px=(-6.0, 150.0),
                     velocity_px_s=(1600.0, -100.0), seed=5, distractors=(), noise_rate_hz=1.0, hot_pixels=10)
    path = tmp_path / "long"
    with create_session(path, width=W, height=H) as w:
        w.append_events(rec.events)
    whole = track_ball(rec.events, width=W, height=H)
    monkeypatch.setattr(replay_mod, "BATCH_EVENTS", 5000)
    opts = ReplayOptions(window_us=2000, max_window_us=8000, step_us=2000, min_events=300, windows_per_unit=1)
    parts = []
    track_session(path, opts, progress=False, on_part=parts.append)
    on_rows = 0
    for p in parts:
        full = list(spin_windows(rec.events, whole, starts_us={p.flight: p.starts_us}, window_us=2000, step_us=2000,
                                 min_events=300, max_events=opts.max_events, max_window_us=8000))
        assert [w.sigma_px for w in p.windows] == [w.sigma_px for w in full]
        on_rows += sum(int(w.t_start_us) in set(whole.t_us.tolist()) for w in full)
    assert len(parts) > 100 and on_rows > 50 and np.isfinite([w.sigma_px for p in parts for w in p.windows]).all()


def test_a_flight_the_tracker_drops_has_no_period(tmp_path):
    """A bat's face that started a flight and was lost young (``detect_bench`` row ``paddle``, seed 10:
    the tracker drops it, see ``tests/test_detect_sim.py``) gets no period in the stored results: a
    flight's whole-flight work is handed out for each flight of the track, as a batch's
    ``session_flights`` finds them."""
    from test_detect_sim import paddle_flight

    rec = paddle_flight(10)
    path = tmp_path / "paddle"
    with create_session(path, width=640, height=480) as w:
        w.append_events(rec.events)
    flights = []
    track = track_session(path, progress=False, on_part=lambda part: None,
                          on_flight=lambda part: flights.append(part.flight))
    assert track.flight_ids().tolist() == [1] and flights == [1]  # flight 0 (the bat's) dropped


def test_a_sparse_ball_whose_windows_give_no_spin_gets_its_spin_from_the_whole_flight(tmp_path):
    """A tennis ball (two seams) at 30 rps through nine turns: no window of its flight is trusted, so replay
    finds its spin from all its events at its period's speed (``spin.flight``), stores it, and the flight
    table takes it (``spin_from == "flight"``): the axis within 5 deg, the rate within 1 %. (The demo's
    volleyball, whose windows give its spin, gets none: ``tests/test_demo.py``.)"""
    import sim
    from capture.pipeline.replay import replay
    from capture.results import session_results

    rec = sim.flight("tennis", rps=30.0, axis=(0.5, -0.6, 0.62), radius_px=18.0, width=320, height=240,
                     duration_s=0.3, distractors=(), sensor="realistic", seed=4)
    path = tmp_path / "tennis"
    with create_session(path, width=320, height=240) as w:
        w.append_events(rec.events)
    result = replay(path, progress=False)
    assert len(result.spin["confidence"]) > 5 and (result.spin["confidence"] < 0.5).all()
    whole = open_session(path).attrs["flight_spins"]["0"]
    assert whole["trusted"] and whole["omega_rad_s"] / (2 * np.pi) == pytest.approx(30.0, rel=0.01)
    assert np.degrees(np.arccos(np.clip(np.dot(whole["axis"], rec.truth["axis"]), -1, 1))) < 5.0
    flights, _ = session_results(path)
    assert flights["spin_from"].tolist() == ["flight"] and flights["rpm"][0] == pytest.approx(1800.0, rel=0.01)
