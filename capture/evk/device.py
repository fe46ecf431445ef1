"""Discovery and opening of Prophesee EVK3/EVK4 cameras over pyusb, and the :class:`Camera`.

Follows ``docs/evk-usb.md`` section 1.3 in order: early quirk from ``bcdDevice``, interface /
endpoint scan by position, open and read strings, detach a kernel driver, claim ("busy" on
failure), SET_INTERFACE (unless the quirk applies; never SET_CONFIGURATION), firmware version
and build date, refusal of firmware < 3.8.0, Treuzell enumeration and sensor identification,
then the sensor's bring-up sequences.
"""

from __future__ import annotations

import errno
import logging
import threading
from dataclasses import dataclass, field

import usb.core
import usb.util

from . import treuzell as tz
from .errors import (
    EvkBusyError,
    EvkConnectionError,
    EvkDisconnectedError,
    EvkError,
    EvkFirmwareError,
    EvkNotFoundError,
    EvkPermissionError,
    TreuzellError,
    usb_error,
)
from .sensors import IMX646_COMPATIBLE, driver_for
from .stream import Reader
from .transfers import open_queue

log = logging.getLogger(__name__)

BOARDS = {(0x04B4, 0x00F5): "EVK4", (0x04B4, 0x00F4): "EVK3"}
"""USB ids of the Treuzell boards this driver supports (Cypress CX3 bridge)."""

EARLY_QUIRK_BCD = 0x0307  # below: do not SET_INTERFACE
MIN_FIRMWARE = 0x030800  # 3.8.0, as the HAL
FALLBACK_ENDPOINTS = (0x82, 0x02, 0x81)  # EVK4 values, used only if the scan finds nothing
LIBUSB_SPEED_SUPER = 4
SENSOR_NAMES = {
    "psee,ccam5_imx636": "IMX636", "psee,ccam5_gen42": "IMX636",
    "psee,ccam5_fpga": "Gen3.1", "psee,ccam5_gen41": "Gen4.1", IMX646_COMPATIBLE: "IMX646",
}
STREAMER = "treuzell,streamer"


@dataclass
class DeviceInfo:
    """What is known about a connected EVK.

    ``serial`` is the HAL-style lowercase hex serial; ``firmware`` is "major.minor.patch";
    ``build_date_s`` Unix seconds; ``width``/``height`` pixels; ``error`` says why a listed
    device could not be queried (e.g. permission denied), else ``None``.
    """

    serial: str | None
    board: str
    sensor: str | None = None
    width: int | None = None
    height: int | None = None
    format: str | None = None
    firmware: str | None = None
    build_date_s: int | None = None
    bus: int | None = None
    address: int | None = None
    product: str | None = None
    compatible: list[str] = field(default_factory=list)
    error: str | None = None


def _version_str(v: int | None) -> str | None:
    return None if v is None else f"{(v >> 16) & 0xFF}.{(v >> 8) & 0xFF}.{v & 0xFF}"


def _scan_interface(dev):
    """First interface/alt of configuration 0 matching the HAL's rules (section 1.2).

    Returns ``(interface, alt, ep_ctrl_in, ep_ctrl_out, ep_data, data_max_packet)`` or None.
    """
    cfg = dev[0]
    for intf in cfg:
        if (intf.bInterfaceClass, intf.bInterfaceSubClass, intf.bInterfaceProtocol) != (0xFF, 0x19, 0):
            continue
        eps = list(intf)
        if len(eps) != 3 or any(usb.util.endpoint_type(e.bmAttributes) != usb.util.ENDPOINT_TYPE_BULK for e in eps):
            continue
        dirs = [usb.util.endpoint_direction(e.bEndpointAddress) for e in eps]
        if dirs != [usb.util.ENDPOINT_IN, usb.util.ENDPOINT_OUT, usb.util.ENDPOINT_IN]:
            continue
        return (intf.bInterfaceNumber, intf.bAlternateSetting, eps[0].bEndpointAddress,
                eps[1].bEndpointAddress, eps[2].bEndpointAddress, eps[2].wMaxPacketSize)
    return None


