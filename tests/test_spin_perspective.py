"""Spin of balls seen in perspective through a calibrated lens (``spin.estimate_spin(..., camera=)``).

The simulator's pinhole camera (``projection="pinhole"``) shows a ball off the optical axis
obliquely: its silhouette is an ellipse and its texture is foreshortened.  With the camera's
intrinsics the estimate stays accurate there (both circle conventions: the circle fitted to the
rendered silhouette, as a detector reports it, and the simulator's projected circle), and through
a distorting lens; the orthographic model on the same events is off by 10-20 deg and 30 %.
"""

import numpy as np
import pytest

import sim
import spin
from calib.intrinsics import Intrinsics
from sim.balls import make_ball
from sim.scene import Camera
from spin import lens

W, H, F = 1280, 720, 1000.0
K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])
PINHOLE = Intrinsics(K, np.zeros(5), W, H)
BARREL = Intrinsics(K, np.array([-0.25, 0.08, 0.0, 0.0, 0.0]), W, H)
RADIUS = 60.0
AXIS = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])


def _center(deg, direction=(-1.0, 0.0)):
    """Pixel of the direction ``deg`` off the optical axis, towards ``direction`` in the image."""
    d = np.asarray(direction) / np.linalg.norm(direction)
    return tuple(K[:2, 2] + F * np.tan(np.radians(deg)) * d)


def _ball(texture="volleyball", rps=100.0, deg=25.0, axis=AXIS, seed=0, **opts):
    opts = {"n_events": 30_000, **opts}
    return sim.spinning_ball(texture, rps=rps, axis=axis, radius_px=RADIUS, center=_center(deg), projection="pinhole",
                             focal_px=F, width=W, height=H, seed=seed, **opts)


def _errors(est, truth):
    axis_deg = np.degrees(np.arccos(np.clip(np.dot(est.axis, truth["axis"]), -1, 1)))
    return axis_deg, 100 * abs(est.omega_rad_s - truth["omega_rad_s"]) / truth["omega_rad_s"]


def _distort(camera, uv_px):
    """Pixels (N, 2) of the undistorted pinhole ``PINHOLE`` seen through ``camera``'s lens."""
    return camera.project(lens.unit_rays(PINHOLE, uv_px))


def _silhouette_circle(truth, camera=PINHOLE):
    """Least-squares circle through the edge of the rendered ball mask in ``camera``'s image.

    The mask is the simulator's coverage (>= 0.5) of the ball at its first event; edge points
    lie halfway between 4-neighbouring pixels inside and outside it.
    """
    scam = Camera(W, H, "pinhole", F)
    ball = make_ball(scam, texture=truth["texture"], radius_px=truth["radius_px"], center_px=truth["center"],
                     velocity_px_s=(0, 0), accel_px_s2=(0, 0), axis=(0, 0, 1), omega_rad_s=0.0, R0=np.eye(3))
    cu, cv = np.round(_distort(camera, [truth["center"]])[0]).astype(int)
    reach = int(1.5 * truth["radius_px"])
    u, v = np.meshgrid(np.arange(cu - reach, cu + reach + 1), np.arange(cv - reach, cv + reach + 1))
    seen = lens.normalised_coordinates(camera, np.column_stack([u.ravel(), v.ravel()])) * F + K[:2, 2:]
    mask = (ball.render(scam, seen[0], seen[1], [0.0], np.array([0.0, 0.0, -1.0]), 0.3)[1][0] >= 0.5).reshape(u.shape)
    edges = []
    for du, dv in ((1, 0), (0, 1)):
        a, b = mask[:mask.shape[0] - dv, :mask.shape[1] - du], mask[dv:, du:]
        iy, ix = np.nonzero(a != b)
        edges.append(np.column_stack([u[iy, ix] + 0.5 * du, v[iy, ix] + 0.5 * dv]))
    p = np.concatenate(edges)
    sol = np.linalg.lstsq(np.column_stack([2 * p, np.ones(len(p))]), (p * p).sum(1), rcond=None)[0]
    return sol[:2], float(np.sqrt(sol[2] + sol[:2] @ sol[:2]))


