"""Command line for a GoPro on wired USB.

    python -m capture.gopro --serial C3461324698573 state
    python -m capture.gopro --serial C3461324698573 configure --fps 240 --lens linear --anti-flicker 50Hz
    python -m capture.gopro --serial C3461324698573 record --duration 10
    python -m capture.gopro --serial C3461324698573 list
    python -m capture.gopro --serial C3461324698573 download --last OUT_DIR
    python -m capture.gopro --fake clip.mp4 download --last OUT_DIR      # no camera: loopback fake
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time

from capture import cliargs
from capture.gopro.client import PORT, GoPro, MediaNotFound
from capture.gopro.models import FPS_OPTIONS, LENS_OPTIONS, MAINS_HZ, RESOLUTION_OPTIONS
from capture.gopro.fake import FakeGoPro

PROG = "python -m capture.gopro"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="GoPro over wired USB (Open GoPro HTTP)")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--serial", help="camera serial number (gives the 172.2X.1YZ.51 address)")
    where.add_argument("--host", help="camera address")
    where.add_argument("--fake", metavar="FILE", help="run against a loopback fake camera serving this MP4")
    p.add_argument("--port", type=int, default=PORT, help=f"HTTP port (default {PORT})")
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("state", help="print status and settings as JSON")
    sub.add_parser("list", help="list media files")
    c = sub.add_parser("configure", help="set the video settings for ball capture")
    c.add_argument("--resolution", default="1080", choices=list(RESOLUTION_OPTIONS))
    c.add_argument("--fps", type=int, default=240, choices=list(FPS_OPTIONS), help="frames per second")
    c.add_argument("--lens", default="linear", choices=list(LENS_OPTIONS))
    c.add_argument("--anti-flicker", default="50Hz", choices=list(MAINS_HZ),
                   help="mains frequency of the lighting")
    c.add_argument("--set-time", action="store_true", help="also set the camera clock to this computer's")
    r = sub.add_parser("record", help="record for a while")
    r.add_argument("--duration", type=float, required=True, metavar="S", help="recording length, seconds")
    d = sub.add_parser("download", help="download a recording (all chapters), resuming partial files")
    d.add_argument("name", nargs="?", help="file name, e.g. GX010042.MP4")
    d.add_argument("--last", action="store_true", help="the newest recording")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.add_argument("out", help="destination folder")
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.cmd == "download" and not (args.name or args.last):
        parser.error("download: give a file NAME or --last")
    return cliargs.run_command(PROG, lambda: _run(args))


def _run(args) -> None:
    with contextlib.ExitStack() as stack:
        if args.fake:
            fake = stack.enter_context(FakeGoPro(args.fake))
            cam = GoPro(host=fake.host, port=fake.port)
        else:
            cam = GoPro(args.serial, host=args.host, port=args.port)
        stack.enter_context(cam)
        if args.cmd == "state":
            print(json.dumps({"model": cam.model.name, **cam.state()}, indent=1))
        elif args.cmd == "list":
            for m in cam.media_list():
                print(f"{m.path}\t{m.size_bytes}")
        elif args.cmd == "configure":
            cam.configure(resolution=args.resolution, fps=args.fps, lens=args.lens,
                          hypersmooth=False, anti_flicker=args.anti_flicker)
            for note in cam.notes:
                print(note)
            if args.set_time:
                cam.set_date_time()
        elif args.cmd == "record":
            for warning in cam.health():
                print(warning)
            cam.start_recording()
            time.sleep(args.duration)
            cam.stop_recording()
        elif args.cmd == "download":
            if args.last:
                media = cam.media_list()
                if not media:
                    raise MediaNotFound("GoPro: the card holds no media")
                target = media[-1]
            else:
                target = args.name
            for path in cam.download_recording(target, args.out, progress=not args.quiet):
                print(path)
