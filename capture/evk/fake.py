"""A file-backed fake Prophesee EVK: a real pyusb backend (``usb.backend.IBackend``).

``capture.evk.open(backend=FakeEVK("rec.raw"))`` runs the unmodified driver against it, the
way pyusb itself swaps libusb1 / libusb0 / openusb. The fake

- enumerates as one EVK4 (``04B4:00F5``) or EVK3 (``04B4:00F4``) with the documented
  configuration: interface 0 (class 0xFF, subclass 0x19) with bulk endpoints 0x82 IN,
  0x02 OUT, 0x81 IN in that order, and manufacturer / product strings;
- answers the Treuzell protocol from a register model and records every access in order in
  :attr:`FakeEVK.log` (``("W", device, address, value)``, ``("R", device, address)``,
  ``("D", microseconds)`` for driver delays, ``("prop", property, payload)`` for other
  commands and ``("usb", action, ...)`` for USB-level calls);
- streams the payload of a RAW file (after its ``%`` header; EVT3, or EVT 2.1 for the IMX636
  once the driver selected it) on the data endpoint once the sensor's start sequence ran, in device packets of the given sizes, either as fast as
  possible (``pace="max"``) or paced so that the stream's own timestamps (EVT3 / EVT2
  TIME_HIGH words) drive wall-clock time (``pace="recorded"``), through an optional finite
  device FIFO and USB link throughput (:mod:`capture.evk.fake_data`): data produced while no
  request is pending and the FIFO is full is lost, as on the camera;
- answers synchronous reads (pyusb's ``bulk_read``) and queued requests (the
  ``bulk_in_queue`` hook, :mod:`capture.evk.transfers`) from the same device model;
- injects faults: data-endpoint silence, stall or unplug after N bytes, permission denied,
  interface busy, old firmware, early-quirk ``bcdDevice``.

Driver hooks it offers (the driver uses them when present): ``sleep_us(us)`` records the
sequence delays instead of sleeping (``realtime_delays=True`` sleeps too), and
``end_of_stream()`` tells the recorder that the whole file has been served.
"""

from __future__ import annotations

import array
import errno
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import usb.backend
import usb.core

from . import seq_imx636
from .fake_data import GONE, STALL, DataSide, wait_for
from .transfers import Done
from .treuzell import (
    FLAG_FAILURE,
    FLAG_WRITE,
    PROP_BUILD_DATE,
    PROP_DEVICE_COMPATIBLE,
    PROP_DEVICE_ENABLE,
    PROP_DEVICE_NAME,
    PROP_DEVICE_REG32,
    PROP_DEVICE_STREAM,
    PROP_DEVICES,
    PROP_RELEASE_VERSION,
    PROP_SERIAL,
)

EP_CTRL_IN, EP_CTRL_OUT, EP_DATA = 0x82, 0x02, 0x81
log = logging.getLogger(__name__)
LIBUSB_SPEED_SUPER = 4