def libusb_backend():
    """pyusb's libusb-1.0 backend on the system's libusb-1.0, else on the copy that the
    ``libusb-package`` wheel ships (a machine with only Python and pip has no other), else None."""
    import usb.backend.libusb1

    backend = usb.backend.libusb1.get_backend()
    if backend is None:
        try:
            import libusb_package
        except ImportError:
            return None
        backend = libusb_package.get_libusb1_backend()
    return backend


def _candidates(backend):
    try:
        return list(usb.core.find(
            find_all=True, backend=backend if backend is not None else libusb_backend(),
            custom_match=lambda d: (d.idVendor, d.idProduct) in BOARDS,
        ))
    except usb.core.NoBackendError as exc:
        raise EvkError("no libusb backend found: install libusb-1.0 (e.g. apt install libusb-1.0-0, or pip install "
                       "libusb-package)") from exc


class _UsbSession:
    """Open, claimed USB device with its Treuzell link (section 1.3 steps 1-8)."""

    def __init__(self, dev, backend):
        self.dev = dev
        self.board = BOARDS[(dev.idVendor, dev.idProduct)]
        where = f"{self.board} on bus {dev.bus} address {dev.address}"
        self.where = where
        quirk = dev.bcdDevice < EARLY_QUIRK_BCD
        found = _scan_interface(dev)
        if found is None:
            # [uncertain] The HAL would skip the device; a known VID/PID with unexpected
            # descriptors falls back to the EVK4 layout, with a warning.
            log.warning("%s: unexpected descriptors, assuming interface 0 with endpoints 0x82/0x02/0x81", where)
            found = (0, 0, *FALLBACK_ENDPOINTS, 1024)
        self.interface, alt, ep_in, ep_out, self.ep_data, self.max_packet = found
        self.product = None
        try:
            self.product = usb.util.get_string(dev, dev.iProduct) if dev.iProduct else None
        except usb.core.USBError as exc:
            err = usb_error(exc, f"opening {where}")
            if isinstance(err, (EvkPermissionError, EvkBusyError)) or exc.errno == 19:
                raise err from exc
        except (ValueError, NotImplementedError):
            pass
        try:
            try:
                if dev.is_kernel_driver_active(self.interface):
                    dev.detach_kernel_driver(self.interface)
            except NotImplementedError:
                pass
        except usb.core.USBError as exc:
            if exc.errno != errno.ENOSYS:  # "not supported" on macOS / Windows: nothing to detach
                raise usb_error(exc, f"detaching the kernel driver of {where}") from exc
        try:
            usb.util.claim_interface(dev, self.interface)
        except usb.core.USBError as exc:
            err = usb_error(exc, f"claiming {where}")
            if not isinstance(err, EvkPermissionError):
                err = EvkBusyError(f"camera is busy: cannot claim {where} ({exc}); close other programs using it")
            raise err from exc
        self.claimed = True
        try:
            # Never SET_CONFIGURATION (the HAL does not; on Linux it could disturb a
            # configured device [uncertain whether harmless]).
            if not quirk:
                dev.set_interface_altsetting(interface=self.interface, alternate_setting=alt)
            if dev.speed is not None and dev.speed < LIBUSB_SPEED_SUPER:
                log.warning("%s is not on a SuperSpeed (USB 3) port: event drops are likely", where)
            sleep = getattr(backend, "sleep_us", None) or tz.sleep_us
            self.link = tz.TzLink(dev, ep_in, ep_out, sleep_us=sleep, name=where)
            self.firmware = self._optional(lambda: self.link.get_u32(tz.PROP_RELEASE_VERSION))
            self.build_date = self._optional(self.link.build_date)
            # [uncertain] An unreadable version is not refused (the HAL ignores the read
            # failure); a readable one below 3.8.0 is, as the HAL does.
            if self.firmware is not None and self.firmware < MIN_FIRMWARE:
                raise EvkFirmwareError(
                    f"{where}: firmware {_version_str(self.firmware)} is no longer supported "
                    f"(need >= {_version_str(MIN_FIRMWARE)}); update it with Prophesee's firmware updater"
                )
            self.serial = self.link.serial()
            self.where = f"{self.board} {self.serial}"
            self.link.name = self.where
        except BaseException:
            self.release()
            raise

    def _optional(self, fn):
        """Step 7: version / build date read failures are ignored (as the HAL)."""
        try:
            return fn()
        except (TreuzellError, EvkError) as exc:
            log.warning("%s: %s", self.where, exc)
            return None

    def enumerate(self) -> list[tuple[list[str], str]]:
        """Treuzell devices: ``[(compatible strings, name)]`` by device id (section 2.7).

        As lenient as the HAL (``TzDeviceBuilder::get_build_fun``): a NAME that fails after
        COMPATIBLE answered gives ``"device<i>"``; a COMPATIBLE that fails (refused, timed out)
        falls back to the NAME strings (old firmware put the compatible string there); a device
        answering neither is listed with no compatible string (and so never used).
        """
        n = self.link.get_u32(tz.PROP_DEVICES)
        out = []
        for dev_id in range(n):
            try:
                compatible = self.link.device_strings(tz.PROP_DEVICE_COMPATIBLE, dev_id)
                name = " ".join(self._lenient(lambda: self.link.device_strings(tz.PROP_DEVICE_NAME, dev_id))
                                or [f"device{dev_id}"])
            except EvkDisconnectedError:
                raise
            except EvkError as exc:
                compatible = self._lenient(lambda: self.link.device_strings(tz.PROP_DEVICE_NAME, dev_id))
                if compatible is None:
                    log.warning("%s: no compatible string from Treuzell device %d (%s); skipped", self.where,
                                dev_id, exc)
                    compatible = []
                name = " ".join(compatible) or f"device{dev_id}"
            out.append((compatible, name))
        return out

    def _lenient(self, fn):
        """``fn()``, or None when the board refuses or does not answer (never when it is gone)."""
        try:
            return fn()
        except EvkDisconnectedError:
            raise
        except EvkError as exc:
            log.debug("%s: %s", self.where, exc)
            return None

    def release(self) -> None:
        if not getattr(self, "claimed", False):
            return
        self.claimed = False
        try:
            usb.util.release_interface(self.dev, self.interface)
        except usb.core.USBError as exc:
            log.warning("%s: releasing the interface failed: %s", self.where, exc)
        usb.util.dispose_resources(self.dev)


