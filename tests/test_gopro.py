"""GoPro client against the loopback fake camera, and MP4 ingest of written videos."""

import socket
import time
from fractions import Fraction

import numpy as np
import pytest

from capture.gopro import (
    CameraBusy, CameraUnreachable, DownloadError, FakeGoPro, GoPro, MediaNotFound, MP4Error,
    address_from_serial, read_video, video_timing, write_video,
)
from capture.gopro.client import FPS_OPTIONS, LENS_OPTIONS, STATUS_ENCODING


def _frames(n, h=48, w=64):
    for i in range(n):
        img = np.zeros((h, w), np.uint8)
        img[:, (i * 3) % w] = 255  # a moving bar: each frame differs
        img[: h // 2, : w // 2] = (i * 37) % 256
        yield img


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_video(tmp_path_factory.mktemp("clip") / "clip.mp4", _frames(30), fps=240)


@pytest.fixture
def fake(clip):
    with FakeGoPro(clip) as f:
        yield f


def _closed_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_address_from_serial():
    assert address_from_serial("C3461324698573") == "172.25.173.51"
    with pytest.raises(ValueError, match="three digits"):
        address_from_serial("C34613246985X")


def test_open_enables_wired_control_and_keep_alive_runs(fake):
    with GoPro(host=fake.host, port=fake.port, keep_alive_s=0.05) as cam:
        assert fake.wired_control
        time.sleep(0.4)
    n = len(fake.keep_alive_times)
    assert n >= 3
    assert np.max(np.diff(fake.keep_alive_times)) < 0.35  # every 0.05 s asked; generous for loaded machines
    time.sleep(0.15)
    assert len(fake.keep_alive_times) == n  # thread stopped on close
    assert cam.keep_alive_failures == 0


def test_record_start_stop_adds_media(fake):
    cam = GoPro(host=fake.host, port=fake.port)
    before = [m.name for m in cam.media_list()]
    assert before == ["GX010001.MP4"]
    cam.start_recording()
    assert cam.is_recording() and cam.state()["status"][STATUS_ENCODING] == 1
    cam.stop_recording()
    assert not cam.is_recording()
    assert [m.name for m in cam.media_list()] == ["GX010001.MP4", "GX010002.MP4"]


def test_settings_and_date_time(fake):
    cam = GoPro(host=fake.host, port=fake.port)
    cam.configure(resolution="1080", fps=240, lens="linear", hypersmooth=False, anti_flicker="50Hz")
    s = cam.state()["settings"]
    assert s[3] == FPS_OPTIONS[240] == 0 and s[121] == LENS_OPTIONS["linear"] == 4
    assert s[135] == 0 and s[134] == 3 and s[2] == 9
    with pytest.raises(ValueError, match="fps=500"):
        cam.configure(fps=500)
    import datetime as dt
    cam.set_date_time(dt.datetime(2026, 3, 4, 5, 6, 7, tzinfo=dt.timezone(dt.timedelta(hours=1))))
    assert fake.date_time["date"] == "2026_3_4" and fake.date_time["time"] == "5_6_7"
    assert fake.date_time["tzone"] == "60" and fake.date_time["dst"] == "0"


def test_preview_start_stop(fake):
    cam = GoPro(host=fake.host, port=fake.port)
    cam.start_preview()
    assert fake.preview_port == 8554
    cam.stop_preview()
    assert fake.preview_port is None


def test_busy_camera_waits_then_gives_clear_error(clip):
    with FakeGoPro(clip, busy_s=0.3, finish_s=0.0) as fake:
        cam = GoPro(host=fake.host, port=fake.port)
        cam.start_recording()
        t0 = time.monotonic()
        cam.stop_recording(timeout_s=2.0)  # sent at once, then waits out the busy period
        assert time.monotonic() - t0 >= 0.25
        assert not fake.encoding and not fake.busy
        cam.start_recording(timeout_s=2.0)
        with pytest.raises(CameraBusy, match="still busy after 0.05 s"):
            cam.stop_recording(timeout_s=0.05)
        assert not fake.encoding  # the stop itself was not held back by the busy camera
        cam.stop_recording(timeout_s=2.0)
        cam.start_recording(timeout_s=2.0)
        time.sleep(0.35)
        with pytest.raises(CameraBusy, match="still recording"):
            cam.set_setting(3, 0, timeout_s=0.05)


def test_unreachable_camera_one_line_error():
    cam = GoPro(host="127.0.0.1", port=_closed_port(), timeout_s=1.0)
    with pytest.raises(CameraUnreachable, match=r"GoPro at 127\.0\.0\.1:\d+ unreachable") as e:
        cam.state()
    assert "\n" not in str(e.value)
    with pytest.raises(CameraUnreachable):
        cam.open()


def test_download_with_progress_is_byte_exact(fake, clip, tmp_path):
    cam = GoPro(host=fake.host, port=fake.port)
    out = cam.download("GX010001.MP4", tmp_path, progress=True)
    assert out.read_bytes() == clip.read_bytes()
    assert not (tmp_path / "GX010001.MP4.part").exists()
    n = len(fake.requests)
    assert cam.download("GX010001.MP4", tmp_path) == out  # complete file kept: only the media list is asked
    assert [r for r in fake.requests[n:] if r.startswith("/videos/")] == []


def test_download_resumes_after_cut_connection(clip, tmp_path):
    size = clip.stat().st_size
    with FakeGoPro(clip, cut_after_bytes=size // 3) as fake:
        cam = GoPro(host=fake.host, port=fake.port)
        with pytest.raises(DownloadError, match="partial data kept") as e:
            cam.download("GX010001.MP4", tmp_path, progress=False, retries=0)
        assert "\n" not in str(e.value)
        part = tmp_path / "GX010001.MP4.part"
        assert part.stat().st_size == size // 3
        out = cam.download("GX010001.MP4", tmp_path, progress=False, retries=0)
        ranges = [r for r in fake.requests if r.startswith("/videos/")]
        assert len(ranges) == 2
    assert out.read_bytes() == clip.read_bytes()
    assert not part.exists()


def test_download_retries_automatically(clip, tmp_path):
    with FakeGoPro(clip, cut_after_bytes=1000) as fake:
        out = GoPro(host=fake.host, port=fake.port).download("GX010001.MP4", tmp_path, progress=False)
    assert out.read_bytes() == clip.read_bytes()


def test_missing_media_clear_error(fake, tmp_path):
    cam = GoPro(host=fake.host, port=fake.port)
    with pytest.raises(MediaNotFound, match="GX019999.MP4"):
        cam.download("GX019999.MP4", tmp_path)


def test_chaptered_recording_download_and_ingest(tmp_path):
    a = write_video(tmp_path / "a.mp4", _frames(12), fps=120)
    b = write_video(tmp_path / "b.mp4", _frames(7), fps=120)
    with FakeGoPro([a, b]) as fake:
        cam = GoPro(host=fake.host, port=fake.port)
        assert [m.name for m in cam.chapters("GX020001.MP4")] == ["GX010001.MP4", "GX020001.MP4"]
        paths = cam.download_recording("GX010001.MP4", tmp_path / "dl", progress=False)
    assert [p.name for p in paths] == ["GX010001.MP4", "GX020001.MP4"]
    v = read_video(paths[0])
    assert v.n_frames == 19 and list(v.chapter_start) == [0, 12]
    assert v.fps == Fraction(120)
    np.testing.assert_allclose(v.t_s, np.arange(19) / 120, atol=1e-12)
    n = sum(1 for _ in v.frames(gray=True))
    assert n == 19


@pytest.mark.parametrize("fps", [240, 59.94, 25])
def test_read_video_exact_timestamps(tmp_path, fps):
    p = write_video(tmp_path / "v.mp4", _frames(20), fps=fps)
    v = read_video(p)
    expected = Fraction(fps).limit_denominator(1000)
    assert v.fps == expected, (v.fps, expected)
    np.testing.assert_allclose(v.t_s, np.arange(20) / float(expected), rtol=0, atol=1e-9)
    frames = list(v.frames(gray=True))
    assert [i for i, _, _ in frames] == list(range(20))
    src = list(_frames(20))
    # the moving bar is where it was written: frames come in presentation order
    for (i, t, img), ref in zip(frames, src):
        assert np.argmax(img[-1]) == np.argmax(ref[-1])
        assert t == v.t_s[i]


def test_opencv_pos_msec_agrees_with_container(tmp_path):
    import cv2
    p = write_video(tmp_path / "v.mp4", _frames(10), fps=59.94)
    cap = cv2.VideoCapture(str(p))
    ms = []
    while cap.read()[0]:
        ms.append(cap.get(cv2.CAP_PROP_POS_MSEC))
    np.testing.assert_allclose(np.array(ms) / 1000, video_timing(p).t_s, atol=1e-9)


def test_missing_and_bad_video_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.mp4"):
        read_video(tmp_path / "nope.mp4")
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"\x00\x00\x00\x10ftypisom\x00\x00\x00\x00" + b"junk" * 10)
    with pytest.raises(MP4Error, match="bad.mp4"):
        read_video(bad)
    with pytest.raises(FileNotFoundError, match="simulated video not found"):
        FakeGoPro(tmp_path / "missing.mp4")


def test_cli_download_from_fake_and_errors(clip, tmp_path, capsys):
    from capture.gopro.cli import main
    assert main(["--fake", str(clip), "download", "--quiet", "--last", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    assert captured.out.strip().splitlines() == [str(tmp_path / "out" / "GX010001.MP4")] and not captured.err
    assert (tmp_path / "out" / "GX010001.MP4").read_bytes() == clip.read_bytes()
    assert main(["--host", "127.0.0.1", "--port", str(_closed_port()), "state"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("capture.gopro: error: GoPro at 127.0.0.1:") and "unreachable" in err
    assert err.count("\n") == 1
    assert main(["--fake", str(tmp_path / "missing.mp4"), "state"]) == 1
    assert capsys.readouterr().err.startswith("capture.gopro: error: FakeGoPro: simulated video not found")
    with pytest.raises(SystemExit) as exc:
        main(["--fake", str(clip), "download", str(tmp_path / "out")])
    assert exc.value.code == 2 and "give a file NAME or --last" in capsys.readouterr().err