_SENSORS = {
    "imx636": dict(
        pid=0x00F5,
        product="EVK4",
        name="CCam5 Imx636 Event-Based Camera",
        compatible=("psee,ccam5_imx636", "psee,ccam5_gen42"),
        registers={
            0x0014: seq_imx636.CHIP_ID,
            0xF128: 0x0,
            0x00400010: 0xCAFEBABE,
            0x0004: 0xF0005042,
            0x4058: 0x00FF0000,
            0x6000: 0x00155400,
            0x6008: 0x80,
            0x600C: 0x80,
            0x7000: 0xFFFF0001,
            0x7004: 0xC1FF,
            0x8000: 0x0001E085,
            0x9008: 0x640,
            # Anti-flicker block at its register-map defaults, initialisation done.
            0xC004: 0x34, 0xC008: 0x89C0F, 0xC0C0: 0x0A05A5A0, 0xC0C4: 0x4,
            # Trail filter (STC) block at its register-map defaults, not initialised; bypassed (0x5:
            # assumed, the map gives 0; the HAL writes it before anything else).
            0xD000: 0x5, 0xD004: 0x2710 << 1, 0xD008: 0x186A0 << 1, 0xD00C: 0xD | 1 << 5 | 1 << 9,
            0xD0C0: 4 | 0x118 << 12 | 0xA << 24,
            0x0044: 0xCCFFFCCF,  # dig_pad2_ctrl: SYNC pad as input
            # Factory-trimmed bias registers (ND's EVK4 values; idac_ctl in the low byte).
            0x1004: 0x11A1E853,
            0x100C: 0x11A1FF00,
            0x1010: 0x11A16366,
            0x1014: 0x11A1504D,
            0x1018: 0x11A13749,
            0x1020: 0x11A29614,
        },
    ),
    "gen31": dict(
        pid=0x00F4,
        product="EVK3",
        name="CCam5 Gen31 FPGA",
        compatible=("psee,ccam5_fpga",),
        registers={0x0800: 0x28, 0x0218: 0x90200C02, 0x0204: 0x0B},
    ),
    "gen41": dict(
        pid=0x00F4,
        product="EVK3",
        name="CCam5 Gen41 Event-Based Camera",
        compatible=("psee,ccam5_gen41",),
        registers={0x0014: 0xA0301003, 0x7004: 0xC1FF, 0x6000: 0x00155400, 0x9008: 0x640,
                   0xC004: 0x34, 0xC008: 0x89C0F, 0xC0C0: 0x0A05A5A0, 0xC0C4: 0x4,
                   0x1004: 0x11A1004A, 0x100C: 0x11A10000, 0x1010: 0x11A10073,
                   0x1014: 0x11A10050, 0x1018: 0x11A10034, 0x1020: 0x11A10044},
    ),
}


def _running(sensor: str, regs: Mapping[int, int]) -> bool:
    """Whether the sensor's start sequence has made it stream (and stop has not)."""
    if sensor == "gen31":
        return bool(regs.get(0x0000, 0) & (1 << 18))  # ATIS_CONTROL.TD_RSTN
    return (
        not regs.get(0x9028, 0) & 0x2  # ro_ctrl.output_disable
        and bool(regs.get(0x9008, 0) & 0x1)  # time base enabled
        and bool(regs.get(0x0004, 0) & (1 << 10))  # px_td_rstn: pixels released
    )


def _usb_error(code: int, err: int, text: str) -> usb.core.USBError:
    return usb.core.USBError(text, code, err)


def _split_raw(data: bytes) -> tuple[bytes, str | None, bool]:
    """(payload, format, legacy) of a RAW file's bytes: skip the ``%`` header lines (format None
    when the header names none; legacy: EVT 2.1 words in the legacy order, the IMX636's)."""
    pos = 0
    fmt = None
    legacy = False
    while pos < len(data) and data[pos:pos + 1] == b"%":
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end + 1
        line = data[pos:end].decode("ascii", "replace").lower()
        if "evt 2.0" in line or "format evt2" in line and "evt21" not in line:
            fmt = "EVT2"
        elif "evt 2.1" in line or "format evt21" in line:
            fmt = "EVT21"
        elif "evt 3.0" in line or "format evt3" in line:
            fmt = "EVT3"
        legacy |= "endianness=legacy" in line or line.split() == ["%", "endianness", "legacy"]
        pos = end
        if line.strip() == "% end":
            break
    return data[pos:], fmt, legacy


class _Handle:
    pass


