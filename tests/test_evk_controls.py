"""IMX636 controls against OpenEB 5.1.1's register traffic, through the fake EVK: the event trail
filter (STC), camera synchronisation, the event rate controller's read-back, and EVT 2.1 output
(recorded end to end)."""

import numpy as np
import pytest

from capture import evk, raw
from capture.cliargs import trail_filter
from capture.events import make_events
from capture.evk.fake import FakeEVK
from tests.test_raw_words import evt21_words


def opened(**kw):
    fake = FakeEVK(kw.pop("raw_path", None), **kw)
    return fake, evk.open(backend=fake)


def traffic(fake, start):
    """The register accesses since ``start``, without the device id."""
    return [e[:1] + e[2:] for e in fake.register_log()[start:]]


def test_stc_cut_register_traffic_is_the_hals():
    # EventTrailFilter::enable: bypass; clear the init flag, request the SRAM init; STC on with
    # the threshold in µs in [19:1] and cut-trail; trail off; prescaler / multiplier / timeout
    # of the 10 ms row of the HAL's table, last-timestamp update on; init flag polled; on.
    fake, cam = opened()
    n = len(fake.register_log())
    cam.set_trail_filter("stc_cut", 10_000)
    assert traffic(fake, n) == [
        ("W", 0xD000, 0b101),
        ("R", 0xD0C4), ("W", 0xD0C4, 0b100),
        ("R", 0xD0C4), ("W", 0xD0C4, 0b001),
        ("R", 0xD004), ("W", 0xD004, 0x00004E21),
        ("R", 0xD008), ("W", 0xD008, 0x186A0 << 1),
        ("R", 0xD00C), ("W", 0xD00C, 0x0001032D),
        ("R", 0xD0C0), ("W", 0xD0C0, 0x0A05A004),
        ("R", 0xD0C4),  # done at the first read
        ("W", 0xD000, 0b001),
    ]
    assert cam.sensor.trail_filter == ("stc_cut", 10_000)
    cam.set_trail_filter("stc_keep", 42_400)  # rounded to 42 ms as the HAL does
    assert fake.registers[0xD004] == 1 | 42_000 << 1 | 1 << 24  # disable_stc_cut_trail: keep
    assert fake.registers[0xD00C] & 0x1FF == 14 | 5 << 5 and fake.registers[0xD0C0] >> 12 & 0xFFF == 109
    cam.set_trail_filter("stc_cut", 2_500)  # a half rounds up, as C's roundf in the HAL
    assert fake.registers[0xD004] & 0xFFFFF == 1 | 3_000 << 1 and cam.sensor.trail_filter == ("stc_cut", 3_000)
    assert fake.registers[0xD00C] & 0x1FF == 11 | 5 << 5  # the 3 ms row of the table
    cam.set_trail_filter("trail", 5_000)
    assert fake.registers[0xD004] & 1 == 0 and fake.registers[0xD008] == 1 | 5_000 << 1
    assert cam.sensor.trail_filter == ("trail", 5_000)
    n = len(fake.register_log())
    cam.set_trail_filter(None)
    assert traffic(fake, n) == [("W", 0xD000, 0b101)] and cam.sensor.trail_filter is None
    cam.close()


def test_trail_filter_errors_write_nothing_or_leave_it_bypassed():
    fake, cam = opened()
    n = len(fake.register_log())
    with pytest.raises(ValueError, match="threshold 500 µs is outside 1000..100000 µs"):
        cam.set_trail_filter("trail", 500)
    with pytest.raises(ValueError, match="kind must be one of trail, stc_cut, stc_keep"):
        cam.set_trail_filter("stc", 10_000)
    assert fake.register_log()[n:] == []
    cam.close()

    class NoInit(FakeEVK):
        def _stc_init(self, written):
            self.registers[0xD0C4] = written & ~0b101  # the SRAM init never reports done

    fake = NoInit(None)
    cam = evk.open(backend=fake)
    with pytest.raises(evk.EvkError, match=r"trail filter did not report its initialisation done \(register 0xD0C4\)"):
        cam.set_trail_filter("stc_cut", 10_000)
    assert fake.registers[0xD000] == 0b101 and cam.sensor.trail_filter is None
    assert [e for e in fake.register_log() if e[0] == "R" and e[2] == 0xD0C4][-3:] == [("R", 0, 0xD0C4)] * 3
    cam.close()
    for sensor in ("gen41", "gen31"):
        fake, cam = opened(sensor=sensor)
        with pytest.raises(evk.EvkError, match="has no trail filter in this driver"):
            cam.set_trail_filter("trail", 10_000)
        cam.close()


