"""Live Prophesee EVK3/EVK4 capture over USB with pyusb (no Metavision SDK).

Quick use::

    from capture import evk
    print(evk.list_devices())
    with evk.open() as cam:                 # or evk.open(serial="0000a1b2")
        cam.configure(biases={"bias_fo": 10},  # IMX636: offsets from the factory trim
                      erc_ev_s=20e6,            # cap at 20 Mev/s in the sensor
                      trigger_in=True)
        stats = evk.record(cam, "rec.raw", max_duration_s=10)

Testing without hardware: ``evk.open(backend=evk.fake.FakeEVK("file.raw"))`` runs the same
driver against a file-backed emulated EVK (a pyusb backend). The protocol and register
sequences follow ``docs/evk-usb.md`` (openeb HAL 5.1.1).

Command line: ``python -m capture.evk`` (:mod:`capture.evk.cli`).
"""

from . import fake
from .device import Camera, DeviceInfo, list_devices, open
from .errors import (
    UDEV_RULE,
    BiasRangeError,
    EvkBusyError,
    EvkConnectionError,
    EvkDisconnectedError,
    EvkError,
    EvkFirmwareError,
    EvkNotFoundError,
    EvkPermissionError,
    EvkStallError,
    EvkTimeoutError,
    TreuzellError,
)
from .record import RecordStats, record

__all__ = [
    "Camera", "DeviceInfo", "RecordStats", "list_devices", "open", "record", "fake", "UDEV_RULE",
    "EvkError", "EvkNotFoundError", "EvkPermissionError", "EvkBusyError", "EvkFirmwareError",
    "EvkConnectionError", "EvkDisconnectedError", "EvkStallError", "EvkTimeoutError",
    "TreuzellError", "BiasRangeError",
]
