"""Exceptions of the live EVK driver, and the mapping from pyusb errors to them.

Every message is one line that names the camera or the operation and says what to do.
"""

from __future__ import annotations

import errno as _errno

import usb.core

UDEV_RULE = 'SUBSYSTEM=="usb", ATTRS{idVendor}=="04b4", MODE="0666"'
"""udev rule giving non-root users access to Prophesee EVK3/EVK4 (Cypress VID 04b4)."""

UDEV_HINT = (
    f"add the udev rule '{UDEV_RULE}' to /etc/udev/rules.d/88-prophesee-evk.rules, run "
    "'sudo udevadm control --reload-rules && sudo udevadm trigger' and re-plug the camera"
)


class EvkError(RuntimeError):
    """Base class of every error raised by :mod:`capture.evk`."""


class EvkNotFoundError(EvkError):
    """No matching EVK is connected."""


class EvkPermissionError(EvkError, PermissionError):
    """The OS refused access to the USB device (missing udev rule)."""


class EvkBusyError(EvkError):
    """Another process (or driver) holds the camera's interface."""


class EvkFirmwareError(EvkError):
    """The camera's firmware is too old for this driver (and for the Metavision HAL)."""


class EvkConnectionError(EvkError):
    """USB transfer failure: stall, I/O error or unplug. ``stats`` is set by ``record``."""

    stats = None


class EvkDisconnectedError(EvkConnectionError):
    """The device vanished (unplugged) while in use."""


class EvkStallError(EvkConnectionError):
    """An endpoint stalled (USB pipe error)."""


class EvkTimeoutError(EvkConnectionError):
    """A command got no answer in time."""


class TreuzellError(EvkError):
    """The device answered a Treuzell command with an error or an invalid frame."""


class BiasRangeError(EvkError, ValueError):
    """A bias value is outside the sensor's allowed range."""


def usb_error(exc: usb.core.USBError, what: str) -> EvkError:
    """Translate a pyusb exception raised during ``what`` into an :class:`EvkError`.

    Parameters
    ----------
    exc : usb.core.USBError
        The exception from pyusb (``errno`` carries the libusb error as an OS errno).
    what : str
        The operation, e.g. ``"reading the data endpoint of EVK4 0000a1b2"``.
    """
    code = exc.errno
    if isinstance(exc, usb.core.USBTimeoutError) or code == _errno.ETIMEDOUT:
        return EvkTimeoutError(f"timeout while {what}")
    if code == _errno.ENODEV:
        return EvkDisconnectedError(f"camera disconnected while {what}")
    if code == _errno.EPIPE:
        return EvkStallError(f"endpoint stalled (USB pipe error) while {what}")
    if code == _errno.EACCES:
        return EvkPermissionError(f"permission denied while {what}: {UDEV_HINT}")
    if code == _errno.EBUSY:
        return EvkBusyError(
            f"camera is busy while {what}: another process (e.g. Metavision Studio) has it open"
        )
    return EvkConnectionError(f"USB error while {what}: {exc}")
