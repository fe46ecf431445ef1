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


def test_non_finite_numbers():
    ev = _events()
    with pytest.raises(spin.SpinInputError, match="circle: .* must be finite"):
        spin.estimate_spin(ev, (np.nan, 80), 30)
    with pytest.raises(spin.SpinInputError, match="circle: .* must be finite"):
        spin.estimate_spin(ev, (100, 80), np.inf, velocity=(0.0, 0.0))
    with pytest.raises(spin.SpinInputError, match="velocity: .* not finite"):
        spin.estimate_spin(ev, (100, 80), 30, velocity=(np.nan, 0.0))
    with pytest.raises(spin.SpinInputError, match="t0_us: .* not finite"):
        spin.estimate_spin(ev, (100, 80), 30, t0_us=np.nan)


def _camera(width=640, height=480, K=None, dist=None):
    from calib.intrinsics import Intrinsics

    K = np.array([[300.0, 0.0, 319.5], [0.0, 300.0, 239.5], [0.0, 0.0, 1.0]]) if K is None else np.asarray(K, float)
    return Intrinsics(K, np.zeros(5) if dist is None else np.asarray(dist, float), width, height)


def test_camera_that_does_not_fit_the_events():
    ev = _events()
    with pytest.raises(spin.SpinInputError, match=r"events reach pixel .* outside the camera's 120x480 px"):
        spin.estimate_spin(ev, (100, 80), 30, camera=_camera(width=120))
    with pytest.raises(spin.SpinInputError, match="camera: size 640x480 px differs from the sensor size 1280x720"):
        spin.estimate_spin(ev, (100, 80), 30, camera=_camera(), sensor_size=(1280, 720))
    with pytest.raises(spin.SpinInputError, match="not invertible"):
        spin.estimate_spin(ev, (100, 80), 30, camera=_camera(K=[[300, 0, 0], [600, 0, 0], [0, 0, 1]]))
    with pytest.raises(spin.SpinInputError, match="not invertible"):
        spin.estimate_spin(ev, (100, 80), 30, camera=_camera(K=np.zeros((3, 3))))
    with pytest.raises(spin.SpinInputError, match="finite 3x3"):
        spin.estimate_spin(ev, (100, 80), 30, camera=_camera(K=[[np.nan, 0, 0], [0, 300, 0], [0, 0, 1]]))
    with pytest.raises(spin.SpinInputError, match="3 distortion coefficients"):
        spin.estimate_spin(ev, (100, 80), 30, camera=_camera(dist=[0.1, 0.0, 0.0]))


def test_bad_circle_with_a_camera():
    ev = _events()
    cam = _camera()
    with pytest.raises(spin.SpinInputError, match="outside the sensor 640x480"):
        spin.estimate_spin(ev, (700, 80), 30, camera=cam)
    with pytest.raises(spin.SpinInputError, match="no events inside the circle"):
        spin.estimate_spin(ev, (400, 300), 30, camera=cam)
    with pytest.raises(spin.SpinInputError, match="only .* events inside the circle"):
        spin.estimate_spin(_events(50), (100, 80), 30, camera=cam, min_events=200)
    with pytest.raises(spin.SpinInputError, match="circle: 'fitted' is not one of"):
        spin.estimate_spin(ev, (100, 80), 30, camera=cam, circle="fitted")
    with pytest.raises(spin.SpinInputError, match="viewing cone reaches behind the camera"):
        spin.estimate_spin(ev, (100, 80), 1000, camera=cam, circle="projected")


def test_camera_errors_reach_estimate_windows():
    from detect.track import SpinWindow

    ev = _events()
    win = SpinWindow(0, 2000, ev, (100.0, 80.0), 30.0, (0.0, 0.0), 0)
    assert spin.estimate_windows([win], camera=_camera(width=120)) == []
    with pytest.raises(spin.SpinInputError, match="outside the camera's"):
        spin.estimate_windows([win], camera=_camera(width=120), skip_errors=False)


def test_an_estimate_runs_on_one_blas_thread_and_gives_the_others_back(monkeypatch):
    # its matrix products are small: BLAS's other threads would only spin on the other cores
    from threadpoolctl import threadpool_info, threadpool_limits

    import sim
    from spin import fast

    from spin.estimate import _blas

    seen = []
    real = fast.estimate_fast
    known = {lib["filepath"] for lib in _blas().info() if lib["user_api"] == "blas"}  # NumPy's, which spin uses

    def spy(*args, **kwargs):
        seen.append([lib["num_threads"] for lib in threadpool_info() if lib["filepath"] in known])
        return real(*args, **kwargs)

    monkeypatch.setattr("spin.estimate.estimate_fast", spy)
    ev, truth = sim.spinning_ball("volleyball", rps=30, axis=(0.0, 0.0, 1.0), radius_px=30, n_events=5000, seed=1)
    with threadpool_limits(2, user_api="blas"):
        spin.estimate_spin(ev, truth["center"], truth["radius_px"], velocity=(0.0, 0.0))
        after = [lib["num_threads"] for lib in threadpool_info() if lib["filepath"] in known]
    assert seen and seen[0] and all(n == 1 for n in seen[0])
    assert after and all(n == 2 for n in after)


def test_one_blas_thread_is_held_while_any_estimate_runs():
    # two estimates overlapping in two threads: the first to end must not give the threads back under the
    # second, and the last to end gives back what was there before
    from threadpoolctl import threadpool_info, threadpool_limits

    from spin.estimate import _blas, _one_blas_thread

    known = {lib["filepath"] for lib in _blas().info() if lib["user_api"] == "blas"}  # NumPy's, which spin uses

    def blas_threads():
        return {lib["num_threads"] for lib in threadpool_info() if lib["filepath"] in known}

    with threadpool_limits(2, user_api="blas"):
        first, second = _one_blas_thread(), _one_blas_thread()
        first.__enter__()
        second.__enter__()
        first.__exit__(None, None, None)
        assert blas_threads() == {1}
        second.__exit__(None, None, None)
        assert blas_threads() == {2}
