"""Discovery, open-time errors and settings (biases, ROI, ERC, trigger) through the fake."""

import struct

import pytest

from capture import evk
from capture.evk.fake import FakeEVK
from capture.evk.treuzell import (
    FLAG_WRITE, PROP_DEVICE_COMPATIBLE, PROP_DEVICE_ENABLE, PROP_DEVICE_NAME, PROP_DEVICE_STREAM,
)


def opened(**kw):
    fake = FakeEVK(None, **kw)
    return fake, evk.open(backend=fake)


def test_list_devices_reports_serial_board_sensor():
    (info,) = evk.list_devices(backend=FakeEVK(None, serial=0x1234ABCD))
    assert (info.serial, info.board, info.sensor, info.width, info.height) == ("1234abcd", "EVK4", "IMX636", 1280, 720)
    assert info.firmware == "3.9.0" and info.error is None
    (info,) = evk.list_devices(backend=FakeEVK(None, sensor="gen31"))
    assert (info.board, info.sensor, info.width) == ("EVK3", "Gen3.1", 640)


def test_open_by_serial():
    fake = FakeEVK(None, serial=0xABC)
    with evk.open("00000abc", backend=fake) as cam:
        assert cam.info.serial == "00000abc"
    with pytest.raises(evk.EvkNotFoundError, match="no EVK with serial 0000dead"):
        evk.open("0000dead", backend=FakeEVK(None, serial=0xABC))


def test_no_device():
    fake = FakeEVK(None)
    fake.unplug()
    with pytest.raises(evk.EvkNotFoundError, match="no Prophesee EVK found"):
        evk.open(backend=fake)


def test_permission_denied_names_the_udev_rule():
    with pytest.raises(evk.EvkPermissionError, match="permission denied") as exc:
        evk.open(backend=FakeEVK(None, permission_denied=True))
    assert evk.UDEV_RULE in str(exc.value) and "\n" not in str(exc.value)
    (info,) = evk.list_devices(backend=FakeEVK(None, permission_denied=True))
    assert info.serial is None and evk.UDEV_RULE in info.error


def test_busy():
    with pytest.raises(evk.EvkBusyError, match="camera is busy"):
        evk.open(backend=FakeEVK(None, busy=True))


def test_old_firmware_is_refused_and_released():
    fake = FakeEVK(None, firmware_version=0x030703)
    with pytest.raises(evk.EvkFirmwareError, match=r"firmware 3\.7\.3 is no longer supported \(need >= 3\.8\.0\)"):
        evk.open(backend=fake)
    assert ("usb", "release", 0) in fake.log
    assert not fake.register_log()  # no register touched
    with evk.open(backend=FakeEVK(None, firmware_version=0x030800)) as cam:
        assert cam.info.firmware == "3.8.0"


@pytest.mark.parametrize("registers, message", [({0x14: 0xA0301003}, "no supported sensor"),
                                                 ({0xF128: 0x2}, "no supported sensor")])
def test_sensor_identity_checks(registers, message):
    with pytest.raises(evk.EvkError, match=message):
        evk.open(backend=FakeEVK(None, registers=registers))


def test_gen31_wrong_fpga_id():
    with pytest.raises(evk.EvkError, match="wrong FPGA system ID 0x1C"):
        evk.open(backend=FakeEVK(None, sensor="gen31", registers={0x800: 0x1C}))


def _flag_writes(fake, n=0):
    """(property, device, value) of the ENABLE / STREAM writes in the fake's log from entry n."""
    out = []
    for e in fake.log[n:]:
        if e[0] == "prop" and e[1] & ~FLAG_WRITE in (PROP_DEVICE_ENABLE, PROP_DEVICE_STREAM) and e[1] & FLAG_WRITE:
            out.append((e[1] & ~FLAG_WRITE, *struct.unpack("<II", e[2][:8])))
    return out


def test_auxiliary_devices_follow_the_hal():
    # TzStreamer: STREAM=0 when built; TzUnknownDevice: ENABLE=1 when built; TzDeviceControl then
    # starts every device but the sensor (STREAM=1), and at close stops them in reverse order,
    # after which unknown devices get ENABLE=0. The temperature sensor is left alone.
    fake, cam = opened(extra_devices=[("treuzell,streamer", "dma"), ("ti,tmp103", "temp"), ("acme,gizmo", "x")])
    S, E = PROP_DEVICE_STREAM, PROP_DEVICE_ENABLE
    assert _flag_writes(fake) == [(S, 1, 0), (E, 3, 1), (S, 1, 1), (S, 3, 1)]
    n = len(fake.log)
    cam.close()
    assert _flag_writes(fake, n) == [(S, 3, 0), (S, 1, 0), (E, 3, 0)]


