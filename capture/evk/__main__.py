"""Command line: list EVKs, or record one to a RAW file.

    python -m capture.evk list
    python -m capture.evk record out.raw --duration 10 [--serial a1b2c3d4] [--erc 20e6]
        [--bias bias_fo=10 --bias bias_refr=-5] [--trigger] [--roi X Y W H]
        [--fake some.raw [--pace recorded]]   # no hardware: stream a RAW file through the fake
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from . import EvkError, list_devices, open, record
from .fake import FakeEVK


def _bias(text: str) -> tuple[str, int]:
    name, _, value = text.partition("=")
    if not value:
        raise argparse.ArgumentTypeError(f"bias must be NAME=VALUE, got {text!r}")
    return name, int(value)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m capture.evk", description="Prophesee EVK3/EVK4 over USB")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="list connected EVKs")
    rec = sub.add_parser("record", help="record to a RAW file (Ctrl-C stops)")
    rec.add_argument("out", help="output RAW file")
    rec.add_argument("--serial", help="camera serial (see 'list')")
    rec.add_argument("--duration", type=float, default=None, help="seconds (default: until Ctrl-C)")
    rec.add_argument("--erc", type=float, default=None, help="cap the sensor's event rate, events/s")
    rec.add_argument("--bias", type=_bias, action="append", default=[], help="NAME=VALUE (IMX636: offset)")
    rec.add_argument("--trigger", action="store_true", help="enable the external trigger input")
    rec.add_argument("--roi", type=int, nargs=4, metavar=("X", "Y", "W", "H"), help="keep only this window")
    rec.add_argument("--fake", help="stream this RAW file through the emulated EVK instead of hardware")
    rec.add_argument("--pace", choices=("max", "recorded"), default="recorded", help="fake's pacing")
    args = ap.parse_args(argv)
    try:
        if args.cmd == "list":
            devices = list_devices()
            for d in devices:
                print(f"{d.board} serial {d.serial} sensor {d.sensor} {d.width}x{d.height} "
                      f"firmware {d.firmware} bus {d.bus} address {d.address}"
                      + (f"  ERROR: {d.error}" if d.error else ""))
            if not devices:
                print("no EVK found")
            return 0
        backend = FakeEVK(args.fake, pace=args.pace) if args.fake else None
        stop = threading.Event()
        signal.signal(signal.SIGINT, lambda *_: stop.set())
        with open(args.serial, backend=backend) as cam:
            print(cam)
            if args.bias:
                cam.set_biases(**dict(args.bias))
            if args.roi:
                cam.set_roi(*args.roi)
            if args.erc is not None:
                cam.set_erc(args.erc)
            if args.trigger:
                cam.enable_trigger_in()
            stats = record(cam, args.out, stop=stop, max_duration_s=args.duration)
        print(f"{stats.payload_bytes} bytes in {stats.stream_s:.1f} s to {stats.raw_path} "
              f"({stats.stop_reason}); dropped {stats.dropped_bytes} B, time-base jumps {stats.time_jumps}")
        return 0
    except (EvkError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
