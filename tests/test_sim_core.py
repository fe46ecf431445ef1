"""Simulator core: ESIM event generation, textures, sign convention, truth, determinism."""

import numpy as np
import pytest

import sim
from capture.events import EVENT_DTYPE, is_sorted
from sim.esim import SensorState, noise_events, simulate, step_events
from sim.scene import LOG_EPS, Ball, Camera, Scene


def warp_sharpness(ev, center, r, axis, omega, t_ref_s):
    """Variance of the polarity image of events warped to ``t_ref_s`` (docs/conventions.md model)."""
    x = ev["x"].astype(float) - center[0]
    y = ev["y"].astype(float) - center[1]
    ok = x * x + y * y < (0.95 * r) ** 2
    x, y, t = x[ok], y[ok], ev["t"][ok] * 1e-6
    pol = 2.0 * ev["p"][ok] - 1.0
    p = np.stack([x, y, -np.sqrt(r * r - x * x - y * y)], 1)
    n = np.asarray(axis, float) / np.linalg.norm(axis)
    ang = (omega * (t_ref_s - t))[:, None]
    # Rodrigues: rotate each point by its own angle about n
    q = p * np.cos(ang) + np.cross(n, p) * np.sin(ang) + np.outer(p @ n, n) * (1 - np.cos(ang))
    vis = q[:, 2] < 0
    img, _, _ = np.histogram2d(q[vis, 0], q[vis, 1], bins=int(2 * r), range=[[-r, r], [-r, r]], weights=pol[vis])
    return img.var()


@pytest.mark.parametrize("texture,rps,axis,projection", [
    ("volleyball", 100.0, (1.0, 1.0, 0.0), "orthographic"),
    ("soccer", 100.0, (0.3, -0.5, 0.8), "orthographic"),
    ("volleyball", 20.0, (0.0, -1.0, 0.2), "pinhole"),
])
def test_warp_at_true_spin_is_sharpest_and_sign_is_right(texture, rps, axis, projection):
    r = 50
    ev, tr = sim.spinning_ball(texture, rps=rps, axis=axis, radius_px=r, n_events=20000, seed=3,
                               projection=projection, focal_px=2000.0)
    t_ref = 0.5 * (ev["t"][0] + ev["t"][-1]) * 1e-6
    a, w, c = tr["axis"], tr["omega_rad_s"], tr["center"]
    best = warp_sharpness(ev, c, r, a, w, t_ref)
    assert best > 3.0 * warp_sharpness(ev, c, r, -a, w, t_ref)  # wrong sign: clearly blurred
    assert best > 1.3 * warp_sharpness(ev, c, r, a, 1.3 * w, t_ref)
    assert best > 1.3 * warp_sharpness(ev, c, r, a, 0.7 * w, t_ref)
    tilted = np.cross(a, [0.0, 0.0, 1.0] if abs(a[2]) < 0.9 else [1.0, 0.0, 0.0])
    tilted = a + 1.0 * tilted / np.linalg.norm(tilted)
    assert best > 1.2 * warp_sharpness(ev, c, r, tilted, w, t_ref)


def test_static_ball_without_noise_gives_no_events():
    ev, tr = sim.spinning_ball("volleyball", rps=0.0, radius_px=40, width=160, height=120,
                               n_events=1000, duration_s=0.05)
    assert ev.size == 0
    assert tr["n_events"] == 0


def test_uniform_spinning_ball_does_not_fire_at_silhouette():
    # a uniform ball spinning fast: shading is fixed in the camera frame and the rim is
    # anti-aliased by coverage, so nothing may change anywhere, rim included
    cam = Camera(120, 100)
    ball = Ball("logo", radius=30.3, center=[59.7, 50.2, 0], axis=[0.3, 0.4, 0.86], omega_rad_s=2 * np.pi * 300,
                texture_opts={"logo_albedo": 0.85})
    sensor = SensorState.new(120, 100, np.random.default_rng(0), mismatch_sigma=0.0, threshold=0.05)
    ev = simulate(Scene(cam, [ball]), sensor, 0.0, 0.004)
    assert ev.size == 0


def test_events_lie_on_the_ball_and_have_the_event_dtype():
    ev, tr = sim.spinning_ball("soccer", rps=50, axis=(0, 1, 1), radius_px=30, center=(70.3, 55.6),
                               width=150, height=110, n_events=15000, seed=1)
    assert ev.dtype == EVENT_DTYPE and ev.size == 15000 and is_sorted(ev)
    d = np.hypot(ev["x"] - tr["center"][0], ev["y"] - tr["center"][1])
    assert d.max() <= tr["radius_px"] + 1.0
    assert np.mean(d < tr["radius_px"] - 3) > 0.6  # spread over the face, not just the rim
    assert set(np.unique(ev["p"])) == {0, 1}


def test_step_events_interpolates_crossings_and_emits_several_per_step():
    ref = np.array([0.0, 0.0, 0.5])
    c = np.full(3, 0.15)
    L0 = np.array([0.0, 0.0, 0.5])
    L1 = np.array([1.0, -0.31, 0.6])
    t, i, p = step_events(L0, L1, 1.0, 2.0, ref, c, c)
    on = i == 0
    assert on.sum() == 6 and np.all(p[on] == 1)
    np.testing.assert_allclose(np.sort(t[on]), 1.0 + 0.15 * np.arange(1, 7))
    off = i == 1
    assert off.sum() == 2 and np.all(p[off] == 0)
    np.testing.assert_allclose(np.sort(t[off]), 1.0 + np.array([0.15, 0.30]) / 0.31)
    assert not np.any(i == 2)
    np.testing.assert_allclose(ref, [0.9, -0.3, 0.5])