@pytest.mark.parametrize("faults", [
    {(PROP_DEVICE_NAME, 0): "fail"},  # a name that fails after the compatible string answered
    {(PROP_DEVICE_COMPATIBLE, 0): "echo", (PROP_DEVICE_NAME, 0): "echo"},  # answers echoing another id
    {(PROP_DEVICE_COMPATIBLE, 1): "timeout"},  # no answer from an auxiliary device: it is skipped
    {(PROP_DEVICE_STREAM, 1): "fail", (PROP_DEVICE_ENABLE, 2): "fail"},  # refusals of auxiliary devices
])
def test_enumeration_is_as_lenient_as_the_hal(faults):
    fake, cam = opened(extra_devices=[("treuzell,streamer", "dma"), ("acme,gizmo", "x")], faults=faults)
    assert cam.info.sensor == "IMX636" and cam.info.width == 1280
    cam.start()
    cam.stop()
    cam.close()


def test_compatible_failure_falls_back_to_the_name():
    # Old firmware (treuzell-kernel 1.4.0) put the compatible string in the name.
    fake = FakeEVK(None, faults={(PROP_DEVICE_COMPATIBLE, 0): "fail"})
    fake.devices[0] = (("psee,ccam5_imx636",), "psee,ccam5_imx636")
    with evk.open(backend=fake) as cam:
        assert cam.info.sensor == "IMX636"
    fake = FakeEVK(None, faults={(PROP_DEVICE_COMPATIBLE, 0): "fail", (PROP_DEVICE_NAME, 0): "fail"})
    with pytest.raises(evk.EvkError, match="no supported sensor found"):
        evk.open(backend=fake)


def test_imx636_biases_are_offsets_from_factory_trim():
    fake, cam = opened()
    trim_fo = fake.reset_registers[0x1004] & 0xFF
    cam.set_biases(bias_fo=10, diff_on=-20)
    assert fake.registers[0x1004] == 0x11A10000 | (trim_fo + 10)
    assert fake.registers[0x1010] == 0x11A10000 | ((fake.reset_registers[0x1010] & 0xFF) - 20)
    assert cam.get_biases()["bias_fo"] == 10 and cam.get_biases()["bias_diff_on"] == -20
    n = len(fake.log)
    with pytest.raises(evk.BiasRangeError, match=r"bias_fo offset 56 is outside the IMX636's recommended range -35\.\.55"):
        cam.set_biases(bias_hpf=5, bias_fo=56)
    with pytest.raises(evk.BiasRangeError, match="unknown bias 'bias_pr'"):
        cam.set_biases(bias_pr=0)
    assert len(fake.log) == n  # nothing written when any value is rejected
    cam.close()


def test_gen41_absolute_biases_and_constraints():
    fake, cam = opened(sensor="gen41")
    cam.set_biases(bias_fo=0x50)
    assert fake.registers[0x1004] == 0x11A10050
    with pytest.raises(evk.BiasRangeError, match="bias_diff_on >= bias_diff \\+ 15"):
        cam.set_biases(bias_diff_on=0x50 + 14)
    with pytest.raises(evk.BiasRangeError, match=r"0\.\.120"):
        cam.set_biases(bias_hpf=121)
    cam.close()


def test_gen31_biases_range_checked_then_refused():
    _, cam = opened(sensor="gen31")
    with pytest.raises(evk.BiasRangeError, match=r"bias_diff = 500 mV is outside .* 200\.\.400 mV"):
        cam.set_biases(bias_diff=500)
    with pytest.raises(evk.EvkError, match="calibration tables"):
        cam.set_biases(bias_diff=300)
    cam.close()


