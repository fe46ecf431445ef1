"""Warp geometry and the analytic gradient of the IWE contrast."""

import dataclasses

import numpy as np
import pytest

from spin.objective import BallEvents, IweGeometry, contrast, iwe_parts, lift_moving, warp
from spin.warp import rotate_quaternion


def _random_points(rng, n, r=50.0):
    ang = rng.uniform(0, 2 * np.pi, n)
    rad = r * np.sqrt(rng.uniform(0, 0.9, n))
    return np.stack([rad * np.cos(ang), rad * np.sin(ang), -np.sqrt(r * r - rad * rad)], axis=1)


def _rodrigues(p, r, w_rad_s, tau_s):
    """The estimator's warp (Rodrigues form) of sphere points ``p`` (N, 3), as (N, 3)."""
    ev = BallEvents(p[:, 0], p[:, 1], np.zeros(len(p)), np.asarray(tau_s, dtype=np.float64), np.ones(len(p)), r)
    return warp(ev, w_rad_s, (0.0, 0.0)).T


def test_quaternion_and_rodrigues_agree():
    rng = np.random.default_rng(1)
    p = _random_points(rng, 500)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angles = rng.uniform(-7, 7, 500)
    a = rotate_quaternion(p, axis, angles)
    b = _rodrigues(p, 50.0, 100.0 * axis, angles / 100.0)
    assert np.max(np.abs(a - b)) < 1e-9
    assert np.allclose(np.linalg.norm(a, axis=1), np.linalg.norm(p, axis=1))


def test_rotation_follows_right_hand_rule():
    # spin about +Z (camera forward): a point toward +X moves toward +Y (omega * cross(z, x) = y)
    p = np.array([[6.0, 0.0, -8.0]])
    q = _rodrigues(p, 10.0, np.array([0.0, 0.0, 100.0]), [1e-3])
    assert q[0, 1] > 0.59 and q[0, 0] < 6.0
    q2 = rotate_quaternion(p, np.array([0.0, 0.0, 1.0]), np.array([0.1]))
    assert np.allclose(q, q2)


def test_zero_omega_is_identity():
    rng = np.random.default_rng(2)
    p = _random_points(rng, 200)
    assert np.allclose(rotate_quaternion(p, np.array([0.0, 1.0, 0.0]), np.zeros(200)), p)
    ev = BallEvents(p[:, 0], p[:, 1], rng.uniform(0, 1e-3, 200), rng.uniform(-5e-4, 5e-4, 200),
                    np.ones(200), 50.0)
    q = warp(ev, np.zeros(3), (0.0, 0.0))
    assert np.allclose(q[0], p[:, 0]) and np.allclose(q[1], p[:, 1]) and np.allclose(q[2], p[:, 2])


def test_lift_is_on_camera_facing_half_sphere_with_moving_centre():
    # centre moves +100 px/s in x: at s = 0.03 s an event at x = 3 sits on the centre
    ev = BallEvents(np.array([0.0, 3.0, 3.0]), np.array([0.0, 0.0, 4.0]), np.array([0.0, 0.03, 0.0]),
                    np.zeros(3), np.ones(3), 5.0)
    (px, py, pz), dzdx, _, _ = lift_moving(ev, (100.0, 0.0))
    assert np.allclose(px, [0, 0, 3]) and np.allclose(py, [0, 0, 4])
    assert np.allclose(pz[:2], -5.0) and pz[2] < 0 and abs(pz[2]) <= 0.5 + 1e-9  # rim clamped at 0.1 r
    assert dzdx[2] == 0.0