@pytest.mark.parametrize("mode, time_base, pad", [
    ("master", 0x64E, 0xCCFCFCCF), ("slave", 0x64A, 0xCCFFFCCF), ("standalone", 0x644, 0xCCFFFCCF)])
def test_sync_modes_are_the_hals_time_base_config(mode, time_base, pad):
    fake, cam = opened()
    n = len(fake.register_log())
    cam.set_sync_mode(mode)
    expected = [("R", 0x9008), ("W", 0x9008, time_base)]
    if mode != "standalone":  # the SYNC pad's direction follows for an external time base
        expected += [("R", 0x0044), ("W", 0x0044, pad)]
    assert traffic(fake, n) == expected and fake.registers[0x0044] == pad
    assert cam.sensor.sync_mode == mode
    cam.start()  # start sets the enable bit and keeps the mode
    assert fake.registers[0x9008] == time_base | 1
    with pytest.raises(evk.EvkError, match="sync mode can only change while not streaming"):
        cam.set_sync_mode("standalone")
    cam.close()


def test_format_and_sync_on_other_sensors_refuse_a_change_and_accept_what_they_are():
    for sensor in ("gen41", "gen31"):
        fake, cam = opened(sensor=sensor)
        n = len(fake.register_log())
        cam.set_event_format("EVT3")  # what they stream
        cam.set_sync_mode("standalone")  # what they are
        assert fake.register_log()[n:] == []
        with pytest.raises(evk.EvkError, match="has no format selection in this driver"):
            cam.set_event_format("EVT21")
        with pytest.raises(evk.EvkError, match="has no synchronisation in this driver"):
            cam.set_sync_mode("master")
        cam.close()


def test_format_cannot_change_while_streaming():
    fake, cam = opened()
    cam.start()
    with pytest.raises(evk.EvkError, match="event format can only change while not streaming"):
        cam.set_event_format("EVT21")
    assert fake.registers[0x7000] & 0x2 == 0 and cam.info.format == "EVT3"
    cam.close()


def test_erc_status_reads_back_what_was_set():
    fake, cam = opened()
    assert cam.erc_status() == (False, 50e6)  # initialised, not dropping; the HAL's default count
    cam.set_erc(20e6)
    assert cam.erc_status() == (True, 20e6)
    cam.set_erc(None)
    assert cam.erc_status() == (False, 20e6)
    cam.close()
    fake, cam = opened(sensor="gen31")
    with pytest.raises(evk.EvkError, match="Gen3.1 has no event rate controller"):
        cam.erc_status()
    cam.close()


def test_evt21_is_selected_as_the_hal_does_and_recorded_end_to_end(tmp_path):
    rng = np.random.default_rng(3)
    n = 20_000
    t = np.sort(rng.integers(0, 2_000_000, n))
    ev = make_events(t, rng.integers(0, 1280, n), rng.integers(0, 720, n), rng.integers(0, 2, n))
    src = tmp_path / "evt21.raw"
    src.write_bytes(raw.header_bytes("EVT21", width=1280, height=720, endianness="legacy")
                    + evt21_words(ev, [], "legacy"))
    fake, cam = opened(raw_path=src, pace="max")
    n0 = len(fake.register_log())
    cam.set_event_format("EVT21")
    assert traffic(fake, n0)[:4] == [("R", 0x7000), ("W", 0x7000, 0x00070003), ("R", 0x8000), ("W", 0x8000, 0x0001E005)]
    assert cam.info.format == "EVT21"
    stats = evk.record(cam, tmp_path / "rec.raw")
    cam.close()
    assert stats.lossless and stats.payload_bytes == len(fake.payload)
    assert not stats.time_base_monitored  # EVT 2.1: gaps on the link would go unseen, and it says so
    rec = raw.read(tmp_path / "rec.raw")
    assert rec.format == "EVT21"
    np.testing.assert_array_equal(np.sort(rec.events, order=["t", "y", "p", "x"]),
                                  np.sort(ev, order=["t", "y", "p", "x"]))


