"""Command line: list EVKs, or record one to a RAW file.

    python -m capture.evk list
    python -m capture.evk record out.raw [--duration 10] [--serial a1b2c3d4] [--erc 20e6]
        [--bias bias_fo=10 --bias bias_refr=-5] [--trigger] [--roi X,Y,WIDTH,HEIGHT]
        [--fake some.raw [--speed max]]   # no hardware: stream a RAW file through the fake
"""

from __future__ import annotations

import argparse
import signal
import threading

from capture import cliargs

from . import list_devices, open, record
from .fake import FakeEVK

PROG = "python -m capture.evk"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description="Prophesee EVK3/EVK4 over USB")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="list connected EVKs")
    rec = sub.add_parser("record", help="record to a RAW file (Ctrl-C stops)")
    rec.add_argument("out", help="output RAW file")
    rec.add_argument("--serial", help="camera serial (see 'list'; default: the first EVK found)")
    rec.add_argument("--duration", type=float, metavar="S", help="seconds (default: until Ctrl-C)")
    rec.add_argument("--erc", type=float, metavar="EV_S", help="cap the sensor's event rate, events per second")
    rec.add_argument("--bias", type=cliargs.name_int, action="append", default=[], metavar="NAME=VALUE",
                     help="sensor bias, repeatable (IMX636: offset from the factory trim)")
    rec.add_argument("--anti-flicker", type=cliargs.flicker_band, metavar="50Hz|60Hz|LOW,HIGH",
                     help="drop events of lights flickering in this band (mains frequency, or Hz)")
    rec.add_argument("--trigger", action="store_true", default=None, help="enable the external trigger input")
    rec.add_argument("--roi", type=cliargs.box, metavar="X,Y,WIDTH,HEIGHT",
                     help="keep only this window, pixels")
    rec.add_argument("--fake", metavar="FILE",
                     help="stream this RAW file through the emulated EVK instead of hardware")
    rec.add_argument("--speed", choices=["recorded", "max"], default="recorded",
                     help="--fake pace: as recorded (default), or as fast as possible")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return cliargs.run_command(PROG, lambda: _list() if args.cmd == "list" else _record(args))


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
    with open(args.serial, backend=backend) as cam:
        print(cam)
        cam.configure(biases=dict(args.bias), roi=args.roi, erc_ev_s=args.erc, trigger_in=args.trigger,
                      anti_flicker_hz=args.anti_flicker)
        stop = threading.Event()
        previous_handler = signal.signal(signal.SIGINT, lambda *_: stop.set())
        try:
            stats = record(cam, args.out, stop=stop, max_duration_s=args.duration)
        finally:
            signal.signal(signal.SIGINT, previous_handler)
    print(f"{stats.payload_bytes} bytes in {stats.stream_s:.1f} s to {stats.raw_path} "
          f"({stats.stop_reason}); dropped {stats.dropped_bytes} B, time-base jumps {stats.time_jumps}")