def _through_lens(events, camera):
    """Events of the undistorted pinhole ``PINHOLE`` as ``camera``'s distorting lens shows them,
    rounded to pixels (time order kept).

    Each event is first spread uniformly over its pixel: the lens maps the pinhole's pixel grid
    onto a grid of another pitch, and rounding the pixel centres alone leaves a moire of pixels
    that collect two events' sources or none.
    """
    uv = np.column_stack([events["x"], events["y"]]) + np.random.default_rng(0).uniform(-0.5, 0.5, (len(events), 2))
    uv = np.rint(_distort(camera, uv))
    out = events.copy()
    out["x"], out["y"] = uv[:, 0], uv[:, 1]
    return out


@pytest.mark.parametrize("deg", [0, 25])
@pytest.mark.parametrize("camera", [PINHOLE, BARREL], ids=["pinhole", "barrel"])
def test_viewing_cone_from_either_circle(deg, camera):
    truth = {"texture": "volleyball", "radius_px": RADIUS, "center": _center(deg, (-0.8, 0.6))}
    true_axis = lens.unit_rays(PINHOLE, [truth["center"]])[0]
    alpha = np.arctan(RADIUS / F)
    # the simulator's (projected) circle: the image of the centre, radius f tan(alpha)
    axis, a = lens.viewing_cone(camera, _distort(camera, [truth["center"]])[0], RADIUS, "projected")
    assert np.degrees(np.arccos(min(1.0, axis @ true_axis))) < 1e-3 and a == pytest.approx(alpha, rel=1e-9)
    # the detector's circle, fitted to the silhouette: an ellipse, larger off the axis
    center, radius = _silhouette_circle(truth, camera)
    axis, a = lens.viewing_cone(camera, center, radius, "detected")
    assert np.degrees(np.arccos(min(1.0, axis @ true_axis))) < 0.05 and a == pytest.approx(alpha, rel=0.005)
    if deg and camera is PINHOLE:
        assert radius > 1.15 * RADIUS


@pytest.mark.parametrize("camera", [PINHOLE, BARREL], ids=["pinhole", "barrel"])
def test_ball_coordinates_follow_a_ball_moving_parallel_to_the_image(camera):
    """Points of a (not spinning) ball moving at constant depth map to fixed ball coordinates: exactly
    through a pinhole, to first order in the motion through a distorting lens."""
    center, velocity = np.array(_center(25, (-0.8, 0.6))), np.array([20_000.0, -8000.0])  # undistorted, px/s
    view = lens.ball_view(camera, _distort(camera, [center])[0], RADIUS, "projected")
    c0 = lens.unit_rays(PINHOLE, [center])[0] * view.distance  # ball units
    v3 = np.array([*velocity * c0[2] / F, 0.0])
    # the tracker's velocity: in the distorted image
    ahead, behind = _distort(camera, [center + velocity * 1e-6, center - velocity * 1e-6])
    seen_velocity = (ahead - behind) / 2e-6
    offsets = np.random.default_rng(0).normal(size=(3000, 3))
    offsets *= view.radius / np.linalg.norm(offsets, axis=1, keepdims=True)
    for t_s in (0.0, 1e-3, 2e-3):
        c = c0 + v3 * t_s
        seen = offsets @ -c > view.radius * view.radius  # in front of the tangent plane through the rim
        uv = camera.project(c + offsets[seen])
        xy, hit = lens.ball_coordinates(view, uv, np.full(len(uv), t_s), seen_velocity)
        assert hit.mean() > 0.99
        error = np.abs(xy[:, hit] - (view.rotation @ offsets[seen][hit].T)[:2]).max()
        assert error < (1e-6 if camera is PINHOLE else 0.02)  # (undistortion to ~1e-4 px, near the rim)