class FakeEVK(usb.backend.IBackend):
    """Emulated EVK as a pyusb backend.

    Parameters
    ----------
    raw_path : str or Path or None
        RAW file whose payload is streamed; ``None`` streams nothing (bring-up only).
    sensor : {"imx636", "gen31", "gen41"}
        Emulated sensor: IMX636 on an EVK4 (default), Gen3.1 VGA or Gen4.1 on an EVK3.
    pace : {"max", "recorded"}
        ``"max"`` serves data as fast as it is read; ``"recorded"`` releases each packet
        when wall-clock time since streaming began reaches its stream time / ``speed``.
    speed : float
        Playback speed factor for ``pace="recorded"``.
    packet_bytes : int or sequence of int
        Device-side packet (transfer) sizes, cycled. A packet whose size is not a multiple
        of ``max_packet_size`` ends in a short USB packet, which ends a host read.
    max_packet_size : int
        ``wMaxPacketSize`` of the bulk endpoints (1024 SuperSpeed, 512 High Speed).
    serial : int
        Serial number (u64) answered to ``TZ_PROP_SERIAL``.
    firmware_version : int
        ``major << 16 | minor << 8 | patch``; below ``0x030800`` the driver must refuse.
    bcd_device : int
        ``bcdDevice``; below ``0x0307`` the driver must skip SET_INTERFACE.
    registers : mapping, optional
        Register values overriding the sensor's defaults (e.g. a wrong chip id).
    extra_devices : sequence of (compatible, name)
        Additional Treuzell devices after device 0 (e.g. ``("treuzell,streamer", "dma")``).
    faults : mapping of (int, int) to str
        Fault injection per ``(Treuzell property, device id)``: ``"fail"`` answers with the
        failure flag, ``"echo"`` echoes another device id, ``"timeout"`` never answers (the
        read times out). Writes of ENABLE/STREAM are matched by their property without the
        write flag.
    pause_after_bytes : (int, float), optional
        After serving that many bytes, the data endpoint is silent (timeouts) for that
        many seconds.
    stall_after_bytes, disconnect_after_bytes : int, optional
        After serving that many bytes the data endpoint stalls (EPIPE) / the device is
        unplugged (ENODEV on every call).
    permission_denied, busy : bool
        ``open_device`` fails with EACCES / ``claim_interface`` fails with EBUSY.
    kernel_driver_active : bool
        Report a kernel driver bound to interface 0 (the driver must detach it).
    realtime_delays : bool
        Really sleep the driver's sequence delays (default: only record them).
    temperature_c : float
        Die temperature the IMX636's ADC converts, °C.
    illuminance_lux : float
        Light level whose LIFO on-time count the IMX636 reports, lux.
    fifo_bytes : int, optional
        Device FIFO between sensor and USB (e.g. ``fake_data.EVK_FIFO_BYTES``); ``None`` (default)
        never loses data.
    link_bytes_s : float, optional
        USB throughput, bytes/s (``fake_data.USB3_LINK_BYTES_S``, ``USB2_LINK_BYTES_S``);
        ``None`` (default) is unlimited.
    usbfs_bytes : int, optional
        Memory for pending queued requests (Linux's usbfs budget, 16 MiB by default and shared
        by every device); a request beyond it fails with ENOMEM. ``None``: no limit.
    """

    def __init__(
        self,
        raw_path=None,
        *,
        sensor: str = "imx636",
        pace: str = "max",
        speed: float = 1.0,
        packet_bytes: int | Sequence[int] = 131072,
        max_packet_size: int = 1024,
        serial: int = 0x00000000A1B2C3D4,
        firmware_version: int = 0x030900,
        build_date: int = 1_700_000_000,
        bcd_device: int = 0x0310,
        registers: Mapping[int, int] | None = None,
        extra_devices: Sequence[tuple[str, str]] = (),
        faults: Mapping[tuple[int, int], str] | None = None,
        pause_after_bytes: tuple[int, float] | None = None,
        stall_after_bytes: int | None = None,
        disconnect_after_bytes: int | None = None,
        permission_denied: bool = False,
        busy: bool = False,
        kernel_driver_active: bool = False,
        realtime_delays: bool = False,
        temperature_c: float = 38.0,
        illuminance_lux: float = 800.0,
        fifo_bytes: int | None = None,
        link_bytes_s: float | None = None,
        usbfs_bytes: int | None = None,
    ):
        if sensor not in _SENSORS:
            raise ValueError(f"sensor must be one of {sorted(_SENSORS)}, got {sensor!r}")
        if pace not in ("max", "recorded"):
            raise ValueError(f"pace must be 'max' or 'recorded', got {pace!r}")
        if speed <= 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.sensor = sensor
        spec = _SENSORS[sensor]
        self.pace = pace
        self.speed = float(speed)
        self.max_packet_size = int(max_packet_size)
        self.serial = serial
        self.firmware_version = firmware_version
        self.build_date = build_date
        self.bcd_device = bcd_device
        self.permission_denied = permission_denied
        self.busy = busy
        self.faults = dict(faults or {})
        self.realtime_delays = realtime_delays
        self.temperature_c = float(temperature_c)
        self.illuminance_lux = float(illuminance_lux)
        self._kernel_driver = kernel_driver_active
        self.devices = [(spec["compatible"], spec["name"])] + [((c,), n) for c, n in extra_devices]
        self.registers: dict[int, int] = dict(spec["registers"])
        self.registers.update(registers or {})
        self.reset_registers = dict(self.registers)
        self.log: list[tuple] = []
        self.device_flags: dict[tuple[int, int], int] = {}

        self._desc = SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x0320, bDeviceClass=0, bDeviceSubClass=0,
            bDeviceProtocol=0, bMaxPacketSize0=9, idVendor=0x04B4, idProduct=spec["pid"],
            bcdDevice=bcd_device, iManufacturer=1, iProduct=2, iSerialNumber=0,
            bNumConfigurations=1, address=7, bus=2, port_number=1, port_numbers=(1,),
            speed=LIBUSB_SPEED_SUPER,
        )
        self._strings = {1: "Prophesee", 2: spec["product"]}
        self._answers: list[bytes] = []
        self._gone = False
        self._open = False
        self._claimed = False

        if raw_path is not None:
            data = Path(raw_path).read_bytes()
            if not data:
                raise ValueError(f"FakeEVK: {raw_path} is empty")
            payload, self.format, legacy = _split_raw(data)
            if self.format == "EVT21" and not legacy:
                raise ValueError(f"FakeEVK: {raw_path} is EVT 2.1 in the standard word order; an IMX636 "
                                 "streams the legacy order (endianness=legacy)")
            streams = ("EVT3", "EVT21") if sensor == "imx636" else ("EVT3",)
            if self.format not in streams:  # what the emulated sensor can be set to stream
                raise ValueError(f"FakeEVK: {raw_path} is " + (f"an {self.format} recording" if self.format else
                                 "not a Prophesee RAW recording (no header naming its format)")
                                 + f"; the emulated {spec['product']} streams {' or '.join(streams)} "
                                 "(read other files with capture.ingest raw)")
            if not payload:
                raise ValueError(f"FakeEVK: {raw_path} holds no event data")
        else:
            payload, self.format = b"", "EVT3"
        self.payload = payload
        sizes = np.atleast_1d(np.asarray(packet_bytes, dtype=np.int64))
        if sizes.size == 0 or (sizes <= 0).any():
            raise ValueError("packet_bytes must be positive")
        if fifo_bytes is not None and fifo_bytes <= 0:
            raise ValueError(f"fifo_bytes must be > 0, got {fifo_bytes}")
        if link_bytes_s is not None and link_bytes_s <= 0:
            raise ValueError(f"link_bytes_s must be > 0, got {link_bytes_s}")
        reps = -(-len(payload) // int(sizes.sum())) if payload else 0
        ends = np.cumsum(np.tile(sizes, max(reps, 1)))
        ends = ends[: np.searchsorted(ends, len(payload)) + 1]
        ends[-1] = len(payload)
        ends = ends if payload else np.zeros(0, dtype=np.int64)
        starts = np.concatenate([[0], ends[:-1]]) if payload else ends
        short = ((ends - starts) % self.max_packet_size) != 0
        self._data = DataSide(payload, self.format, ends, short, pace=pace, speed=self.speed,
                              fifo_bytes=fifo_bytes, link_bytes_s=link_bytes_s,
                              stall_at=stall_after_bytes, gone_at=disconnect_after_bytes,
                              pause=pause_after_bytes)
        self.usbfs_bytes = usbfs_bytes
        self._stc_done = False
        self._warned_format = False
        self._lock = threading.Lock()

    # ---- test helpers -----------------------------------------------------------------
    @property
    def bytes_served(self) -> int:
        """Bytes delivered on the data endpoint so far."""
        return self._data.served

    def served_payload(self) -> bytes:
        """Every byte delivered on the data endpoint so far, in order (the payload less what the
        device FIFO lost)."""
        return b"".join(self.payload[s:e] for s, e in self._data.served_ranges)

    @property
    def dropped_bytes(self) -> int:
        """Bytes the device FIFO could not hold (lost before the host saw them)."""
        return self._data.dropped_bytes

    def register_log(self) -> list[tuple]:
        """The ``R``/``W``/``D`` entries of :attr:`log`, in order."""
        return [e for e in self.log if e[0] in ("R", "W", "D")]

    def unplug(self) -> None:
        """Emulate pulling the cable now."""
        self._gone = self._data.gone = True

    # ---- driver hooks -----------------------------------------------------------------
    def sleep_us(self, us: int) -> None:
        """Sequence delay: recorded (and slept when ``realtime_delays``)."""
        self.log.append(("D", int(us)))
        if self.realtime_delays:
            time.sleep(us / 1e6)

    def end_of_stream(self) -> bool:
        """True once the whole payload has been served (nothing more will come)."""
        return self._data.exhausted

    @property
    def device_buffer_bytes(self) -> int | None:
        """The fake's FIFO, bytes (``None``: unbounded, it never loses data); the driver takes
        it in place of ``Camera.device_buffer_bytes`` to judge spells without a request."""
        return self._data.fifo_bytes

    # ---- enumeration and descriptors ----------------------------------------------------
    def _check_present(self):
        if self._gone or self._data.gone:
            raise _usb_error(-4, errno.ENODEV, "No such device (it may have been disconnected)")

    def enumerate_devices(self):
        if not self._gone:
            yield self

    def get_parent(self, dev):
        return None

    def get_device_descriptor(self, dev):
        return self._desc

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(config)
        return SimpleNamespace(
            bLength=9, bDescriptorType=2, wTotalLength=9 + 9 + 3 * 7, bNumInterfaces=1,
            bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80, bMaxPower=112,
            extra_descriptors=[],
        )

    def get_interface_descriptor(self, dev, intf, alt, config):
        if config != 0 or intf != 0 or alt != 0:
            raise IndexError((intf, alt, config))
        return SimpleNamespace(
            bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
            bNumEndpoints=3, bInterfaceClass=0xFF, bInterfaceSubClass=0x19,
            bInterfaceProtocol=0, iInterface=0, extra_descriptors=[],
        )

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        addresses = (EP_CTRL_IN, EP_CTRL_OUT, EP_DATA)
        if config != 0 or intf != 0 or alt != 0 or not 0 <= ep < 3:
            raise IndexError((ep, intf, alt, config))
        return SimpleNamespace(
            bLength=7, bDescriptorType=5, bEndpointAddress=addresses[ep], bmAttributes=0x02,
            wMaxPacketSize=self.max_packet_size, bInterval=0, bRefresh=0, bSynchAddress=0,
            extra_descriptors=[],
        )

    # ---- device handle ------------------------------------------------------------------
    def open_device(self, dev):
        self._check_present()
        if self.permission_denied:
            raise _usb_error(-3, errno.EACCES, "Access denied (insufficient permissions)")
        self.log.append(("usb", "open"))
        self._open = True
        return _Handle()

    def close_device(self, dev_handle):
        self.log.append(("usb", "close"))
        self._open = False

    def get_configuration(self, dev_handle):
        self._check_present()
        return 1

    def set_configuration(self, dev_handle, config_value):
        self._check_present()
        self.log.append(("usb", "set_configuration", config_value))

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        self._check_present()
        self.log.append(("usb", "set_interface", intf, altsetting))

    def claim_interface(self, dev_handle, intf):
        self._check_present()
        if self.busy:
            raise _usb_error(-6, errno.EBUSY, "Resource busy")
        self.log.append(("usb", "claim", intf))
        self._claimed = True

    def release_interface(self, dev_handle, intf):
        self.log.append(("usb", "release", intf))
        self._claimed = False

    def is_kernel_driver_active(self, dev_handle, intf):
        self._check_present()
        return self._kernel_driver

    def detach_kernel_driver(self, dev_handle, intf):
        self._check_present()
        self.log.append(("usb", "detach_kernel_driver", intf))
        self._kernel_driver = False

    def clear_halt(self, dev_handle, ep):
        self._check_present()
        self.log.append(("usb", "clear_halt", ep))
        if ep == EP_DATA:
            self._data.stalled = False

    def reset_device(self, dev_handle):
        self._check_present()
        self.log.append(("usb", "reset"))

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        self._check_present()
        if bmRequestType == 0x80 and bRequest == 6 and wValue >> 8 == 3:  # GET_DESCRIPTOR string
            index = wValue & 0xFF
            if index == 0:
                desc = bytes([4, 3, 0x09, 0x04])
            elif index in self._strings:
                text = self._strings[index].encode("utf-16-le")
                desc = bytes([2 + len(text), 3]) + text
            else:
                raise _usb_error(-9, errno.EPIPE, "Pipe error")
        elif bmRequestType == 0xC0 and bRequest == 0x72:  # vendor: system id (ND)
            desc = bytes([0x31 if self.sensor == "imx636" else 0x28 if self.sensor == "gen31" else 0x30, 0])
        else:
            raise _usb_error(-9, errno.EPIPE, "Pipe error")
        n = min(len(desc), len(data))
        data[:n] = array.array("B", desc[:n])
        return n

    # ---- bulk transfers -----------------------------------------------------------------
    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        self._check_present()
        if ep != EP_CTRL_OUT:
            raise _usb_error(-9, errno.EPIPE, "Pipe error")
        frame = bytes(data)
        answer = self._answer(frame)
        if answer is not None:  # None: a "timeout" fault, no answer at all
            self._answers.append(answer)
        return len(frame)

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        self._check_present()
        if ep == EP_CTRL_IN:
            if not self._answers:
                time.sleep(min(timeout, 50) / 1000)
                raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
            answer = self._answers.pop(0)
            if len(answer) > len(buff):
                raise _usb_error(-8, errno.EOVERFLOW, "Overflow")
            memoryview(buff).cast("B")[: len(answer)] = answer
            return len(answer)
        if ep == EP_DATA:
            return self._data_read(buff, timeout)
        raise _usb_error(-9, errno.EPIPE, "Pipe error")

    # ---- Treuzell -----------------------------------------------------------------------
    def _answer(self, frame: bytes) -> bytes:
        if len(frame) < 8:
            return struct.pack("<II", FLAG_FAILURE, 0)
        prop, size = struct.unpack_from("<II", frame)
        payload = frame[8:8 + size]
        base = prop & ~FLAG_WRITE
        write = bool(prop & FLAG_WRITE)

        def ok(body: bytes) -> bytes:
            return struct.pack("<II", prop, len(body)) + body

        def fail(body: bytes = b"") -> bytes:
            return struct.pack("<II", prop | FLAG_FAILURE, len(body)) + body

        n_words = len(payload) // 4
        w = struct.unpack_from(f"<{n_words}I", payload) if n_words else ()
        fault = self.faults.get((base, w[0])) if n_words and base != PROP_DEVICE_REG32 else None
        if fault == "timeout":
            self.log.append(("prop", prop, payload))
            return None
        if fault == "fail":
            self.log.append(("prop", prop, payload))
            return fail(payload[:4])
        if fault == "echo":
            payload = struct.pack("<I", w[0] + 1) + payload[4:]
        if base == PROP_DEVICE_REG32 and n_words >= 3:
            device, address = w[0], w[1]
            if device >= len(self.devices):
                return fail(struct.pack("<III", device, address, errno.ENODEV))
            if write:
                with self._lock:
                    for i, value in enumerate(w[2:]):
                        self.registers[address + 4 * i] = value
                        self.log.append(("W", device, address + 4 * i, value))
                        if self.sensor == "imx636" and address + 4 * i == seq_imx636.ADC_CONTROL:
                            self._adc_convert()
                        if self.sensor == "imx636" and address + 4 * i == seq_imx636.STC_INITIALIZATION:
                            self._stc_init(value)
                return ok(struct.pack("<II", device, address))
            count = w[2]
            values = []
            with self._lock:
                for i in range(count):
                    if self.sensor == "imx636" and address + 4 * i == seq_imx636.LIFO_STATUS:
                        self._lifo_count()
                    values.append(self.registers.get(address + 4 * i, 0))
                    self.log.append(("R", device, address + 4 * i))
            return ok(struct.pack(f"<II{count}I", device, address, *values))
        self.log.append(("prop", prop, payload))
        if write:
            if base in (PROP_DEVICE_ENABLE, PROP_DEVICE_STREAM) and n_words >= 2:
                self.device_flags[(base, w[0])] = w[1]
                return ok(payload[:4])
            return struct.pack("<II", FLAG_FAILURE, 0)
        if base == PROP_SERIAL:
            return ok(struct.pack("<Q", self.serial))
        if base == PROP_RELEASE_VERSION:
            return ok(struct.pack("<I", self.firmware_version))
        if base == PROP_BUILD_DATE:
            return ok(struct.pack("<Q", self.build_date))
        if base == PROP_DEVICES:
            return ok(struct.pack("<I", len(self.devices)))
        if base in (PROP_DEVICE_NAME, PROP_DEVICE_COMPATIBLE) and n_words >= 1:
            if w[0] >= len(self.devices):
                return fail(payload[:4])
            compatible, name = self.devices[w[0]]
            strings = (name,) if base == PROP_DEVICE_NAME else compatible
            return ok(payload[:4] + b"".join(s.encode("ascii") + b"\0" for s in strings))
        return struct.pack("<II", FLAG_FAILURE, 0)

    def _adc_convert(self) -> None:
        """The IMX636's ADC: a start with its clock on and the temperature input selected leaves
        the die temperature (``temperature_c``) in ``adc_status`` with the done flag."""
        s = seq_imx636
        ctrl, misc = self.registers.get(s.ADC_CONTROL, 0), self.registers.get(s.ADC_MISC_CTRL, 0)
        if ctrl & 0b110 == 0b110 and misc >> 12 & 1:
            dac = int(round((self.temperature_c - s.TEMPERATURE_OFFSET_C) / s.TEMPERATURE_C_PER_STEP)) & 0x3FF
            self.registers[s.ADC_STATUS] = 1 << 11 | dac
            self.registers[s.ADC_CONTROL] = ctrl & ~(1 << 2)  # the start bit clears itself

    def _stc_init(self, written: int) -> None:
        """The trail filter's SRAM init: writing 1 to ``stc_flag_init_done`` [2] clears it, a
        request ``stc_req_init`` [0] completes at once and sets it (the request bit clears)."""
        done = bool(self._stc_done) and not written >> 2 & 1
        if written & 1:
            done = True
        self._stc_done = done
        self.registers[seq_imx636.STC_INITIALIZATION] = (written & ~0b101) | int(done) << 2

    def _lifo_count(self) -> None:
        """The IMX636's LIFO light counter, counting (lifo_en and lifo_cnt_en set): the on-time
        count that the HAL's conversion turns into ``illuminance_lux``, flagged valid."""
        s = seq_imx636
        if self.registers.get(s.LIFO_CONTROL, 0) & 0b101 == 0b101 and self.illuminance_lux > 0:
            counter = int(round(s.lifo_counter(self.illuminance_lux)))
            self.registers[s.LIFO_STATUS] = 1 << 29 | min(max(counter, 1), (1 << 27) - 1)

    # ---- data endpoint ------------------------------------------------------------------
    def _data_read(self, buff, timeout_ms: int) -> int:
        """One synchronous read: a single request pending until it completes (pyusb)."""
        side = self._data
        with self._lock:
            if side.stalled:
                raise _usb_error(-9, errno.EPIPE, "Pipe error")
            req = side.submit(memoryview(buff).cast("B"), timeout_ms, time.monotonic(), self._running())
        wait_for(side, req, self._running, self._lock)
        with self._lock:
            side.requests.remove(req)
        if req.got and req.status in ("completed", "timed_out", STALL, GONE):
            return req.got  # libusb: TIMED_OUT with data; pyusb returns the count
        if req.status == GONE:
            raise _usb_error(-4, errno.ENODEV, "No such device (it may have been disconnected)")
        if req.status == STALL:
            raise _usb_error(-9, errno.EPIPE, "Pipe error")
        raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)

    def _running(self) -> bool:
        """Streaming, in the file's format: an EVT2.1 file streams once the driver selected
        EVT2.1 (``edf/pipeline_control`` bit 1), an EVT3 file while EVT3 is selected."""
        running = _running(self.sensor, self.registers)
        if self.sensor == "imx636" and bool(self.registers.get(seq_imx636.EDF_PIPELINE_CONTROL, 0) & 0x2) != (
                self.format == "EVT21"):
            if running and not self._warned_format:
                self._warned_format = True
                log.warning("fake EVK: its recording is %s but the driver selected the other format, so "
                            "nothing is streamed (select %s: --event-format %s)", self.format, self.format, self.format)
            return False
        return running

    def bulk_in_queue(self, dev_handle, ep: int) -> FakeQueue:
        """Asynchronous bulk-IN requests on ``ep`` (the hook :func:`capture.evk.transfers.open_queue`
        uses): the same interface as :class:`capture.evk.transfers.LibusbQueue`."""
        self._check_present()
        if ep != EP_DATA:
            raise _usb_error(-9, errno.EPIPE, "Pipe error")
        self.log.append(("usb", "queue", ep))
        return FakeQueue(self)


