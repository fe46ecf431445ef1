"""Track container and spin-window cutting."""

import numpy as np
import pytest

from capture.events import make_events
from detect.track import Track, spin_windows


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