@pytest.mark.parametrize("texture", ["volleyball", "soccer"])
@pytest.mark.parametrize("deg", [0, 15, 25])
def test_camera_recovers_the_spin_of_a_ball_off_the_axis(texture, deg):
    events, truth = _ball(texture, deg=deg, seed=deg)
    kw = dict(velocity=truth["velocity_px_s"], camera=PINHOLE)
    center, radius = _silhouette_circle(truth)
    for est in (spin.estimate_spin(events, center, radius, **kw),
                spin.estimate_spin(events, truth["center"], truth["radius_px"], circle="projected", **kw)):
        axis_deg, omega_pct = _errors(est, truth)
        assert axis_deg < 2.0 and omega_pct < 1.5 and est.confidence > 0.5
    if deg == 25:  # the orthographic model on the same events (either circle)
        for c, r in ((center, radius), (truth["center"], truth["radius_px"])):
            axis_deg, omega_pct = _errors(spin.estimate_spin(events, c, r, velocity=truth["velocity_px_s"]), truth)
            assert axis_deg > 6.0


def test_camera_models_lens_distortion():
    """Events of a barrel-distorted image (pinhole events remapped through the lens and rounded to
    pixels): accurate with the distortion, worse without."""
    events, truth = _ball("volleyball", deg=25, seed=3)
    seen = _through_lens(events, BARREL)
    center, radius = _silhouette_circle(truth, BARREL)
    kw = dict(velocity=truth["velocity_px_s"])
    with_lens = [spin.estimate_spin(seen, center, radius, camera=BARREL, **kw),
                 spin.estimate_spin(seen, _distort(BARREL, [truth["center"]])[0], truth["radius_px"], camera=BARREL,
                                    circle="projected", **kw)]
    for est in with_lens:
        axis_deg, omega_pct = _errors(est, truth)
        assert axis_deg < 2.0 and omega_pct < 2.0
    assert _errors(spin.estimate_spin(seen, center, radius, camera=PINHOLE, **kw), truth)[0] > 3.5


def test_camera_follows_a_moving_ball():
    events, truth = _ball("volleyball", rps=30, deg=25, seed=4, velocity_px_s=(8000.0, -3000.0), threshold=0.4)
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=truth["velocity_px_s"],
                             camera=PINHOLE, circle="projected")
    axis_deg, omega_pct = _errors(est, truth)
    assert axis_deg < 1.5 and omega_pct < 1.5
    np.testing.assert_allclose(est.velocity_px_s, truth["velocity_px_s"], atol=300.0)


def test_paper_method_takes_the_camera():
    """The paper's Adam ascent, started at the true spin (camera frame), stays near it with the camera
    and drifts to the orthographic model's maximum without."""
    events, truth = _ball("volleyball", deg=25, seed=5, n_events=8000, threshold=0.6)
    kw = dict(velocity=truth["velocity_px_s"], method="paper", iterations=300,
              init_w_rad_s=truth["axis"] * truth["omega_rad_s"])
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], camera=PINHOLE, circle="projected", **kw)
    axis_deg, omega_pct = _errors(est, truth)
    assert axis_deg < 4.0 and omega_pct < 4.0 and est.method == "paper"
    assert _errors(spin.estimate_spin(events, truth["center"], truth["radius_px"], **kw), truth)[0] > 8.0


def test_without_camera_the_model_is_orthographic():
    """``camera=None`` is the orthographic model, bit for bit; a near-orthographic camera (far away,
    long lens) on the axis gives nearly the same estimate."""
    events, truth = sim.spinning_ball("volleyball", rps=40, axis=AXIS, radius_px=40, n_events=8000, seed=1,
                                      threshold=0.6)
    kw = dict(velocity=truth["velocity_px_s"], sensor_size=(640, 480))
    ortho = spin.estimate_spin(events, truth["center"], truth["radius_px"], **kw)
    same = spin.estimate_spin(events, truth["center"], truth["radius_px"], camera=None, **kw)
    for name in ("axis", "omega_rad_s", "velocity_px_s", "contrast", "confidence", "n_events"):
        np.testing.assert_array_equal(getattr(same, name), getattr(ortho, name), err_msg=name)
    far = Intrinsics(np.array([[1e6, 0, truth["center"][0]], [0, 1e6, truth["center"][1]], [0, 0, 1]]), np.zeros(5),
                     640, 480)
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], camera=far, **kw)
    assert np.degrees(np.arccos(min(1.0, est.axis @ ortho.axis))) < 0.5
    assert est.omega_rad_s == pytest.approx(ortho.omega_rad_s, rel=0.005)


