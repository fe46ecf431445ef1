"""Per-model GoPro behaviour (HERO9–13) against the fake camera's model profiles, and the
recorder going on without video when the GoPro cannot record."""

import dataclasses
import datetime as dt
import time

import numpy as np
import pytest

from capture.gopro import FakeGoPro, GoPro, GoProError, write_video
from capture.gopro.client import CameraNotReady, SettingRefused
from capture.gopro.models import (
    MODELS, PRESET_GROUP_VIDEO, SETTING_ANTI_FLICKER, SETTING_AUTO_POWER_DOWN, SETTING_CONTROL_MODE,
    SETTING_FPS, SETTING_VIDEO_LENS, model_by_name, nearest_option,
)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    frames = [np.full((48, 64), v, np.uint8) for v in range(0, 240, 8)]
    return write_video(tmp_path_factory.mktemp("clip") / "clip.mp4", frames, fps=240)


@pytest.mark.parametrize("name, mains, option", [("HERO10", "50Hz", 3), ("HERO11", "60Hz", 2),
                                                 ("HERO12", "50Hz", 3), ("HERO13", "50Hz", 1),
                                                 ("HERO13", "60Hz", 0)])
def test_each_model_gets_its_own_options_in_a_video_preset(clip, name, mains, option):
    with FakeGoPro(clip, model=name) as fake, GoPro(host=fake.host, port=fake.port) as cam:
        assert cam.model is model_by_name(name) and fake.preset_group != PRESET_GROUP_VIDEO
        done = cam.configure(fps=240, anti_flicker=mains)
        assert fake.settings[SETTING_ANTI_FLICKER] == option == done[SETTING_ANTI_FLICKER]
        assert fake.preset_group == PRESET_GROUP_VIDEO
        assert fake.settings[SETTING_AUTO_POWER_DOWN] == 0
        assert (fake.settings.get(SETTING_CONTROL_MODE) == 1) == (name != "HERO10")
        assert cam.notes == []  # nothing refused: the profile knew the options
        assert any("setting=175" in r for r in fake.requests) == (name != "HERO10")


def test_refused_option_takes_the_nearest_supported_one_and_says_so(clip):
    no_240 = dataclasses.replace(MODELS[62], options={**MODELS[62].options, SETTING_FPS: (1, 5, 13)})
    no_linear = dataclasses.replace(MODELS[62], options={**MODELS[62].options, SETTING_VIDEO_LENS: (0, 3)})
    with FakeGoPro(clip, model=no_240) as fake, GoPro(host=fake.host, port=fake.port) as cam:
        done = cam.configure(fps=240)
        assert done[SETTING_FPS] == fake.settings[SETTING_FPS] == 13  # 200 fps: nearest to 240
        assert len(cam.notes) == 1 and "refused option 0 of setting 3" in cam.notes[0]
    with FakeGoPro(clip, model=no_linear) as fake, GoPro(host=fake.host, port=fake.port) as cam:
        with pytest.raises(SettingRefused, match=r"setting 121 option 4; it supports: option 0 \(0\), option 3"):
            cam.configure(lens="linear")


def test_nearest_option_by_meaning():
    assert nearest_option(SETTING_FPS, 0, [1, 5]) == 1  # 240 -> 120
    assert nearest_option(SETTING_FPS, 1, [2, 13]) == 2  # 120 -> 100, not 200
    assert nearest_option(SETTING_ANTI_FLICKER, 3, [0, 1]) == 1  # 50 Hz on HERO13's options
    assert nearest_option(SETTING_VIDEO_LENS, 4, [0, 3]) is None


def test_settings_are_read_back(clip):
    with FakeGoPro(clip, ignore_settings={SETTING_FPS}) as fake, GoPro(host=fake.host, port=fake.port) as cam:
        with pytest.raises(GoProError, match="setting 3 is 5, not 0"):
            cam.configure(fps=240)


