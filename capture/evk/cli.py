"""Command line: list EVKs, or record one to a RAW file.

    python -m capture.evk list
    python -m capture.evk biases [--serial a1b2c3d4] [--save current.bias]
    python -m capture.evk record out.raw [--duration 10] [--serial a1b2c3d4] [--erc 20e6]
        [--bias-file tuned.bias] [--bias bias_fo=10 --bias bias_refr=-5] [--trigger] [--roi X,Y,WIDTH,HEIGHT]
        [--fake some.raw [--speed max]]   # no hardware: stream a RAW file through the fake
"""

from __future__ import annotations

import argparse
import signal
import threading

from capture import cliargs

from . import list_devices, open, record
from .bias_file import biases_of, write_bias_file
from .fake import FakeEVK

PROG = "python -m capture.evk"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description="Prophesee EVK3/EVK4 over USB")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="list connected EVKs")
    b = sub.add_parser("biases", help="print the sensor's biases (IMX636: offsets from the factory trim)")
    b.add_argument("--serial", help="camera serial (default: the first EVK found)")
    b.add_argument("--save", metavar="FILE.bias", help="also write them as a Metavision bias file")
    b.add_argument("--fake", metavar="FILE", help="ask the emulated EVK instead of hardware")
    rec = sub.add_parser("record", help="record to a RAW file (Ctrl-C stops)")
    rec.add_argument("out", help="output RAW file")
    rec.add_argument("--serial", help="camera serial (see 'list'; default: the first EVK found)")
    rec.add_argument("--duration", type=float, metavar="S", help="seconds (default: until Ctrl-C)")
    rec.add_argument("--erc", type=float, metavar="EV_S", help="cap the sensor's event rate, events per second")
    rec.add_argument("--bias-file", metavar="FILE.bias",
                     help="Metavision bias file (VALUE %% NAME lines); --bias values override it")
    rec.add_argument("--bias", type=cliargs.name_int, action="append", default=[], metavar="NAME=VALUE",
                     help="sensor bias, repeatable (IMX636: offset from the factory trim)")
    rec.add_argument("--anti-flicker", type=cliargs.flicker_band, metavar="50Hz|60Hz|LOW,HIGH",
                     help="drop events of lights flickering in this band (mains frequency, or Hz)")
    cliargs.add_sensor_mode_args(rec)
    rec.add_argument("--trigger", action="store_true", default=None, help="enable the external trigger input")
    rec.add_argument("--roi", type=cliargs.box, metavar="X,Y,WIDTH,HEIGHT",
                     help="keep only this window, pixels")
    rec.add_argument("--crop", type=cliargs.box, metavar="X,Y,WIDTH,HEIGHT",
                     help="drop events outside this window in the sensor's digital readout, pixels")
    rec.add_argument("--fake", metavar="FILE",
                     help="stream this RAW file through the emulated EVK instead of hardware")
    rec.add_argument("--speed", choices=["recorded", "max"], default="recorded",
                     help="--fake pace: as recorded (default), or as fast as possible")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    commands = {"list": _list, "record": lambda: _record(args), "biases": lambda: _biases(args)}
    return cliargs.run_command(PROG, commands[args.cmd])


def _biases(args) -> None:
    backend = FakeEVK(args.fake) if args.fake else None
    with open(args.serial, backend=backend) as cam:
        biases = cam.get_biases()
    for name, value in sorted(biases.items()):
        print(f"{name} {value}")
    if args.save:
        print(f"saved to {write_bias_file(args.save, biases)}")


def _list() -> None:
    devices = list_devices()
    for d in devices:
        print(f"{d.board} serial {d.serial} sensor {d.sensor} {d.width}x{d.height} "
              f"firmware {d.firmware} bus {d.bus} address {d.address}"
              + (f"  ERROR: {d.error}" if d.error else ""))
    if not devices:
        print("no EVK found")


def _record(args) -> None:
    backend = FakeEVK(args.fake, pace=args.speed) if args.fake else None
    event_format = args.event_format
    if backend is not None and backend.format != "EVT3":  # stream the file's format unless told otherwise
        event_format = event_format or backend.format
    with open(args.serial, backend=backend) as cam:
        if args.usb_transfers is not None:
            cam.n_transfers = args.usb_transfers
        cam.configure(biases=biases_of(args.bias_file, args.bias), roi=args.roi, erc_ev_s=args.erc, trigger_in=args.trigger,
                      anti_flicker_hz=args.anti_flicker, crop=args.crop, trail_filter=args.trail_filter,
                      sync_mode=args.sync, event_format=event_format)
        print(cam)
        stop = threading.Event()
        previous_handler = signal.signal(signal.SIGINT, lambda *_: stop.set())
        try:
            stats = record(cam, args.out, stop=stop, max_duration_s=args.duration)
        finally:
            signal.signal(signal.SIGINT, previous_handler)
    print(f"{stats.payload_bytes} bytes in {stats.stream_s:.1f} s to {stats.raw_path} "
          f"({stats.stop_reason}, {stats.n_transfers} USB requests in flight); dropped {stats.dropped_bytes} B, "
          + (f"{stats.idle_risks} possible unseen losses (no USB request pending too long), " if stats.idle_risks else "")
          + (f"time-base jumps {stats.time_jumps}" if stats.time_base_monitored
             else f"time base not checked for gaps ({cam.info.format})"))