def test_an_evt21_file_streams_nothing_while_evt3_is_selected(tmp_path, caplog):
    src = tmp_path / "evt21.raw"
    ev = make_events([10, 20], [1, 2], [3, 4], [0, 1])
    src.write_bytes(raw.header_bytes("EVT21", width=1280, height=720, endianness="legacy")
                    + evt21_words(ev, [], "legacy"))
    fake, cam = opened(raw_path=src, pace="max")
    stats = evk.record(cam, tmp_path / "rec.raw", max_duration_s=0.3)
    cam.close()
    assert stats.payload_bytes == 0 and fake.bytes_served == 0
    assert "its recording is EVT21 but the driver selected the other format" in caplog.text


def test_capture_run_applies_and_stores_the_controls(shared_raw_dir, tmp_path):
    from capture.run import main
    from capture.session import open_session

    src = shared_raw_dir / "ros_codecs_evt3_trigger_1280x720.raw"
    rc = main(["--fake", str(src), "--out", str(tmp_path / "s"), "--viewer", "none", "--no-analysis", "--quiet",
               "--speed", "max", "--erc", "30e6", "--trail-filter", "stc-cut:20", "--sync", "master",
               "--usb-transfers", "8"])
    assert rc == 0
    attrs = open_session(tmp_path / "s").attrs
    sensor = attrs["sensor"]
    assert sensor["trail_filter"] == ["stc_cut", 20_000] and sensor["sync_mode"] == "master"
    assert sensor["erc"] == {"enabled": True, "cap_ev_s": 30_000_000} and sensor["format"] == "EVT3"
    assert attrs["recording"]["usb_transfers"] == 8 and attrs["recording"]["payload_bytes"] == 758_296


def test_the_fake_refuses_evt21_in_the_standard_word_order(tmp_path):
    src = tmp_path / "little.raw"
    ev = make_events([10, 20], [1, 2], [3, 4], [0, 1])
    src.write_bytes(raw.header_bytes("EVT21", width=1280, height=720, endianness="little")
                    + evt21_words(ev, [], "little"))
    with pytest.raises(ValueError, match="EVT 2.1 in the standard word order; an IMX636 streams the legacy order"):
        FakeEVK(src)


def test_capture_evk_record_takes_the_fake_files_format(tmp_path, capsys):
    from capture.evk.cli import main

    rng = np.random.default_rng(5)
    ev = make_events(np.sort(rng.integers(0, 500_000, 5000)), rng.integers(0, 1280, 5000),
                     rng.integers(0, 720, 5000), rng.integers(0, 2, 5000))
    src = tmp_path / "evt21.raw"
    src.write_bytes(raw.header_bytes("EVT21", width=1280, height=720, endianness="legacy")
                    + evt21_words(ev, [], "legacy"))
    assert main(["record", str(tmp_path / "out.raw"), "--fake", str(src), "--speed", "max"]) == 0
    assert "EVT21" in capsys.readouterr().out  # the camera as configured
    assert len(raw.read(tmp_path / "out.raw").events) == 5000


@pytest.mark.parametrize("text, expected", [("trail", ("trail", 10_000)), ("stc-keep:1", ("stc_keep", 1_000)),
                                            ("stc-cut:100", ("stc_cut", 100_000))])
def test_trail_filter_option(text, expected):
    assert trail_filter(text) == expected


@pytest.mark.parametrize("text", ["stc", "trail:", "trail:0", "trail:101", "trail:x", "stc-cut:2.5"])
def test_trail_filter_option_errors(text):
    import argparse

    with pytest.raises(argparse.ArgumentTypeError):
        trail_filter(text)