def test_date_time_zone_only_where_the_model_takes_it(clip):
    when = dt.datetime(2026, 3, 4, 5, 6, 7, tzinfo=dt.timezone(dt.timedelta(hours=1)))
    for name, zone in (("HERO10", False), ("HERO12", True)):
        with FakeGoPro(clip, model=name) as fake, GoPro(host=fake.host, port=fake.port) as cam:
            cam.set_date_time(when)
            assert fake.date_time["date"] == "2026_3_4" and ("tzone" in fake.date_time) == zone


def test_hero9_cannot_be_controlled_over_usb(clip):
    with FakeGoPro(clip, model="HERO9") as fake:
        with pytest.raises(GoProError, match="HERO9 Black and older cannot be controlled over USB"):
            GoPro(host=fake.host, port=fake.port).open()


@pytest.mark.parametrize("health, match", [({"sd_status": 2}, "SD card removed"), ({"sd_free_kb": 0}, "SD card full"),
                                           ({"overheating": True}, "overheating")])
def test_health_refuses_a_camera_that_cannot_record(clip, health, match):
    with FakeGoPro(clip, **health) as fake, GoPro(host=fake.host, port=fake.port) as cam:
        with pytest.raises(CameraNotReady, match=match):
            cam.health()
        with pytest.raises(CameraNotReady, match="not recording after 0.3 s"):
            cam.start_recording(timeout_s=0.3)  # the shutter is accepted, encoding never starts


def test_health_warns_on_low_battery(clip):
    with FakeGoPro(clip, battery_pct=9) as fake, GoPro(host=fake.host, port=fake.port) as cam:
        assert cam.health() == ["GoPro battery at 9 %: connect it to power"]


def test_photo_preset_at_power_on_still_records_video(clip):
    with FakeGoPro(clip) as fake, GoPro(host=fake.host, port=fake.port) as cam:
        cam.start_recording()
        assert fake.encoding and not any(n.endswith(".JPG") for n in fake.media_names())


def test_stop_waits_until_the_file_is_finished(clip):
    with FakeGoPro(clip, finish_s=0.4) as fake, GoPro(host=fake.host, port=fake.port) as cam:
        before = {m.name for m in cam.media_list()}
        cam.start_recording()
        t0 = time.monotonic()
        cam.stop_recording()
        assert time.monotonic() - t0 >= 0.35
        assert {m.name for m in cam.media_list()} - before == {"GX010002.MP4"}


def test_recording_goes_on_without_video_when_the_gopro_cannot_record(shared_raw_dir, tmp_path):
    from capture import raw
    from capture.evk.fake import FakeEVK
    from capture.pipeline.record import RecordSettings, record_session
    from capture.session import open_session

    src = shared_raw_dir / "ros_codecs_evt3_trigger_1280x720.raw"
    mp4 = write_video(tmp_path / "clip.mp4", [np.full((48, 64), v, np.uint8) for v in range(0, 200, 20)], 30)
    with FakeGoPro(mp4, sd_status=2) as fake:
        settings = RecordSettings(out=tmp_path / "s", backend=FakeEVK(src), quiet=True,
                                  gopro=GoPro(host=fake.host, port=fake.port))
        result = record_session(settings)
    assert any("GoPro not recording (GoPro SD card removed" in m and "without video" in m for m in result.messages)
    s = open_session(tmp_path / "s")
    assert s.attrs["closed"] and s.n_events == len(raw.read(src).events) > 0
    assert not (tmp_path / "s" / "gopro").exists()


def test_cli_download_into_a_file_is_one_line(clip, tmp_path, capsys):
    from capture.gopro.cli import main

    target = tmp_path / "exists.mp4"
    target.write_bytes(b"x")
    assert main(["--fake", str(clip), "download", "--last", "--quiet", str(target)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"capture.gopro: error: GoPro download: {target} is a file, not a folder to download into"]