@pytest.mark.parametrize("hemispheres", [False, True])
def test_analytic_gradient_matches_finite_differences(hemispheres):
    rng = np.random.default_rng(3)
    n, r = 4000, 40.0
    p = _random_points(rng, n, r)
    s = np.sort(rng.uniform(0, 2e-3, n))
    # events clustered on a few blobs so the IWE has structure
    ev = BallEvents(p[:, 0], p[:, 1], s, 1e-3 - s, rng.choice([-1.0, 1.0], n), r)
    geo = IweGeometry(r, 0.5, 1.5, hemispheres)
    w = np.array([300.0, -200.0, 500.0])
    v = np.array([400.0, -250.0])
    f, gw, gv = contrast(ev, w, v, geo)

    def fd(step, i, which):
        d = np.zeros(3 if which == "w" else 2)
        d[i] = step
        if which == "w":
            hi, lo = contrast(ev, w + d, v, geo, gradient=False), contrast(ev, w - d, v, geo, gradient=False)
        else:
            hi, lo = contrast(ev, w, v + d, geo, gradient=False), contrast(ev, w, v - d, geo, gradient=False)
        return (hi - lo) / (2 * step)

    # bilinear voting makes the objective piecewise smooth: small steps, compare whole vectors
    fd_w = np.array([fd(0.01, i, "w") for i in range(3)])
    fd_v = np.array([fd(1.0, i, "v") for i in range(2)])
    assert np.linalg.norm(fd_w - gw) < 0.05 * np.linalg.norm(gw)
    assert np.linalg.norm(fd_v - gv) < 0.05 * np.linalg.norm(gv)
    assert f > 0


def _ball_events(rng, n=3000, r=40.0):
    p = _random_points(rng, n, r)
    s = np.sort(rng.uniform(0, 2e-3, n))
    return BallEvents(p[:, 0], p[:, 1], s, 1e-3 - s, rng.choice([-1.0, 1.0], n), r)


@pytest.mark.parametrize("hemispheres", [False, True])
# the last two velocities push events off the ball: down-left, and right (where a half turn about z
# then holds the next IWE's events at its left edge, next to the first IWE's right edge)
@pytest.mark.parametrize("velocity", [(0.0, 0.0), (9000.0, -6000.0), (-20000.0, 0.0)])
def test_several_angular_velocities_in_one_pass_equal_one_at_a_time(hemispheres, velocity):
    ev = _ball_events(np.random.default_rng(4))
    geo = IweGeometry(ev.radius_px, 0.5, 1.2, hemispheres)
    ws = np.array([[300.0, -200.0, 500.0], [0.0, 0.0, np.pi / 1e-3], [0.0, 0.0, 0.0], [-900.0, 50.0, 10.0]])
    f, gw, gv = contrast(ev, ws, velocity, geo)
    assert f.shape == (4,) and gw.shape == (4, 3) and gv.shape == (4, 2)
    for i, w in enumerate(ws):
        f1, gw1, gv1 = contrast(ev, w, velocity, geo)
        assert f[i] == pytest.approx(f1, rel=1e-5)
        assert np.allclose(gw[i], gw1, rtol=1e-4, atol=1e-6 * np.abs(gw1).max())
        assert np.allclose(gv[i], gv1, rtol=1e-4, atol=1e-6 * np.abs(gv1).max())
    assert np.allclose(contrast(ev, ws, velocity, geo, gradient=False), f)


def test_contrast_is_the_variance_of_the_blurred_iwe():
    ev = _ball_events(np.random.default_rng(5))
    geo = IweGeometry(ev.radius_px, 0.5, 1.5)
    w = np.array([300.0, -200.0, 500.0])
    image = iwe_parts(ev, w, (0.0, 0.0), geo)[0]
    assert image.shape == geo.shape
    assert contrast(ev, w, (0.0, 0.0), geo, gradient=False) == pytest.approx(float(np.var(image, dtype=np.float64)),
                                                                            rel=1e-4)
    # the parts' IWEs are the IWEs of every other event
    even, odd = iwe_parts(ev, w, (0.0, 0.0), geo, 2)
    assert np.allclose(even, iwe_parts(ev.take(slice(0, None, 2)), w, (0.0, 0.0), geo)[0], atol=1e-5)
    assert np.allclose(odd, iwe_parts(ev.take(slice(1, None, 2)), w, (0.0, 0.0), geo)[0], atol=1e-5)
    assert np.allclose(even + odd, image, atol=1e-4)