def test_camera_frame_priors_turn_into_the_ball_frame(monkeypatch):
    """A warm start (``prior_w_rad_s``, camera frame) reaches the estimator in the ball frame, and the
    estimate comes back in the camera frame."""
    import spin.estimate as estimate_mod

    events, truth = _ball("volleyball", deg=25, seed=6)
    w_true = truth["axis"] * truth["omega_rad_s"]
    seen = {}
    fast = estimate_mod.estimate_fast

    def spy(ev, velocity, **kw):
        seen["prior"] = kw["prior_w_rad_s"]
        return fast(ev, velocity, **kw)

    monkeypatch.setattr(estimate_mod, "estimate_fast", spy)
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=truth["velocity_px_s"],
                             camera=PINHOLE, circle="projected", prior_w_rad_s=w_true)
    view = lens.ball_view(PINHOLE, truth["center"], truth["radius_px"], "projected")
    np.testing.assert_allclose(seen["prior"], view.rotation @ w_true)
    assert np.degrees(np.arccos(np.clip(seen["prior"] @ w_true / truth["omega_rad_s"] ** 2, -1, 1))) > 20
    assert _errors(est, truth)[0] < 2.0


def test_estimate_windows_along_a_track_with_the_camera():
    """Windows of a ball moving 25 deg off the axis; the second starts warm from the first."""
    from capture.events import Track
    from detect.track import spin_windows

    events, truth = _ball("volleyball", rps=30, deg=25, seed=7, velocity_px_s=(8000.0, -3000.0), threshold=0.4)
    t0, t1 = int(events["t"][0]), int(events["t"][-1])
    (cx, cy), (vx, vy) = truth["center"], truth["velocity_px_s"]
    track = Track(t_us=[t0, t1], cx=[cx, cx + vx * (t1 - t0) * 1e-6], cy=[cy, cy + vy * (t1 - t0) * 1e-6],
                  r=[truth["radius_px"]] * 2, vx=[vx, vx], vy=[vy, vy], score=[1, 1], flight=[0, 0])
    windows = list(spin_windows(events, track, window_us=(t1 - t0) // 2 + 1, min_events=1000))
    estimates = spin.estimate_windows(windows, camera=PINHOLE, circle="projected")
    assert len(estimates) == len(windows) == 2
    for est in estimates:
        axis_deg, omega_pct = _errors(est, truth)
        assert axis_deg < 2.0 and omega_pct < 2.0


def test_replay_takes_the_event_camera_from_the_session_calibration(tmp_path, monkeypatch, two_crossings):
    import capture.pipeline.replay as replay_mod
    from calib.stereo import CameraPair
    from calib.store import event_camera
    from capture.session import create_session, open_session

    rec = two_crossings[0]
    w, h = 480, 320
    camera = Intrinsics(np.array([[400.0, 0, 239.5], [0, 400.0, 159.5], [0, 0, 1]]), np.zeros(5), w, h)
    sessions = {}
    for name, attrs in (("calibrated", {"calibration": CameraPair(event=camera).to_dict()}), ("plain", None),
                        ("other_size", {"calibration": CameraPair(event=Intrinsics(camera.K, camera.dist, 640, 480))
                                        .to_dict()})):
        with create_session(tmp_path / name, width=w, height=h, attrs=attrs) as writer:
            writer.append_events(rec.events)
        sessions[name] = tmp_path / name
    assert event_camera(open_session(sessions["plain"])) is None
    with pytest.raises(ValueError, match="calibrated for 640x480 px"):
        event_camera(open_session(sessions["other_size"]))
    options = replay_mod.ReplayOptions(window_us=2000, max_window_us=8000, step_us=8000, min_events=300)
    parts = []
    replay_mod.track_session(sessions["calibrated"], options, progress=False, on_part=parts.append)
    assert parts and all(np.array_equal(p.camera.K, camera.K) for p in parts)
    # the spin units hand the camera to the estimator
    used = []
    monkeypatch.setattr(spin, "estimate_windows", lambda windows, **kw: used.append(kw["camera"]) or [])
    replay_mod.spin_part(parts[0], options)
    replay_mod.spin_flight(rec.events, rec.truth_track(), options, camera=camera)
    assert used == [parts[0].camera, camera]
