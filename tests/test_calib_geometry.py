"""Intrinsics, stereo extrinsics, homography and circle mapping on simulated views with known geometry."""

import json

import cv2
import numpy as np
import pytest

from calib import (
    CalibrationError, CameraPair, Extrinsics, Intrinsics, accumulate_events, calibrate_charuco,
    calibrate_checkerboard, calibrate_from_points, calibrate_stereo, charuco_board, checkerboard_points,
    find_checkerboard, fit_homography,
)
from capture.events import make_events

PATTERN = (8, 6)
SQUARE_M = 0.03


def K_of(f, w, h):
    return np.array([[f, 0, (w - 1) / 2 + 3.0], [0, f * 1.002, (h - 1) / 2 - 2.0], [0, 0, 1.0]])


def board_poses(n, rng, z=(0.55, 0.8)):
    """Board poses (rvec, tvec) with the board roughly centred in front of the camera."""
    poses = []
    for _ in range(n):
        rvec = np.array([rng.uniform(-0.45, 0.45), rng.uniform(-0.45, 0.45), rng.uniform(-0.3, 0.3)])
        R = cv2.Rodrigues(rvec)[0]
        centre = np.array([(PATTERN[0] - 1) * SQUARE_M / 2, (PATTERN[1] - 1) * SQUARE_M / 2, 0])
        t = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.04, 0.04), rng.uniform(*z)]) - R @ centre
        poses.append((rvec, t))
    return poses


def render_checkerboard(K, w, h, rvec, tvec, sq_px=40):
    """Ideal image of the checkerboard (white margin of one square) seen by a pinhole camera."""
    nx, ny = PATTERN[0] + 1, PATTERN[1] + 1
    m = sq_px
    tex = np.full((ny * sq_px + 2 * m, nx * sq_px + 2 * m), 255, np.uint8)
    for j in range(ny):
        for i in range(nx):
            if (i + j) % 2 == 0:
                tex[m + j * sq_px: m + (j + 1) * sq_px, m + i * sq_px: m + (i + 1) * sq_px] = 0
    s = SQUARE_M / sq_px
    c0 = m + sq_px - 0.5  # texture coordinate of the first inner corner
    B = np.array([[s, 0, -c0 * s], [0, s, -c0 * s], [0, 0, 1.0]])
    R = cv2.Rodrigues(rvec)[0]
    M = K @ np.column_stack([R[:, 0], R[:, 1], tvec]) @ B
    return cv2.warpPerspective(tex, M, (w, h), flags=cv2.INTER_AREA, borderValue=30)


def corner_error(found, truth):
    """Mean corner error, allowing OpenCV's 180-degree ordering flip."""
    return min(np.linalg.norm(found - truth, axis=1).mean(), np.linalg.norm(found[::-1] - truth, axis=1).mean())


def test_checkerboard_images_calibrate_gopro_intrinsics():
    w, h = 640, 480
    K = K_of(520.0, w, h)
    rng = np.random.default_rng(1)
    poses = board_poses(8, rng)
    imgs = [render_checkerboard(K, w, h, r, t) for r, t in poses]
    obj = checkerboard_points(PATTERN, SQUARE_M)
    truth = Intrinsics(K=K, dist=np.zeros(5), width=w, height=h)
    errs = [corner_error(find_checkerboard(im, PATTERN), truth.project(obj, r, t)) for im, (r, t) in zip(imgs, poses)]
    intr, used = calibrate_checkerboard(imgs + [np.zeros((h, w), np.uint8)], PATTERN, SQUARE_M)
    f_err = abs(intr.focal_px - 520.0 * 1.001) / 520.0
    print(f"checkerboard: corner err {np.mean(errs):.3f} px, f err {100 * f_err:.3f} %, "
          f"c err {np.abs(intr.K[:2, 2] - K[:2, 2]).max():.2f} px, rms {intr.rms_px:.3f} px")
    assert used == list(range(8))  # the blank image is skipped
    assert np.mean(errs) < 0.15
    assert f_err < 0.005
    assert np.abs(intr.K[:2, 2] - K[:2, 2]).max() < 3.0
    with pytest.raises(CalibrationError, match="found in 0 images"):
        calibrate_checkerboard([np.zeros((h, w), np.uint8)] * 3, PATTERN, SQUARE_M)


