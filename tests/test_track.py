"""Track container and spin-window cutting."""

import numpy as np
import pytest

from capture.events import Track, make_events
from detect.track import spin_windows


def _track():
    t = np.arange(0, 10_001, 1000)
    return Track(t_us=t, cx=100 + 0.01 * t, cy=np.full(len(t), 50.0), r=np.full(len(t), 20.0),
                 vx=np.full(len(t), 1e4), vy=np.zeros(len(t)), score=np.ones(len(t)),
                 flight=np.zeros(len(t)))


def test_track_interpolates_and_extrapolates():
    tr = _track()
    cx, cy, r, vx, vy = tr.at(2500)
    assert cx == pytest.approx(125.0) and cy == 50 and r == 20 and vx == 1e4
    cx, *_ = tr.at(12_000)  # 2 ms after the end at 1e4 px/s -> +20 px
    assert cx == pytest.approx(200.0 + 20.0)
    assert Track.from_columns(tr.columns()).columns().keys() == tr.columns().keys()
    with pytest.raises(ValueError):
        Track.empty().at(0)


def test_a_track_without_sigmas_has_them_as_not_measured():
    tr = _track()  # made without sigma_px
    assert tr.sigma_px.dtype == np.float32 and len(tr.sigma_px) == len(tr) and np.isnan(tr.sigma_px).all()
    cols = {k: v for k, v in tr.columns().items() if k != "sigma_px"}
    assert np.isnan(Track.from_columns(cols).sigma_px).all()
    given = Track.from_columns({**cols, "sigma_px": np.arange(len(tr))})
    assert list(given.select(given.t_us >= 9000).sigma_px) == [9.0, 10.0]
    both = Track.concat([given, tr]).sigma_px
    assert both[len(tr) - 1] == 10.0 and np.isnan(both[len(tr):]).all()


def test_spin_windows_follow_the_moving_circle():
    tr = _track()
    rng = np.random.default_rng(0)
    t = np.sort(rng.integers(0, 10_000, 40_000))
    # half the events on the moving ball, half far away
    on = rng.random(len(t)) < 0.5
    ang = rng.uniform(0, 2 * np.pi, len(t)); rad = 19 * np.sqrt(rng.random(len(t)))
    x = np.where(on, 100 + 0.01 * t + rad * np.cos(ang), 600)
    y = np.where(on, 50 + rad * np.sin(ang), 400)
    ev = make_events(t, np.round(x), np.round(y), 1)
    wins = list(spin_windows(ev, tr, window_us=2000, min_events=100))
    assert [w.t_start_us for w in wins] == [0, 2000, 4000, 6000, 8000]
    for w in wins:
        assert np.all(w.events["x"] < 600)
        assert abs(len(w.events) - on[(t >= w.t_start_us) & (t < w.t_end_us)].sum()) <= 2
        assert w.center[0] == pytest.approx(100 + 0.01 * w.t_start_us)
    assert list(spin_windows(ev, tr, window_us=2000, min_events=10**6)) == []
    assert all(np.isnan(w.sigma_px) for w in wins)  # a track without sigmas: not known
    # with them, each window carries the row at its start, else the larger of the two rows around it (as
    # Track.at takes them; rows every 1,000 µs; a row not measured counts for nothing)
    sigma = 0.1 * np.arange(len(tr))
    sigma[5] = np.nan
    sig = Track.from_columns({**tr.columns(), "sigma_px": sigma})
    got = [w.sigma_px for w in spin_windows(ev, sig, window_us=2000, step_us=1500, min_events=100)]
    np.testing.assert_allclose(got, [0.0, 0.2, 0.3, 0.4, 0.6, 0.8, 0.9])  # starts 0, 1500, ..., 9000


def test_windows_lengthen_where_the_ball_fires_few_events():
    tr = _track()
    rng = np.random.default_rng(1)
    # sparse ball: about 100 events per ms
    t = np.sort(rng.integers(0, 10_000, 1000))
    ang = rng.uniform(0, 2 * np.pi, len(t)); rad = 19 * np.sqrt(rng.random(len(t)))
    ev = make_events(t, np.round(100 + 0.01 * t + rad * np.cos(ang)), np.round(50 + rad * np.sin(ang)), 1)
    assert list(spin_windows(ev, tr, window_us=1000, step_us=2000, min_events=300)) == []
    wins = list(spin_windows(ev, tr, window_us=1000, step_us=2000, min_events=300, max_window_us=5000))
    assert len(wins) >= 3
    for w in wins:
        # just long enough for min_events, and no ball event of the window left out
        in_window = (ev["t"] >= w.t_start_us) & (ev["t"] < w.t_end_us)
        assert len(w.events) == in_window.sum()
        assert 300 <= len(w.events) < 300 + (ev["t"] == w.t_end_us - 1).sum()
        assert 1000 < w.t_end_us - w.t_start_us <= 5000
        assert w.events["t"][-1] == w.t_end_us - 1
    # explicit starts give the same windows as the default grid, so a flight can be split
    from detect.track import window_starts_us

    grid = window_starts_us(tr, 2000)[0]
    parts = [list(spin_windows(ev, tr, window_us=1000, min_events=300, max_window_us=5000,
                               starts_us={0: g})) for g in (grid[:2], grid[2:])]
    joined = parts[0] + parts[1]
    assert [w.t_start_us for w in joined] == [w.t_start_us for w in wins]
    assert all(np.array_equal(a.events, b.events) for a, b in zip(joined, wins))


def test_flight_spans_in_order_of_appearance():
    t = np.array([0, 10, 20, 30, 40, 50])
    track = Track(t_us=t, cx=np.zeros(6), cy=np.zeros(6), r=np.ones(6), vx=np.zeros(6), vy=np.zeros(6),
                  score=np.ones(6), flight=[3, 3, 1, 1, 1, 7])
    ids, first, last = track.spans()
    assert list(ids) == [3, 1, 7] and list(first) == [0, 20, 50] and list(last) == [10, 40, 50]
    assert [len(a) for a in Track.empty().spans()] == [0, 0, 0]