class FakeQueue:
    """Queued requests on the fake's data endpoint; they fill while Python does other things
    (the device model is brought up to date at each call, see :mod:`capture.evk.fake_data`)."""

    def __init__(self, fake: FakeEVK):
        self._fake = fake
        self._order: deque = deque()  # (request, buffer)

    @property
    def pending(self) -> int:
        return len(self._order)

    @property
    def incomplete(self) -> int:
        """Requests still on the endpoint (submitted, not complete), as of the last call."""
        return sum(req.status is None for req, _ in self._order)

    def submit(self, buffer, timeout_ms: int) -> None:
        fake = self._fake
        with fake._lock:
            fake._check_present()
            in_use = sum(r.size for r in fake._data.requests)
            if fake.usbfs_bytes is not None and in_use + len(buffer) > fake.usbfs_bytes:
                raise _usb_error(-11, errno.ENOMEM, "Insufficient memory")
            req = fake._data.submit(memoryview(buffer).cast("B"), timeout_ms, time.monotonic(), fake._running())
        self._order.append((req, buffer))

    def reap(self, timeout_s: float) -> Done | None:
        if not self._order:
            return None
        fake = self._fake
        req, buffer = self._order[0]
        if not wait_for(fake._data, req, fake._running, fake._lock, time.monotonic() + timeout_s):
            return None
        with fake._lock:
            fake._data.requests.remove(req)
        self._order.popleft()
        return Done(buffer, req.got, req.status)

    def cancel(self) -> None:
        with self._fake._lock:
            self._fake._data.advance(time.monotonic(), self._fake._running())
            for req, _ in self._order:
                if req.status is None:
                    req.status = "cancelled"

    def close(self) -> None:
        self.cancel()
        with self._fake._lock:
            for req, _ in self._order:
                self._fake._data.requests.remove(req)
        self._order.clear()