def list_devices(backend=None) -> list[DeviceInfo]:
    """Connected EVK3/EVK4 cameras with serial, board and sensor.

    Each camera is briefly opened (claimed) to ask its serial number and sensor; a camera
    that cannot be queried is still listed, with ``error`` set (busy, permission...).

    Parameters
    ----------
    backend : usb.backend.IBackend, optional
        pyusb backend (default: libusb); e.g. :class:`capture.evk.fake.FakeEVK`.
    """
    infos = []
    for dev in _candidates(backend):
        board = BOARDS[(dev.idVendor, dev.idProduct)]
        try:
            s = _UsbSession(dev, backend)
        except EvkError as exc:
            infos.append(DeviceInfo(serial=None, board=board, bus=dev.bus, address=dev.address, error=str(exc)))
            continue
        try:
            devices = s.enumerate()
            compatible = devices[0][0] if devices else []
            sensor = next((SENSOR_NAMES[c] for c in compatible if c in SENSOR_NAMES), None)
            cls = next((driver_for(c) for c in compatible if driver_for(c)), None)
            infos.append(DeviceInfo(
                serial=s.serial, board=board, sensor=sensor,
                width=cls.width if cls else None, height=cls.height if cls else None,
                firmware=_version_str(s.firmware), build_date_s=s.build_date,
                bus=dev.bus, address=dev.address, product=s.product, compatible=compatible,
            ))
        except EvkError as exc:
            infos.append(DeviceInfo(serial=s.serial, board=board, bus=dev.bus, address=dev.address, error=str(exc)))
        finally:
            s.release()
    return infos