@pytest.mark.parametrize("hemispheres", [False, True])
def test_coarse_scores_are_variances_of_nearest_pixel_iwes(hemispheres):
    # each score of the coarse search's table, recomputed the plain way: every event rotated by its own
    # angle about one direction (float64), rounded to its nearest IWE pixel, the image blurred
    from spin.objective import blur
    from spin.search import _lift_rows, direction_matrix, fibonacci_sphere, score_rows

    ev = _ball_events(np.random.default_rng(6), n=400)
    geo = IweGeometry(ev.radius_px, 0.3, 1.0, hemispheres, 2.0, margin_px=0)
    omegas = np.array([400.0, 1500.0, 6000.0])
    index = np.stack([np.arange(0, 400, 2), np.arange(1, 400, 2), np.arange(100, 300)])  # (R, N) events per row
    pts, tau, weight = _lift_rows(ev, index, (0.0, 0.0))
    directions = fibonacci_sphere(12)
    table = score_rows(pts, tau, weight, omegas, direction_matrix(directions, geo), geo)
    assert table.shape == (3, 13)
    h, width = geo.shape
    for r, omega in enumerate(omegas):
        p = pts[:, r].astype(np.float64)
        for d, n in enumerate([*directions, None]):
            if n is None:  # the last column: no rotation
                q = p
            else:
                phi = omega * tau[:, r].astype(np.float64)[:, None]
                q = p + np.sin(phi) * np.cross(n, p) + (1 - np.cos(phi)) * (n * (p @ n)[:, None] - p)
            u = q[:, 0] * geo.scale + geo.radius_px * geo.scale + geo.pad + 0.5
            v = q[:, 1] * geo.scale + geo.radius_px * geo.scale + geo.pad + 0.5
            if hemispheres:
                u += (q[:, 2] > 0) * geo.size
            image = np.zeros((h, width), np.float32)
            np.add.at(image, (v.astype(int), u.astype(int)), weight[:, r])
            expected = float(np.var(blur(image, geo.sigma, geo.truncate), dtype=np.float64))
            assert table[r, d] == pytest.approx(expected, rel=0.02)
    # the directions score apart: the table is not one value throughout
    assert np.ptp(table[:, :-1]) > 0.1 * table.max()


def test_contrast_refuses_non_finite_parameters_and_holds_points_of_a_bigger_ball_on_its_raster():
    ev = _ball_events(np.random.default_rng(7))
    geo = IweGeometry(ev.radius_px, 0.5, 1.5, True)
    for w, v in (([np.nan, 0.0, 300.0], (0.0, 0.0)), ([np.inf, 0.0, 0.0], (0.0, 0.0)),
                 ([300.0, 0.0, 0.0], (np.nan, 0.0))):
        with pytest.raises(ValueError, match="not finite"):
            contrast(ev, np.array(w), v, geo)
    for field in ("tau_s", "x_px", "s_s"):  # (a NaN time made the loops write outside the image)
        bad = np.array(getattr(ev, field))
        bad[::7] = np.nan
        with pytest.raises(ValueError, match="not finite"):
            contrast(dataclasses.replace(ev, **{field: bad}), np.array([[300.0, 0.0, 0.0], [0.0, 200.0, 0.0]]),
                     (0.0, 0.0), geo)
    # an IWE raster made for a smaller ball: its points are held on it, as the plain IWE holds them
    small = IweGeometry(0.6 * ev.radius_px, 0.5, 1.5, True)
    w = np.array([300.0, -200.0, 500.0])
    image = iwe_parts(ev, w, (0.0, 0.0), small)[0]
    assert contrast(ev, w, (0.0, 0.0), small, gradient=False) == pytest.approx(float(np.var(image, dtype=np.float64)),
                                                                              rel=1e-4)
