"""Bad input to the spin estimator gives a clear SpinInputError."""

import numpy as np
import pytest

import spin
from capture.events import make_events


def _events(n=3000, cx=100.0, cy=80.0, r=30.0, seed=0):
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, 2 * np.pi, n)
    rad = r * np.sqrt(rng.uniform(0, 1, n))
    return make_events(np.sort(rng.integers(0, 2000, n)), cx + rad * np.cos(ang), cy + rad * np.sin(ang),
                       rng.integers(0, 2, n))


def test_too_few_events():
    ev = _events(50)
    with pytest.raises(spin.SpinInputError, match="only .* events inside the circle"):
        spin.estimate_spin(ev, (100, 80), 30, min_events=200)


def test_empty_circle():
    ev = _events()
    with pytest.raises(spin.SpinInputError, match="no events inside the circle"):
        spin.estimate_spin(ev, (400, 300), 30)


def test_circle_outside_sensor():
    ev = _events()
    with pytest.raises(spin.SpinInputError, match="outside the sensor"):
        spin.estimate_spin(ev, (700, 80), 30, sensor_size=(640, 480))
    with pytest.raises(spin.SpinInputError, match="outside the sensor"):
        spin.estimate_spin(ev, (-50, 80), 30)


def test_bad_radius_and_method_and_dtype():
    ev = _events()
    with pytest.raises(spin.SpinInputError, match="radius"):
        spin.estimate_spin(ev, (100, 80), 0)
    with pytest.raises(spin.SpinInputError, match="method"):
        spin.estimate_spin(ev, (100, 80), 30, method="magic")
    with pytest.raises(spin.SpinInputError, match="fields t, x, y, p"):
        spin.estimate_spin(np.zeros((10, 4)), (100, 80), 30)
    with pytest.raises(spin.SpinInputError, match="empty"):
        spin.estimate_spin(ev[:0], (100, 80), 30)


def test_spin_table_shapes_match_store_columns():
    from capture.events import SPIN_COLUMNS, spin_table
    est = spin.SpinEstimate(axis=np.array([0.0, 0.0, 1.0]), omega_rad_s=6.28, rps=1.0,
                            velocity_px_s=np.array([1.0, 2.0]), t_start_us=0, t_end_us=10, n_events=5,
                            contrast=1.0, converged=True, confidence=0.5, method="fast")
    cols = spin_table([est, est])
    assert set(cols) == set(SPIN_COLUMNS)
    for name, (dtype, shape) in SPIN_COLUMNS.items():
        assert cols[name].shape == (2, *shape)
        assert cols[name].dtype == np.dtype(dtype)
    assert spin_table([])["axis"].shape == (0, 3)
    assert spin_table(est)["rps"].tolist() == [1.0]


def test_long_windows_are_thinned_evenly_for_the_fast_method():
    from spin.estimate import prepare

    ev = _events(3000)
    ball, t_sel = prepare(ev, (100.0, 80.0), 33.0, thin_to=1000)
    assert len(ball) <= 1000 and len(ball) == len(t_sel)
    assert np.array_equal(t_sel, ev["t"][::3][:len(t_sel)])  # every third event (all lie on the ball)
    assert len(prepare(ev, (100.0, 80.0), 33.0)[0]) == 3000
    est = spin.estimate_spin(ev, (100.0, 80.0), 30.0, velocity=(0.0, 0.0), thin_to=1000)
    assert est.n_events <= 1000
    # only the events on the ball count (not the background elsewhere), after max_events
    background = _events(30_000, cx=400.0, cy=300.0, r=60.0, seed=1)
    both = np.sort(np.concatenate([ev, background]), order="t")
    ball, t_sel = prepare(both, (100.0, 80.0), 33.0, thin_to=1000, min_events=2500)
    assert 750 < len(ball) <= 1000
    ball, t_sel = prepare(both, (100.0, 80.0), 33.0, max_events=1500, thin_to=1000)
    assert len(ball) == 750 and t_sel[-1] <= ev["t"][1499]
    with pytest.raises(spin.SpinInputError, match="thin_to"):
        prepare(ev, (100.0, 80.0), 33.0, thin_to=0)
