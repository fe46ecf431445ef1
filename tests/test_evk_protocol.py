"""Treuzell framing against the byte-exact examples of docs/evk-usb.md section 2.4, and the
answer checks of section 2.5, with a minimal stand-in device (not the fake)."""

import struct

import pytest

from capture.evk import treuzell as tz
from capture.evk.errors import EvkTimeoutError, TreuzellError


def hexb(s: str) -> bytes:
    return bytes.fromhex(s.replace(" ", ""))


class CannedDevice:
    """Records bulk writes and answers each with the next canned frame."""

    def __init__(self, *answers: bytes):
        self.answers = list(answers)
        self.written = []

    def write(self, ep, data, timeout):
        assert ep == 0x02 and timeout == 1000
        self.written.append(bytes(data))
        return len(data)

    def read(self, ep, size, timeout):
        assert ep == 0x82 and size == 1024 and timeout in (10000, tz.DRAIN_TIMEOUT_MS)
        return self.answers.pop(0)


def link(*answers):
    dev = CannedDevice(*answers)
    return tz.TzLink(dev, 0x82, 0x02, sleep_us=lambda us: None, name="EVK4 test"), dev


def test_request_frames_are_byte_exact():
    assert tz.encode_frame(tz.PROP_RELEASE_VERSION) == hexb("79 00 00 00 00 00 00 00")
    assert tz.encode_frame(tz.PROP_BUILD_DATE) == hexb("7A 00 00 00 00 00 00 00")
    assert tz.encode_frame(tz.PROP_SERIAL) == hexb("72 00 00 00 00 00 00 00")
    assert tz.encode_frame(tz.PROP_DEVICES) == hexb("00 00 01 00 00 00 00 00")
    assert tz.encode_frame(tz.PROP_DEVICE_NAME, tz.words(0)) == hexb("01 00 01 00 04 00 00 00 00 00 00 00")
    assert tz.encode_frame(tz.PROP_DEVICE_COMPATIBLE, tz.words(0)) == hexb("03 00 01 00 04 00 00 00 00 00 00 00")


def test_register_read_and_write_frames():
    lk, dev = link(hexb("02 01 01 00 0C 00 00 00 00 00 00 00 14 00 00 00 06 18 40 A0"),
                   hexb("02 01 01 40 08 00 00 00 00 00 00 00 28 90 00 00"))
    assert lk.read_reg(0, 0x14) == 0xA0401806
    lk.write_reg(0, 0x9028, 2)
    assert dev.written == [
        hexb("02 01 01 00 0C 00 00 00 00 00 00 00 14 00 00 00 01 00 00 00"),
        hexb("02 01 01 40 0C 00 00 00 00 00 00 00 28 90 00 00 02 00 00 00"),
    ]


def test_rmw_changes_only_masked_bits():
    lk, dev = link(hexb("02 01 01 00 0C 00 00 00 00 00 00 00 08 90 00 00 44 06 00 00"),
                   hexb("02 01 01 40 0C 00 00 00 00 00 00 00 08 90 00 00 45 06 00 00"))
    assert lk.rmw(0, 0x9008, 0x645, 0x1) == 0x645
    assert struct.unpack("<5I", dev.written[1]) == (0x40010102, 12, 0, 0x9008, 0x645)


def test_serial_version_and_strings():
    lk, _ = link(hexb("72 00 00 00 08 00 00 00") + struct.pack("<Q", 0xA1B2C3D4),
                 hexb("79 00 00 00 04 00 00 00") + struct.pack("<I", 0x030800),
                 hexb("03 00 01 00 27 00 00 00 00 00 00 00") + b"psee,ccam5_imx636\0psee,ccam5_gen42\0")
    assert lk.serial() == "a1b2c3d4"
    assert lk.get_u32(tz.PROP_RELEASE_VERSION) == 0x030800
    assert lk.device_strings(tz.PROP_DEVICE_COMPATIBLE, 0) == ["psee,ccam5_imx636", "psee,ccam5_gen42"]


def test_short_serial_is_u32_zero_padded():
    lk, _ = link(hexb("72 00 00 00 04 00 00 00 2A 00 00 00"))
    assert lk.serial() == "0000002a"


@pytest.mark.parametrize("answer, message", [
    (hexb("02 01 01 00 0C"), "frame too short"),
    (hexb("02 01 01 00 0C 00 00 00 00 00 00 00"), "size mismatch"),
    (hexb("00 00 00 80 00 00 00 00"), "not implemented"),
    (hexb("02 01 01 80 0C 00 00 00 00 00 00 00 14 00 00 00 05 00 00 00"), "failed (device errno 5)"),
    (hexb("79 00 00 00 04 00 00 00 00 00 00 00"), "does not match request"),
    (hexb("02 01 01 00 0C 00 00 00 00 00 00 00 18 00 00 00 06 18 40 A0"), "echoes device 0, address 0x18"),
])
def test_bad_answers_raise_named_errors(answer, message):
    lk, _ = link(answer)
    with pytest.raises(TreuzellError, match=message.replace("(", r"\(").replace(")", r"\)")):
        lk.read_reg(0, 0x14)


def test_command_timeout_drains_the_answer_endpoint():
    import errno

    import usb.core

    class Late(CannedDevice):
        reads = 0

        def read(self, ep, size, timeout):
            self.reads += 1
            raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)

    dev = Late()
    lk = tz.TzLink(dev, 0x82, 0x02, sleep_us=lambda us: None, name="EVK4 test")
    with pytest.raises(EvkTimeoutError, match="timeout while sending Treuzell command 0x00010102"):
        lk.read_reg(0, 0x14)
    assert dev.reads == 2  # the command's read, then one drain read that timed out