def open(serial: str | None = None, *, backend=None) -> Camera:  # noqa: A001 - public API name
    """Open an EVK (the first one, or the one with ``serial``) and bring its sensor up.

    Runs the HAL's open-time sequences (stop, destroy, init, post-init: about 2.5 s of
    documented waits plus ~1000 register round trips). The camera is ready but not streaming.

    Parameters
    ----------
    serial : str, optional
        Serial number as :func:`list_devices` shows it (lowercase hex).
    backend : usb.backend.IBackend, optional
        pyusb backend (default: libusb); :class:`capture.evk.fake.FakeEVK` for the fake.

    Raises
    ------
    EvkNotFoundError, EvkPermissionError, EvkBusyError, EvkFirmwareError, EvkError
    """
    devs = _candidates(backend)
    if not devs:
        raise EvkNotFoundError(
            "no Prophesee EVK found (USB ids 04b4:00f5 EVK4, 04b4:00f4 EVK3); check the cable and 'lsusb'"
        )
    errors = []
    for dev in devs:
        try:
            s = _UsbSession(dev, backend)
        except EvkError as exc:
            if serial is None and len(devs) == 1:
                raise
            errors.append(str(exc))
            continue
        if serial is not None and s.serial != serial.lower():
            s.release()
            continue
        try:
            return Camera(s, backend)
        except BaseException:
            s.release()
            raise
    detail = f" ({'; '.join(errors)})" if errors else ""
    raise EvkNotFoundError(f"no EVK with serial {serial} found{detail}" if serial else f"no usable EVK found{detail}")