def enabled_lines(regs, base, n_lines, inverted):
    out = []
    for k in range(n_lines):
        bit = (regs.get(base + 4 * (k // 32), 0) >> (k % 32)) & 1
        if bit != inverted:
            out.append(k)
    return out


def test_imx636_roi_line_bitmaps():
    fake, cam = opened()
    cam.set_roi(100, 50, 200, 100)
    assert enabled_lines(fake.registers, 0x2000, 1280, True) == list(range(100, 300))
    assert enabled_lines(fake.registers, 0x4000, 720, True) == list(range(50, 150))
    assert fake.registers[0x4058] >> 16 == 0xFFFF
    assert fake.registers[0x0004] & 0b1000110 == 0b1000010 and fake.registers[0x0004] & (1 << 10)
    cam.set_roi()
    assert enabled_lines(fake.registers, 0x2000, 1280, True) == list(range(1280))
    assert enabled_lines(fake.registers, 0x4000, 720, True) == list(range(720))
    assert not fake.registers[0x0004] & 0b10
    with pytest.raises(ValueError, match="does not fit the IMX636's 1280x720"):
        cam.set_roi(1200, 0, 100, 10)
    cam.close()


def test_gen31_roi_is_not_inverted():
    fake, cam = opened(sensor="gen31")
    cam.set_roi(0, 0, 33, 480)
    assert enabled_lines(fake.registers, 0x400, 640, False) == list(range(33))
    assert enabled_lines(fake.registers, 0x500, 480, False) == list(range(480))
    cam.close()


def test_erc_rate_cap():
    fake, cam = opened()
    cam.set_erc(20e6)
    assert fake.registers[0x600C] == 4000 and fake.registers[0x6050] & 1  # 20 Mev/s * 200 µs
    cam.set_erc(None)
    assert not fake.registers[0x6050] & 1
    with pytest.raises(ValueError, match=r"max_event_rate_ev_s=4000000000.0 is outside 0..3200000000 ev/s"):
        cam.set_erc(4e9)
    cam.close()
    fake, cam = opened(sensor="gen31")
    n = len(fake.register_log())
    with pytest.raises(evk.EvkError, match="Gen3.1 has no event rate controller"):
        cam.set_erc(1e6)  # its NFL is an activity filter: as a cap it would blank quiet scenes
    cam.set_erc(None)
    assert not [e for e in fake.register_log()[n:] if e[0] == "W"]
    cam.close()


def test_gen31_activity_filter():
    fake, cam = opened(sensor="gen31")
    cam.set_activity_filter(1e6)  # NFL: drop events while below 1000 kev/s over 1023 µs
    assert fake.registers[0x24C] & 0x3FFF == 1023 and fake.registers[0x248] & 1
    cam.start()  # the start sequence turns the filter off; the driver turns it back on
    assert fake.registers[0x248] & 1
    cam.set_activity_filter(None)
    assert not fake.registers[0x248] & 1
    with pytest.raises(ValueError, match="activity filter's 1e4..1e7 ev/s"):
        cam.set_activity_filter(1e3)
    cam.close()
    fake, cam = opened()
    with pytest.raises(evk.EvkError, match="IMX636 has no event-rate activity filter"):
        cam.set_activity_filter(1e6)
    cam.close()


def test_trigger_in():
    fake, cam = opened()
    assert fake.registers[0x7004] == 0xC1FF
    cam.enable_trigger_in()
    assert fake.registers[0x7004] == 0xC5FF  # ND's whole-word value with enable
    cam.enable_trigger_in(False)
    assert fake.registers[0x7004] == 0xC1FF
    with pytest.raises(ValueError, match="channel 0 only"):
        cam.enable_trigger_in(channel=1)
    cam.close()
    fake, cam = opened(sensor="gen41")
    n = len(fake.register_log())
    cam.enable_trigger_in()
    assert fake.registers[0x7004] & (1 << 10) and (fake.registers.get(0x44, 0) >> 12) & 0xF == 0xF
    writes = [e for e in fake.register_log()[n:] if e[0] == "W"]
    assert [w[2] for w in writes] == [0x0044, 0x7004]  # the HAL's order: pad, then enable
    cam.close()


@pytest.mark.parametrize("sensor", ["imx636", "gen41"])
def test_configure_is_the_individual_settings_in_order(sensor):
    biases = {"bias_fo": 10, "bias_hpf": 5} if sensor == "imx636" else {"bias_fo": 0x50}
    one_call, cam = opened(sensor=sensor)
    start = len(one_call.register_log())
    cam.configure(biases=biases, roi=(100, 50, 200, 100), erc_ev_s=20e6, trigger_in=True)
    configured = one_call.register_log()[start:]
    cam.close()
    separate, cam = opened(sensor=sensor)
    start = len(separate.register_log())
    cam.set_biases(**biases)
    cam.set_roi(100, 50, 200, 100)
    cam.set_erc(20e6)
    cam.enable_trigger_in(True)
    assert configured == separate.register_log()[start:] and configured
    cam.close()


def test_configure_leaves_what_is_not_given():
    fake, cam = opened(sensor="gen31")  # Gen3.1 refuses any set_biases call: empty biases must not make one
    start = len(fake.register_log())
    cam.configure()
    cam.configure(biases={})
    assert fake.register_log()[start:] == []
    cam.configure(trigger_in=False)
    assert fake.register_log()[start:]  # False is given: the trigger input is written (disabled)
    cam.close()


@pytest.mark.parametrize("sensor", ["imx636", "gen41"])
def test_anti_flicker_register_traffic_is_the_hals(sensor):
    # AntiFlickerFilter::enable (OpenEB): pipeline off; poll afk_flag_init_done (up to 3 reads);
    # dt_fifo_wait_time = 1630; band as periods of 128 µs with the 50 % duty cycle; band-stop;
    # hysteresis 6 / 4; pipeline on. Each field write is a read-modify-write.
    fake, cam = opened(sensor=sensor)
    n = len(fake.register_log())
    cam.set_anti_flicker((90, 110))
    log = [e[:1] + e[2:] for e in fake.register_log()[n:]]
    assert log == [
        ("W", 0xC000, 0b101),
        ("R", 0xC0C4),  # done at the first read
        ("R", 0xC0C0), ("W", 0xC0C0, 0x0A05A000 | 1630),
        ("R", 0xC008), ("W", 0xC008, (9090 >> 7) | (11111 >> 7) << 8 | 8 << 16),
        ("R", 0xC004), ("W", 0xC004, 0x34),  # invert [6] <- 0 (band-stop)
        ("R", 0xC004), ("W", 0xC004, 0x34),  # counter_high [5:3] <- 6
        ("R", 0xC004), ("W", 0xC004, 0x34),  # counter_low [2:0] <- 4
        ("W", 0xC000, 0b001),
    ]
    assert cam.sensor.anti_flicker_hz == (90, 110)
    cam.set_anti_flicker(None)
    assert fake.registers[0xC000] == 0b101 and cam.sensor.anti_flicker_hz is None
    with pytest.raises(ValueError, match="band 40..110 Hz is outside 50..520 Hz"):
        cam.set_anti_flicker((40, 110))
    cam.close()


def test_anti_flicker_errors():
    fake, cam = opened(registers={0xC0C4: 0})
    with pytest.raises(evk.EvkError, match=r"anti-flicker did not report its initialisation done \(register 0xC0C4\)"):
        cam.set_anti_flicker((90, 110))
    assert fake.registers[0xC000] == 0b101  # left off
    assert [e for e in fake.register_log() if e[0] == "R" and e[2] == 0xC0C4] == [("R", 0, 0xC0C4)] * 3  # as the HAL
    cam.close()
    fake, cam = opened(sensor="gen31")
    with pytest.raises(evk.EvkError, match="Gen3.1 has no anti-flicker block"):
        cam.set_anti_flicker((90, 110))
    cam.close()


def test_recorder_sets_anti_flicker_and_stores_it(shared_raw_dir, tmp_path):
    from capture.cliargs import flicker_band
    from capture.pipeline.record import RecordSettings, record_session
    from capture.session import open_session

    fake = FakeEVK(shared_raw_dir / "ros_codecs_evt3_trigger_1280x720.raw", pace="max")
    record_session(RecordSettings(out=tmp_path / "s", backend=fake, quiet=True,
                                  anti_flicker_hz=flicker_band("50Hz"), erc_ev_s=20e6))
    assert fake.registers[0xC000] == 0b001 and fake.registers[0xC008] & 0xFFFF == (9090 >> 7) | (11111 >> 7) << 8
    sensor = open_session(tmp_path / "s").attrs["sensor"]
    assert sensor["anti_flicker_hz"] == [90, 110] and sensor["erc_ev_s"] == 20e6


@pytest.mark.parametrize("content, match", [
    (b"", "is empty"),
    (b"% format EVT3;height=720;width=1280\n% end\n", "holds no event data"),
    (b"\x89PNG\r\n\x1a\n" + bytes(64), "is not a Prophesee RAW recording"),
    (b"% evt 2.0\n% end\n" + bytes(64), "is an EVT2 recording; the emulated EVK4 streams EVT3 or EVT21"),
])
def test_fake_refuses_files_it_cannot_present(tmp_path, capsys, content, match):
    from capture.evk.cli import main

    src = tmp_path / "in.raw"
    src.write_bytes(content)
    with pytest.raises(ValueError, match=match):
        FakeEVK(src)
    assert main(["record", str(tmp_path / "out.raw"), "--fake", str(src)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0] and not (tmp_path / "out.raw").exists()


def test_imx636_temperature_register_traffic_is_the_hals():
    # TzImx636::get_temperature (OpenEB): adc_clk_en <- 1, adc_temp <- 1, adc_start <- 1 (each a
    # read-modify-write); adc_done_dyn and adc_dac_dyn read (one register read each) until done;
    # adc_clk_en <- 0; 0.190 x dac - 56 °C.
    fake, cam = opened(sensor="imx636")
    fake.temperature_c = 41.3
    n = len(fake.register_log())
    t = cam.temperature_c()
    assert abs(t - 41.3) <= 0.19 / 2 + 1e-9
    log = [e[:1] + e[2:3] for e in fake.register_log()[n:]]
    assert log == [("R", 0x004C), ("W", 0x004C), ("R", 0x0054), ("W", 0x0054), ("R", 0x004C), ("W", 0x004C),
                   ("R", 0x0050), ("R", 0x0050), ("R", 0x004C), ("W", 0x004C)]
    assert fake.registers[0x004C] & 0b110 == 0  # clock off, start cleared
    cam.close()


@pytest.mark.parametrize("sensor", ["gen41", "gen31"])
def test_sensors_without_a_temperature_say_so(sensor):
    _, cam = opened(sensor=sensor)
    with pytest.raises(evk.EvkError, match="reports no temperature"):
        cam.temperature_c()
    with pytest.raises(evk.EvkError, match="reports no light level"):
        cam.illuminance_lux()
    cam.close()


def test_imx636_light_level_register_traffic_is_the_hals():
    # TzImx636::get_illumination (OpenEB): lifo_status read until lifo_ton_valid (up to 10 times);
    # 10 ** (3.5 - log10(0.37 * counter / 100)) lux.
    fake, cam = opened(sensor="imx636", illuminance_lux=650.0)
    n = len(fake.register_log())
    lux = cam.illuminance_lux()
    assert abs(lux / 650.0 - 1) < 0.002  # the counter's rounding
    assert [e[:1] + e[2:3] for e in fake.register_log()[n:]] == [("R", 0x0010)]
    fake.registers[0x000C] = 0  # the LIFO not counting: never valid
    fake.registers[0x0010] = 0
    with pytest.raises(evk.EvkError, match="light counter did not report"):
        cam.illuminance_lux()
    assert [e[:1] + e[2:3] for e in fake.register_log()[n + 1:]] == [("R", 0x0010)] * 10
    cam.close()


@pytest.mark.parametrize("sensor", ["imx636", "gen41"])
def test_digital_crop_register_traffic_is_the_hals(sensor):
    # Gen41DigitalCrop (OpenEB): set_window_region writes start_x, start_y, end_x, end_y (the last
    # pixel kept) and reset_orig (0: the sensor's coordinates), each a read-modify-write; then
    # enable writes dig_crop_enable = 5. Off: dig_crop_enable = 0.
    fake, cam = opened(sensor=sensor)
    n = len(fake.register_log())
    cam.set_crop(320, 180, 640, 360)
    log = [e[:1] + e[2:3] for e in fake.register_log()[n:]]
    assert log == [("R", 0x9010), ("W", 0x9010)] * 2 + [("R", 0x9014), ("W", 0x9014)] * 2 + [("R", 0x900C), ("W", 0x900C)] * 2
    assert fake.registers[0x9010] == 320 | 180 << 16 and fake.registers[0x9014] == 959 | 539 << 16
    assert fake.registers[0x900C] & 0x17 == 5
    cam.set_crop()
    assert fake.registers[0x900C] & 0x7 == 0
    with pytest.raises(ValueError):
        cam.set_crop(1200, 0, 200, 100)  # past the sensor's edge
    cam.close()


def test_gen31_has_no_digital_crop():
    _, cam = opened(sensor="gen31")
    with pytest.raises(evk.EvkError, match="no digital crop"):
        cam.set_crop(0, 0, 100, 100)
    cam.close()