def test_charuco_partial_views_calibrate():
    board = charuco_board((7, 5), 0.04, 0.03)
    tex = board.generateImage((700, 500), marginSize=0)
    s = 0.04 / 100
    B = np.array([[s, 0, 0.5 * s], [0, s, 0.5 * s], [0, 0, 1.0]])
    w, h = 640, 480
    K = K_of(480.0, w, h)
    rng = np.random.default_rng(3)
    imgs = []
    for _ in range(12):
        rvec = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-0.2, 0.2)])
        R = cv2.Rodrigues(rvec)[0]
        t = np.array([rng.uniform(-0.05, 0.05), 0, rng.uniform(0.6, 0.8)]) - R @ np.array([0.14, 0.10, 0])
        M = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ B
        imgs.append(cv2.warpPerspective(tex, M, (w, h), flags=cv2.INTER_AREA, borderValue=255))
    intr, used = calibrate_charuco(imgs, board)
    f_err = abs(intr.focal_px - 480.0 * 1.001) / 480.0
    print(f"charuco: {len(used)} views, f err {100 * f_err:.3f} %, rms {intr.rms_px:.3f} px")
    assert len(used) >= 10 and f_err < 0.015


def test_event_camera_blinking_checkerboard():
    w, h = 320, 240
    K = K_of(300.0, w, h)
    rng = np.random.default_rng(7)
    (rvec, tvec), = board_poses(1, rng, z=(0.45, 0.5))
    img = render_checkerboard(K, w, h, rvec, tvec)
    # blinking screen: each pixel fires events in proportion to its brightness, plus noise and hot pixels
    lam = 4.0 * (img.astype(float) - 30).clip(0) / 225
    n = rng.poisson(lam).ravel()
    idx = np.repeat(np.arange(w * h), n)
    noise = rng.integers(0, w * h, idx.size // 50)
    hot = np.repeat(rng.integers(0, w * h, 5), 500)
    idx = np.concatenate([idx, noise, hot])
    ev = make_events(np.sort(rng.integers(0, 200_000, idx.size)), idx % w, idx // w, rng.integers(0, 2, idx.size))
    acc = accumulate_events(ev, w, h)
    found = find_checkerboard(acc, PATTERN)
    assert found is not None
    truth = Intrinsics(K=K, dist=np.zeros(5), width=w, height=h).project(checkerboard_points(PATTERN, SQUARE_M), rvec, tvec)
    err = corner_error(found, truth)
    print(f"event-camera blinking board: corner err {err:.3f} px")
    assert err < 0.5


def make_rig():
    frame = Intrinsics(K=K_of(1400.0, 1920, 1080), dist=np.array([-0.05, 0.02, 0, 0, 0]), width=1920, height=1080)
    event = Intrinsics(K=K_of(1000.0, 1280, 720), dist=np.array([-0.08, 0.05, 0, 0, 0]), width=1280, height=720)
    R = cv2.Rodrigues(np.array([0.01, -0.06, 0.005]))[0]
    T = np.array([-0.15, 0.01, 0.02])  # event camera 15 cm to the right of the GoPro
    return frame, event, Extrinsics(R=R, T=T)


def test_stereo_recovers_known_geometry_and_maps_circles():
    frame, event, truth = make_rig()
    rng = np.random.default_rng(11)
    obj = checkerboard_points(PATTERN, SQUARE_M * 3)
    objs, pa, pb = [], [], []
    for _ in range(20):
        rvec = rng.uniform(-0.6, 0.6, 3)
        R = cv2.Rodrigues(rvec)[0]
        t = np.array([rng.uniform(-0.3, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(1.6, 2.6)]) - R @ obj.mean(axis=0)
        Xf = obj @ R.T + t
        Xe = Xf @ truth.R.T + truth.T
        objs.append(obj)
        pa.append(frame.project(Xf) + rng.normal(0, 0.2, (len(obj), 2)))
        pb.append(event.project(Xe) + rng.normal(0, 0.2, (len(obj), 2)))
    fi = calibrate_from_points(objs, pa, (1920, 1080), fix_k3=True)
    ei = calibrate_from_points(objs, pb, (1280, 720), fix_k3=True)
    ext = calibrate_stereo(objs, pa, pb, fi, ei)
    rot_err_deg = np.degrees(np.linalg.norm(cv2.Rodrigues(ext.R @ truth.R.T)[0]))
    t_err_mm = 1000 * np.linalg.norm(ext.T - truth.T)
    f_err = max(abs(fi.focal_px - frame.focal_px) / frame.focal_px, abs(ei.focal_px - event.focal_px) / event.focal_px)
    # a ball 8 m away, in the GoPro image -> event image
    pair = CameraPair(frame=fi, event=ei, extrinsics=ext)
    Xb = np.array([[0.6, -0.4, 8.0], [-1.0, 0.3, 6.0]])
    r_frame = frame.focal_px * 0.105 / Xb[:, 2]
    circles_f = np.column_stack([frame.project(Xb), r_frame])
    Xe = Xb @ truth.R.T + truth.T
    circles_e_true = np.column_stack([event.project(Xe), event.focal_px * 0.105 / Xe[:, 2]])
    mapped = pair.frame_to_event(circles_f)
    map_err = np.linalg.norm(mapped[:, :2] - circles_e_true[:, :2], axis=1).max()
    back = pair.event_to_frame(mapped)
    print(f"stereo: rot err {rot_err_deg:.4f} deg, T err {t_err_mm:.2f} mm, f err {100 * f_err:.3f} %, "
          f"rms {ext.rms_px:.3f} px, circle map err {map_err:.3f} px")
    assert rot_err_deg < 0.3 and t_err_mm < 5.0 and f_err < 0.005
    assert map_err < 1.0
    np.testing.assert_allclose(mapped[:, 2], circles_e_true[:, 2], rtol=0.01)
    np.testing.assert_allclose(back, circles_f, atol=0.05)
    d = json.loads(json.dumps(pair.to_dict()))
    np.testing.assert_allclose(CameraPair.from_dict(d).frame_to_event(circles_f), mapped)


def test_homography_fallback_for_far_plane():
    frame, event, truth = make_rig()
    rng = np.random.default_rng(2)
    P = np.column_stack([rng.uniform(-3, 3, 40), rng.uniform(-1.5, 1.5, 40), np.full(40, 12.0)])  # plane 12 m away
    Pe = P @ truth.R.T + truth.T
    H = fit_homography(frame.project(P), event.project(Pe))
    pair = CameraPair(homography=H)
    Xb = np.array([[0.5, 0.2, 12.0]])
    cf = np.column_stack([frame.project(Xb), [frame.focal_px * 0.105 / 12.0]])
    Xe = Xb @ truth.R.T + truth.T
    ce = np.column_stack([event.project(Xe), [event.focal_px * 0.105 / Xe[0, 2]]])
    m = pair.frame_to_event(cf)
    print(f"homography: centre err {np.linalg.norm(m[0, :2] - ce[0, :2]):.3f} px, radius err {abs(m[0, 2] - ce[0, 2]):.3f} px")
    assert np.linalg.norm(m[0, :2] - ce[0, :2]) < 1.0 and abs(m[0, 2] - ce[0, 2]) < 0.3
    np.testing.assert_allclose(pair.event_to_frame(m), cf, atol=1e-3)
    d = json.loads(json.dumps(pair.to_dict()))
    np.testing.assert_allclose(CameraPair.from_dict(d).homography, H)
    with pytest.raises(CalibrationError, match=">= 4 matched points"):
        fit_homography(np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(CalibrationError, match="neither"):
        CameraPair().frame_to_event(cf)