def test_refractory_period_drops_close_events():
    ref = np.zeros(1)
    last = np.full(1, -np.inf)
    c = np.full(1, 0.1)
    t, i, p = step_events(np.zeros(1), np.ones(1), 0.0, 1e-3, ref, c, c, last, refractory_s=250e-6)
    # crossings every 100 µs; with a 250 µs dead time only every third survives
    np.testing.assert_allclose(t, [1e-4, 4e-4, 7e-4, 1e-3])
    np.testing.assert_allclose(ref, [1.0])


def test_event_counts_per_pixel_follow_log_intensity_change():
    w, h = 100, 80
    cam = Camera(w, h)
    ball = Ball("volleyball", radius=30, center=[49.5, 39.5, 0], axis=[0.2, 1, 0.3], omega_rad_s=2 * np.pi * 40,
                R0=np.eye(3))
    scene = Scene(cam, [ball])
    sensor = SensorState.new(w, h, np.random.default_rng(5), mismatch_sigma=0.03)
    t_end = 0.004
    ev = simulate(scene, sensor, 0.0, t_end)
    v, u = np.divmod(np.arange(w * h), w)
    L = np.log(scene.render(u.astype(float), v.astype(float), [0.0, t_end]) + LOG_EPS)
    flat = ev["y"].astype(int) * w + ev["x"]
    n_on = np.bincount(flat[ev["p"] == 1], minlength=w * h)
    n_off = np.bincount(flat[ev["p"] == 0], minlength=w * h)
    net = n_on * sensor.c_on - n_off * sensor.c_off
    change = L[1] - L[0]
    # the reference stays within one threshold of L: |change - net| < C+ + C-
    assert np.all(np.abs(change - net) < sensor.c_on + sensor.c_off + 1e-9)
    assert ev.size > 2000
    big = np.abs(change) > 1.0
    assert big.sum() > 20  # the check above covered pixels with many events
    on_big = change > 1.0
    assert np.all(n_on[on_big] >= np.floor((change[on_big] - sensor.c_on[on_big] - sensor.c_off[on_big]) / sensor.c_on[on_big]))


def test_same_seed_same_events_other_seed_differs():
    kw = dict(rps=30, axis=(1, 0, 0), radius_px=25, width=80, height=60, n_events=3000, noise_rate_hz=5.0, hot_pixels=2)
    a, ta = sim.spinning_ball("volleyball", seed=7, **kw)
    b, tb = sim.spinning_ball("volleyball", seed=7, **kw)
    c, _ = sim.spinning_ball("volleyball", seed=8, **kw)
    assert np.array_equal(a, b) and np.array_equal(ta["R0"], tb["R0"])
    assert not np.array_equal(a, c)


def test_truth_follows_conventions():
    ev, tr = sim.spinning_ball("volleyball", rps=-20, axis=(0, 0, 2), radius_px=20, center=(40, 30),
                               velocity_px_s=(2000, -1000), width=120, height=80, n_events=4000, t0_us=1000)
    np.testing.assert_allclose(tr["axis"], [0, 0, -1])
    assert tr["omega_rad_s"] == pytest.approx(2 * np.pi * 20) and tr["rps"] == pytest.approx(20)
    assert ev["t"][0] >= 1000 and tr["t_first_us"] == ev["t"][0]
    dt = (tr["t_first_us"] - 1000) * 1e-6
    np.testing.assert_allclose(tr["center"], [40 + 2000 * dt, 30 - 1000 * dt], atol=1e-9)
    np.testing.assert_allclose(tr["velocity_px_s"], [2000, -1000], rtol=1e-6)
    assert tr["radius_px"] == 20
    np.testing.assert_allclose(tr["R0"] @ tr["R0"].T, np.eye(3), atol=1e-12)


def test_noise_and_hot_pixels():
    ev, hot = noise_events(200, 100, 0, 100_000, np.random.default_rng(0), rate_hz_per_px=1.0, hot_pixels=3,
                           hot_rate_hz=5000.0)
    assert is_sorted(ev) and ev["t"].min() >= 0 and ev["t"].max() < 100_000
    counts = np.bincount(ev["y"].astype(int) * 200 + ev["x"], minlength=200 * 100)
    hot_flat = hot[:, 1] * 200 + hot[:, 0]
    assert np.all(counts[hot_flat] > 300)  # ~500 each
    assert 0.8 * 2000 < counts.sum() - counts[hot_flat].sum() < 1.2 * 2000  # 1 Hz x 20000 px x 0.1 s


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="unknown texture"):
        sim.spinning_ball("rugby", n_events=10)
    with pytest.raises(ValueError, match="axis"):
        sim.spinning_ball(axis=(0, 0, 0), n_events=10)
    with pytest.raises(TypeError, match="bogus"):
        sim.spinning_ball(n_events=10, bogus=1)