class Camera:
    """An opened, initialised EVK. Use as a context manager or call :meth:`close`.

    Attributes
    ----------
    info : DeviceInfo
        serial, board, sensor, width, height, format, firmware...
    """

    n_transfers = 64
    """Bulk-IN requests kept in flight on the data endpoint; 1 reads synchronously, one request
    at a time. The HAL keeps 20 and neuromorphic-drivers 32, in code that never waits for a
    GIL; 64 × 128 KiB = 8 MiB covers 28 ms at 300 MB/s (100 Mev/s of EVT3) while Python is
    busy elsewhere. Linux's usbfs lends 16 MiB by default to all devices together: a second
    camera gets fewer requests (with a warning) unless each is given ``n_transfers = 32`` or
    ``/sys/module/usbcore/parameters/usbfs_memory_mb`` is raised."""
    transfer_bytes = 128 << 10
    """Size of each queued request (HAL value; a multiple of wMaxPacketSize)."""
    read_bytes = 1 << 20
    """Size of each synchronous read, where requests cannot be queued (``n_transfers`` 1, or
    a pyusb backend other than libusb-1.0); rounded to a multiple of wMaxPacketSize."""
    device_buffer_bytes = 256 << 10
    """The EVK's buffer between sensor and USB, bytes [uncertain: its FX3 bridge has 512 KiB of
    SRAM shared with its firmware, DMA buffers a few hundred KiB]. Where the endpoint may have
    lacked request space for longer than it covers, a possible loss is reported
    (:attr:`capture.evk.stream.Reader.n_idle_risks`). A backend standing for a device (a fake) may
    state its own as ``device_buffer_bytes`` (``None``: unbounded)."""
    read_timeout_ms = 100
    """Per-request timeout (HAL value); an idle sensor just produces timeouts."""
    queue_bytes = 256 << 20
    """Capacity of the reader's queue; beyond it data is dropped and counted."""

    def __init__(self, session: _UsbSession, backend=None):
        self._usb = session
        self._backend = backend
        self._lock = threading.Lock()
        self.reader: Reader | None = None
        self._closed = False
        self._streaming = False
        link = session.link
        devices = session.enumerate()
        main = None
        for dev_id, (compatible, _name) in enumerate(devices):
            for comp in compatible:
                if comp == IMX646_COMPATIBLE:
                    raise EvkError(f"{session.where}: IMX646 sensors are not supported by this driver")
                cls = driver_for(comp)
                if cls is not None and cls.probe(link, dev_id):
                    main = cls(link, dev_id)
                    break
            if main is not None:
                break
        if main is None:
            found = "; ".join(",".join(c) for c, _ in devices) or "none"
            raise EvkError(f"{session.where}: no supported sensor found (Treuzell devices: {found})")
        self.sensor = main
        # As the HAL: devices are built in id order (a streamer is sent STREAM=0, an unknown
        # device ENABLE=1, the sensor runs its open sequences), then every device but the
        # sensor and the temperature sensor is started (STREAM=1); a refusal is only logged.
        self._aux = [i for i, (c, _) in enumerate(devices)
                     if i != main.device and "ti,tmp103" not in c and not any(driver_for(x) for x in c)]
        self._unknown = [i for i in self._aux if STREAMER not in devices[i][0]]
        for dev_id in range(len(devices)):
            if dev_id == main.device:
                main.bring_up()
            elif dev_id in self._unknown:
                self._device_flag(tz.PROP_DEVICE_ENABLE, dev_id, True)
            elif dev_id in self._aux:
                self._device_flag(tz.PROP_DEVICE_STREAM, dev_id, False)
        for dev_id in self._aux:
            self._device_flag(tz.PROP_DEVICE_STREAM, dev_id, True)
        self.info = DeviceInfo(
            serial=session.serial, board=session.board, sensor=main.name, width=main.width,
            height=main.height, format=main.event_format(), firmware=_version_str(session.firmware),
            build_date_s=session.build_date, bus=session.dev.bus, address=session.dev.address,
            product=session.product, compatible=list(devices[main.device][0]),
        )

    # ---- settings -------------------------------------------------------------------
    def configure(self, *, biases: dict[str, int] | None = None,
                  roi: tuple[int, int, int, int] | None = None,
                  erc_ev_s: float | None = None, trigger_in: bool | None = None,
                  anti_flicker_hz: tuple[int, int] | None = None,
                  crop: tuple[int, int, int, int] | None = None,
                  trail_filter: tuple[str, int] | None = None,
                  sync_mode: str | None = None, event_format: str | None = None) -> None:
        """Apply the recording settings that are given, in this order: event format, biases,
        ROI, digital crop, event rate cap, anti-flicker, trail filter, synchronisation, trigger
        input. A setting left ``None`` is not touched.

        Parameters
        ----------
        biases : dict of str to int, optional
            Named biases for :meth:`set_biases` (IMX636: offsets from the factory trim, DAC
            counts; Gen4.1: absolute 0-255; Gen3.1: mV). Empty or ``None``: not touched.
        roi : (int, int, int, int), optional
            ``(x, y, width, height)`` in pixels for :meth:`set_roi`.
        crop : (int, int, int, int), optional
            ``(x, y, width, height)`` in pixels for :meth:`set_crop`.
        erc_ev_s : float, optional
            Event rate cap for :meth:`set_erc`, events/s.
        anti_flicker_hz : (int, int), optional
            Flicker band for :meth:`set_anti_flicker`, Hz.
        trail_filter : (str, int), optional
            ``(kind, threshold_us)`` for :meth:`set_trail_filter`.
        sync_mode : str, optional
            ``"standalone"``, ``"master"`` or ``"slave"`` (:meth:`set_sync_mode`).
        event_format : str, optional
            ``"EVT3"`` or ``"EVT21"`` (:meth:`set_event_format`).
        trigger_in : bool, optional
            Enable (``True``) or disable (``False``) the external trigger input.

        Raises
        ------
        BiasRangeError, ValueError, EvkError
            A value out of range, or a setting the sensor lacks; settings before it in the
            order above are already applied.
        """
        if event_format is not None:
            self.set_event_format(event_format)
        if biases:
            self.set_biases(**biases)
        if roi is not None:
            self.set_roi(*roi)
        if crop is not None:
            self.set_crop(*crop)
        if erc_ev_s is not None:
            self.set_erc(erc_ev_s)
        if anti_flicker_hz is not None:
            self.set_anti_flicker(anti_flicker_hz)
        if trail_filter is not None:
            self.set_trail_filter(*trail_filter)
        if sync_mode is not None:
            self.set_sync_mode(sync_mode)
        if trigger_in is not None:
            self.enable_trigger_in(trigger_in)

    def set_biases(self, **named: int) -> None:
        """Set named biases (``bias_fo``, ``bias_hpf``, ``bias_diff_on``, ``bias_diff``,
        ``bias_diff_off``, ``bias_refr``; the ``bias_`` prefix is optional). IMX636: offsets
        from the factory trim; Gen4.1: absolute 0-255. Out-of-range values raise
        :class:`BiasRangeError` before anything is written."""
        self.sensor.set_biases(**named)

    def get_biases(self) -> dict[str, int]:
        """Current bias values (IMX636: offsets from the factory trim)."""
        return self.sensor.get_biases()

    def set_roi(self, x: int | None = None, y: int | None = None,
                width: int | None = None, height: int | None = None) -> None:
        """Keep only pixels in ``[x, x+width) x [y, y+height)``; no arguments: full frame."""
        self.sensor.set_roi(x, y, width, height)

    def set_crop(self, x: int | None = None, y: int | None = None,
                 width: int | None = None, height: int | None = None) -> None:
        """Drop the events outside ``[x, x+width) x [y, y+height)`` in the sensor's digital
        readout (IMX636, Gen4.1; the pixels still fire, unlike :meth:`set_roi`, and event
        coordinates stay the sensor's); no arguments: off.

        Raises
        ------
        EvkError
            On a sensor without a digital crop (Gen3.1).
        """
        self._sensor("set_crop", "has no digital crop")(x, y, width, height)

    def set_erc(self, max_event_rate_ev_s: float | None) -> None:
        """Cap the sensor's event rate (events/s) with its event rate controller; ``None``
        disables the cap. The EVK3 Gen3.1 has none and refuses a cap (:class:`EvkError`)."""
        self.sensor.set_erc(max_event_rate_ev_s)

    def set_anti_flicker(self, band_hz: tuple[int, int] | None) -> None:
        """Drop events of lights flickering within ``band_hz = (low, high)`` Hz (50..520), the
        sensor's anti-flicker block (IMX636, Gen4.1); ``None`` switches it off.

        Raises
        ------
        EvkError
            On a sensor without it (Gen3.1).
        """
        self._sensor("set_anti_flicker", "has no anti-flicker block")(band_hz)

    def erc_status(self) -> tuple[bool, float]:
        """``(enabled, cap in events/s)`` of the event rate controller, read back from the
        sensor (IMX636, Gen4.1).

        Raises
        ------
        EvkError
            On a sensor without one (Gen3.1).
        """
        return self._sensor("erc_status", "has no event rate controller")()

    def set_trail_filter(self, kind: str | None, threshold_us: int = 10_000) -> None:
        """Filter event bursts and noise in the sensor (IMX636): ``kind`` ``"trail"`` (keep the
        first event of each burst), ``"stc_cut"`` (keep the second event after a polarity change,
        drop lone events) or ``"stc_keep"`` (drop the first, keep the rest of the burst, drop
        lone events); ``threshold_us`` the longest gap within a burst, 1,000..100,000 µs (whole
        ms); ``None`` switches it off.

        Raises
        ------
        ValueError
            An unknown kind or a threshold out of range.
        EvkError
            On a sensor this driver does not filter on (Gen3.1, Gen4.1), or when the block does
            not report its initialisation.
        """
        self._sensor("set_trail_filter", "has no trail filter in this driver (IMX636 only)")(kind, threshold_us)

    def set_sync_mode(self, mode: str) -> None:
        """Share one time base between cameras wired by their SYNC connectors (IMX636):
        ``"master"`` drives it, ``"slave"`` follows it, ``"standalone"`` (the default) ignores it.
        Only while not streaming; start the slave before the master.

        Raises
        ------
        ValueError
            An unknown mode.
        EvkError
            While streaming, or on a sensor this driver does not synchronise (Gen3.1, Gen4.1).
        """
        self._not_streaming("the sync mode")
        if mode == "standalone" and getattr(self.sensor, "set_sync_mode", None) is None:
            return  # what every sensor is at open
        self._sensor("set_sync_mode", "has no synchronisation in this driver (IMX636 only)")(mode)

    def set_event_format(self, fmt: str) -> None:
        """Select the sensor's output format (IMX636): ``"EVT3"`` (default, about 2 bytes per
        event) or ``"EVT21"`` (EVT 2.1, legacy word order, 8 bytes per word); :attr:`info`
        follows. Only while not streaming.

        Raises
        ------
        ValueError
            An unknown format.
        EvkError
            While streaming, or on a sensor this driver keeps in EVT3 (Gen3.1, Gen4.1).
        """
        self._not_streaming("the event format")
        if fmt == self.info.format and getattr(self.sensor, "set_event_format", None) is None:
            return  # the format it streams already
        self._sensor("set_event_format", "has no format selection in this driver (IMX636 only)")(fmt)
        self.info.format = self.sensor.event_format()

    @property
    def trail_filter(self) -> tuple[str, int] | None:
        """``(kind, threshold_us)`` of the sensor's trail filter as last set, or None (off)."""
        return getattr(self.sensor, "trail_filter", None)

    @property
    def sync_mode(self) -> str:
        """``"standalone"``, ``"master"`` or ``"slave"``, as last set (standalone at open)."""
        return getattr(self.sensor, "sync_mode", "standalone")

    def _sensor(self, method: str, lacks: str):
        """The sensor driver's ``method``; :class:`EvkError` "the <sensor> <lacks>" where it has
        none (an attribute set to None: the sensor has it, this driver does not drive it)."""
        fn = getattr(self.sensor, method, None)
        if fn is None:
            raise EvkError(f"the {self.sensor.name} {lacks}")
        return fn

    def _not_streaming(self, what: str) -> None:
        if self._streaming:
            raise EvkError(f"{self._usb.where}: {what} can only change while not streaming")

    def temperature_c(self) -> float:
        """The sensor's die temperature, °C (IMX636 / EVK4; its ADC's resolution is 0.19 °C).

        Raises
        ------
        EvkError
            On a sensor the HAL reads no temperature from (Gen3.1, Gen4.1 on an EVK3), or when
            the ADC reports no conversion.
        """
        return self._sensor("temperature_c", "reports no temperature")()

    def illuminance_lux(self) -> float:
        """The light level on the sensor, lux (IMX636 / EVK4: the HAL's conversion of its LIFO
        on-time counter; a rough figure, uncalibrated per unit).

        Raises
        ------
        EvkError
            On a sensor the HAL reads no light level from (Gen3.1, Gen4.1 on an EVK3), or when
            the counter gives none.
        """
        return self._sensor("illuminance_lux", "reports no light level")()

    def set_activity_filter(self, min_event_rate_ev_s: float | None) -> None:
        """Gen3.1 only: drop events while the rate is below ``min_event_rate_ev_s`` (its NFL);
        ``None`` disables it.

        Raises
        ------
        EvkError
            On a sensor without this filter.
        """
        self._sensor("set_activity_filter", "has no event-rate activity filter")(min_event_rate_ev_s)

    def enable_trigger_in(self, enabled: bool = True, channel: int = 0) -> None:
        """Enable (or disable) the external trigger input; edges arrive as trigger events."""
        self.sensor.enable_trigger_in(enabled, channel)

    # ---- streaming ------------------------------------------------------------------
    @property
    def is_streaming(self) -> bool:
        return self._streaming

    def start(self) -> None:
        """Start streaming: clear-halt and drain the data endpoint, start the reader thread,
        then run the sensor's start sequence (data path first, as the HAL)."""
        if self._streaming:
            return
        dev, ep = self._usb.dev, self._usb.ep_data
        try:
            dev.clear_halt(ep)
        except usb.core.USBError as exc:
            raise usb_error(exc, f"clearing the data endpoint of {self._usb.where}") from exc
        Reader.drain(dev, ep, self._usb.max_packet)
        queue = None
        if self.n_transfers > 1:
            try:
                queue = open_queue(dev, ep)
            except usb.core.USBError as exc:
                raise usb_error(exc, f"queuing transfers on {self._usb.where}") from exc
            except (ImportError, OSError, RuntimeError) as exc:  # python-libusb1 missing or on another libusb
                log.warning("%s: cannot queue USB transfers (%s); reading one request at a time", self._usb.where, exc)
            else:
                if queue is None:
                    log.warning("%s: the USB backend cannot queue transfers; reading one request at a time "
                                "(data may be lost at high event rates)", self._usb.where)
        wanted = self.transfer_bytes if queue is not None else self.read_bytes
        size = max(wanted // self._usb.max_packet, 1) * self._usb.max_packet
        eos = getattr(self._backend, "end_of_stream", None)
        self.reader = Reader(dev, ep, read_bytes=size, timeout_ms=self.read_timeout_ms,
                             capacity_bytes=self.queue_bytes, end_of_stream=eos, name=self._usb.where,
                             transfers=queue, n_transfers=self.n_transfers,
                             device_buffer_bytes=getattr(self._backend, "device_buffer_bytes",
                                                         self.device_buffer_bytes))
        self.reader.start()
        try:
            self.sensor.start()
        except BaseException:
            self.reader.stop()
            raise
        self._streaming = True

    def stop(self) -> None:
        """Stop streaming: the sensor's stop sequence first, then the reader thread.

        Data still queued stays readable from :attr:`reader` (``record`` drains it). If the
        camera is already gone the stop sequence is skipped with a warning (as the HAL)."""
        if not self._streaming:
            return
        self._streaming = False
        try:
            self.sensor.stop()
        except EvkConnectionError as exc:
            log.warning("%s: failed to properly stop the sensor: %s", self._usb.where, exc)
        finally:
            self.reader.stop()

    def close(self) -> None:
        """Stop, run the destroy sequence (errors only logged, as the HAL), release USB."""
        if self._closed:
            return
        self._closed = True
        try:
            try:
                self.stop()
            except EvkError as exc:
                log.warning("%s: failed to stop properly: %s", self._usb.where, exc)
            try:
                for dev_id in reversed(self._aux):
                    self._device_flag(tz.PROP_DEVICE_STREAM, dev_id, False)
                self.sensor.destroy()
                for dev_id in reversed(self._unknown):
                    self._device_flag(tz.PROP_DEVICE_ENABLE, dev_id, False)
            except EvkError as exc:
                log.warning("%s: destroy sequence failed: %s", self._usb.where, exc)
        finally:
            if self.reader is not None and (self.reader.is_alive() or self.reader.abandoned):
                # requests may still be pending in libusb: closing the handle under them could
                # let the host write into freed memory; the process keeps the handle instead
                log.error("%s: the USB reader did not stop; the device stays claimed until this "
                          "process ends", self._usb.where)
            else:
                self._usb.release()

    def _device_flag(self, prop: int, dev_id: int, on: bool) -> None:
        """ENABLE / STREAM of an auxiliary device; a refusal or no answer is only logged (HAL)."""
        self._usb._lenient(lambda: self._usb.link.set_device_flag(prop, dev_id, on))

    def __enter__(self) -> Camera:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        i = self.info
        return f"<Camera {i.board} {i.serial} {i.sensor} {i.width}x{i.height} {i.format} fw {i.firmware}>"
