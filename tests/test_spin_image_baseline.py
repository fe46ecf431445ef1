"""The image baseline (two-frame registration) recovers a slow spin and aliases a fast one."""

import numpy as np

import sim
from sim.balls import make_ball
from sim.scene import Camera, Scene
from spin.image_baseline import estimate_image_pair


def _frames(rps, fps, axis=(0.3, -0.5, 0.81)):
    _, truth = sim.spinning_ball("volleyball", rps=rps, axis=axis, radius_px=40, width=160, height=120,
                                 n_events=50, seed=3)
    cam = Camera(160, 120, "orthographic", 800.0)
    ball = make_ball(cam, texture="volleyball", radius_px=40, center_px=truth["center"], velocity_px_s=(0, 0),
                     accel_px_s2=(0, 0), axis=truth["axis"], omega_rad_s=truth["omega_rad_s"], R0=truth["R0"])
    t = np.array([0.0, 1.0 / fps])
    v, u = np.mgrid[0:120, 0:160]
    frames = Scene(cam, [ball]).render(u.ravel().astype(float), v.ravel().astype(float), t).reshape(2, 120, 160)
    c = ball.circle(cam, t)
    return frames, c, truth


def test_image_baseline_recovers_slow_spin():
    frames, c, truth = _frames(rps=10, fps=240)
    w = estimate_image_pair(frames[0], frames[1], 1 / 240, tuple(c[0]), tuple(c[1]), grid_pixels=500)
    omega = np.linalg.norm(w)
    assert np.degrees(np.arccos(np.dot(w / omega, truth["axis"]))) < 5.0
    assert abs(omega - truth["omega_rad_s"]) / truth["omega_rad_s"] < 0.05


def test_image_baseline_cannot_see_more_than_half_a_turn_per_frame():
    frames, c, truth = _frames(rps=100, fps=120)  # 0.83 turn per frame
    w = estimate_image_pair(frames[0], frames[1], 1 / 120, tuple(c[0]), tuple(c[1]), grid_pixels=500)
    assert np.linalg.norm(w) <= np.pi * 120 * 1.01 < truth["omega_rad_s"]
