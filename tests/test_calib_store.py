"""Calibration and a GoPro video stored in a real session store and read back."""

import numpy as np

from calib import CameraPair, Intrinsics, TimeMap, attach_video, load_calibration, store_calibration
from capture.gopro import read_video, write_video
from capture.session import create_session, open_session


def test_store_and_load_calibration_with_video(tmp_path):
    frames = [np.full((32, 48), 10 * i, np.uint8) for i in range(12)]
    tm = TimeMap(offset_us=5_000_000.0, drift_ppm=25.0, cov=np.diag([100.0, 4.0]), n=50, method="sync_box")
    pair = CameraPair(frame=Intrinsics(K=np.diag([900.0, 900.0, 1.0]), dist=np.zeros(5), width=48, height=32),
                      homography=np.eye(3) * 2)
    with create_session(tmp_path / "sess", width=64, height=48) as w:
        video = read_video(write_video(tmp_path / "gopro" / "GX010007.MP4", frames, fps=240))
        store_calibration(w, cameras=pair)
        t_us = attach_video(w, tmp_path / "sess", video, tm, exposure_s=1 / 240)
    s = open_session(tmp_path / "sess")
    got = s.frames()
    np.testing.assert_array_equal(got["t_us"], t_us)
    # frame k: exposure centre (k + 0.5) / 240 s mapped with offset and drift
    expected = 5_000_000 + (1 + 25e-6) * (np.arange(12) + 0.5) / 240 * 1e6
    np.testing.assert_allclose(got["t_us"], expected, atol=0.5)
    assert got["video"] == str((tmp_path / "gopro" / "GX010007.MP4").resolve())
    tm2, pair2 = load_calibration(s.attrs)
    assert tm2.drift_ppm == 25.0 and tm2.method == "sync_box" and tm2.sigma_us(0.0) == 10.0
    np.testing.assert_allclose(pair2.homography, pair.homography)
    assert pair2.frame.focal_px == 900.0 and pair2.event is None
