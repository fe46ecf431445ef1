"""Treuzell command protocol: byte-exact frames, answer checks, register access, sequences.

A command is one bulk OUT write of a frame ``[property u32 LE][size u32 LE][payload]`` on the
control OUT endpoint, followed by one bulk IN read of the answer (same shape) on the control
IN endpoint (``docs/evk-usb.md`` section 2). Register sequences are tuples of ops (see
:mod:`capture.evk.seq_imx636`).
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Iterable

import usb.core

from .errors import EvkTimeoutError, TreuzellError, usb_error

PROP_FPGA_STATE = 0x00000071
PROP_SERIAL = 0x00000072
PROP_RELEASE_VERSION = 0x00000079
PROP_BUILD_DATE = 0x0000007A
PROP_DEVICES = 0x00010000
PROP_DEVICE_NAME = 0x00010001
PROP_DEVICE_COMPATIBLE = 0x00010003
PROP_DEVICE_ENABLE = 0x00010010
PROP_DEVICE_REG32 = 0x00010102
PROP_DEVICE_STREAM = 0x00010200

FLAG_WRITE = 0x40000000
FLAG_FAILURE = 0x80000000

WRITE_TIMEOUT_MS = 1000
READ_TIMEOUT_MS = 10000
ANSWER_MAX_BYTES = 1024
DRAIN_TIMEOUT_MS = 20


def encode_frame(prop: int, payload: bytes = b"") -> bytes:
    """Request frame: ``prop`` (with flags) and ``payload`` (``bytes``) -> wire bytes."""
    return struct.pack("<II", prop, len(payload)) + bytes(payload)


def words(*values: int) -> bytes:
    """Little-endian u32 payload from integers."""
    return struct.pack(f"<{len(values)}I", *values)


def check_answer(request_prop: int, answer: bytes) -> bytes:
    """Validate an answer frame against the request's property (section 2.5); return its payload.

    Raises
    ------
    TreuzellError
        Frame too short, size mismatch, command not implemented, command failed (with the
        device's errno for register commands) or an answer to another property.
    """
    if len(answer) < 8:
        raise TreuzellError(f"Treuzell answer to 0x{request_prop:08X}: frame too short ({len(answer)} bytes)")
    prop, size = struct.unpack_from("<II", answer)
    if size != len(answer) - 8:
        raise TreuzellError(
            f"Treuzell answer to 0x{request_prop:08X}: size mismatch (field {size}, got {len(answer) - 8} bytes)"
        )
    if prop == FLAG_FAILURE:
        raise TreuzellError(f"Treuzell command 0x{request_prop:08X} not implemented by the device")
    if prop == request_prop | FLAG_FAILURE:
        detail = ""
        if request_prop & ~FLAG_WRITE == PROP_DEVICE_REG32 and len(answer) >= 20:
            detail = f" (device errno {struct.unpack_from('<I', answer, 16)[0]})"
        raise TreuzellError(f"Treuzell command 0x{request_prop:08X} failed{detail}")
    if prop != request_prop:
        raise TreuzellError(
            f"Treuzell answer 0x{prop:08X} does not match request 0x{request_prop:08X}"
        )
    return answer[8:]


def apply_rmw(old: int, value: int, mask: int) -> int:
    """Read-modify-write result: bits of ``value`` under ``mask`` replace those of ``old``."""
    return ((old & ~mask) | (value & mask)) & 0xFFFFFFFF


class TzLink:
    """Treuzell command channel over a claimed pyusb device.

    Parameters
    ----------
    dev : usb.core.Device
        Opened device with its interface claimed.
    ep_in, ep_out : int
        Control IN (answers) and OUT (commands) endpoint addresses.
    sleep_us : callable
        ``sleep_us(us)`` used for sequence delays.
    name : str
        Camera name for error messages.
    """

    def __init__(self, dev, ep_in: int, ep_out: int, *, sleep_us: Callable[[int], None], name: str):
        self.dev = dev
        self.ep_in = ep_in
        self.ep_out = ep_out
        self.sleep_us = sleep_us
        self.name = name
        self._lock = threading.Lock()

    def command(self, prop: int, payload: bytes = b"") -> bytes:
        """Send one command and return the validated answer payload (lock held for the pair)."""
        frame = encode_frame(prop, payload)
        what = f"sending Treuzell command 0x{prop:08X} to {self.name}"
        with self._lock:
            try:
                self.dev.write(self.ep_out, frame, WRITE_TIMEOUT_MS)
                answer = self.dev.read(self.ep_in, ANSWER_MAX_BYTES, READ_TIMEOUT_MS)
            except usb.core.USBError as exc:
                err = usb_error(exc, what)
                if isinstance(err, EvkTimeoutError):
                    # Our recommendation (not the HAL's): drain so a late answer cannot be
                    # taken for the answer to the next command.
                    self._drain()
                raise err from exc
        return check_answer(prop, bytes(answer))

    def _drain(self) -> None:
        for _ in range(64):
            try:
                self.dev.read(self.ep_in, ANSWER_MAX_BYTES, DRAIN_TIMEOUT_MS)
            except usb.core.USBError:
                return

    # ---- properties ------------------------------------------------------------------
    def get_u32(self, prop: int) -> int:
        payload = self.command(prop)
        if len(payload) < 4:
            raise TreuzellError(f"Treuzell answer to 0x{prop:08X} from {self.name}: {len(payload)} bytes, need 4")
        return struct.unpack_from("<I", payload)[0]

    def serial(self) -> str:
        """Serial number in the HAL's form: lowercase hex, at least 8 digits."""
        payload = self.command(PROP_SERIAL)
        if len(payload) >= 8:
            value = struct.unpack_from("<Q", payload)[0]
        elif len(payload) >= 4:
            value = struct.unpack_from("<I", payload)[0]
        else:
            raise TreuzellError(f"serial number answer from {self.name} has {len(payload)} bytes")
        return f"{value:08x}"

    def build_date(self) -> int:
        """Firmware build date, Unix seconds."""
        payload = self.command(PROP_BUILD_DATE)
        if len(payload) < 8:
            raise TreuzellError(f"build date answer from {self.name} has {len(payload)} bytes")
        return struct.unpack_from("<Q", payload)[0]

    def device_strings(self, prop: int, device: int) -> list[str]:
        """NUL-separated strings of ``TZ_PROP_DEVICE_NAME`` / ``..._COMPATIBLE`` for ``device``."""
        payload = self.command(prop, words(device))
        if len(payload) < 5 or payload[-1] != 0:
            raise TreuzellError(
                f"malformed string answer to 0x{prop:08X} for device {device} from {self.name}"
            )
        # The HAL reads the strings whatever device id the answer echoes; so do we.
        return [s.decode("ascii", "replace") for s in payload[4:-1].split(b"\0")]

    def set_device_flag(self, prop: int, device: int, on: bool) -> None:
        """``TZ_PROP_DEVICE_ENABLE`` / ``_STREAM`` write (answer not checked beyond framing)."""
        self.command(prop | FLAG_WRITE, words(device, int(on)))

    # ---- registers -------------------------------------------------------------------
    def read_reg(self, device: int, address: int) -> int:
        """Read one 32-bit register."""
        payload = self.command(PROP_DEVICE_REG32, words(device, address, 1))
        if len(payload) < 12:
            raise TreuzellError(
                f"register read 0x{address:X} from {self.name}: answer has {len(payload)} bytes, need 12"
            )
        dev_echo, addr_echo, value = struct.unpack_from("<III", payload)
        if dev_echo != device or addr_echo != address:
            raise TreuzellError(
                f"register read 0x{address:X} from {self.name}: answer echoes device {dev_echo}, address 0x{addr_echo:X}"
            )
        return value

    def write_reg(self, device: int, address: int, value: int) -> None:
        """Write one 32-bit register."""
        prop = PROP_DEVICE_REG32 | FLAG_WRITE
        payload = self.command(prop, words(device, address, value & 0xFFFFFFFF))
        if len(payload) < 8:
            raise TreuzellError(f"register write 0x{address:X} to {self.name}: answer has {len(payload)} bytes")
        dev_echo, addr_echo = struct.unpack_from("<II", payload)
        if dev_echo != device or addr_echo != address:
            raise TreuzellError(
                f"register write 0x{address:X} to {self.name}: answer echoes device {dev_echo}, address 0x{addr_echo:X}"
            )

    def rmw(self, device: int, address: int, value: int, mask: int) -> int:
        """Read-modify-write the bits under ``mask``; return the written word."""
        new = apply_rmw(self.read_reg(device, address), value, mask)
        self.write_reg(device, address, new)
        return new

    def run(self, device: int, ops: Iterable[tuple]) -> list[int]:
        """Execute a sequence of ops in order; return the values of its ``R`` ops."""
        reads = []
        for op in ops:
            kind = op[0]
            if kind == "W":
                self.write_reg(device, op[1], op[2])
            elif kind == "RMW":
                self.rmw(device, op[1], op[2], op[3])
            elif kind == "R":
                reads.append(self.read_reg(device, op[1]))
            elif kind == "D":
                self.sleep_us(op[1])
            else:
                raise ValueError(f"unknown sequence op {op!r}")
        return reads


def sleep_us(us: int) -> None:
    """Real-time delay of ``us`` microseconds (nominal, never shorter than the HAL's)."""
    time.sleep(us / 1e6)
