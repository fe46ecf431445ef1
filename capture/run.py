"""Courtside recorder: ``python -m capture.run``.

Finds the EVK (or streams a RAW file through the fake EVK with ``--fake``, or a
simulated rally with ``--demo``), optionally drives a GoPro, records a session
(:func:`capture.pipeline.record.record_session`: the exact RAW bytes plus the session
store, live detection and spin that never slow the recording) and on Ctrl-C stops
cleanly; then analyses the session offline (:func:`capture.pipeline.replay.replay`:
track, spin, a Rerun ``.rrd``) unless ``--no-analysis``.

Examples
--------
::

    python -m capture.run --demo --out demo_session --viewer none
    python -m capture.run --fake recording.raw --out session --viewer none --speed max
    python -m capture.run --out session --gopro-serial C3461324698765 --bias bias_diff_on=20
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import signal
import sys
import threading
from pathlib import Path

from capture.cliargs import (
    add_ball_args,
    add_sensor_mode_args,
    ball_attr,
    box,
    flicker_band,
    flicker_hz,
    name_int,
    run_command,
)
from capture.evk.bias_file import biases_of
from capture.pipeline.record import RecorderError, RecordResult, RecordSettings, record_session
from capture.pipeline.replay import REVIEW_NAME, ReplayOptions, ReplayResult, replay, resolved_options
from capture.results import format_flight_table, session_results

PROG = "python -m capture.run"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG,
                                 description="Record a courtside session: event camera (+ GoPro), live "
                                             "ball tracking and spin, session store and Rerun review.")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--demo", action="store_true",
                     help="simulated rally through the fake EVK and fake GoPro (no hardware)")
    src.add_argument("--fake", metavar="RAW_FILE", help="stream a RAW file through the fake EVK")
    src.add_argument("--serial", help="EVK serial number (default: the first EVK found)")
    ap.add_argument("--out", help="session directory (default: session_YYYYmmdd_HHMMSS)")
    ap.add_argument("--viewer", choices=["spawn", "serve", "none"], default="spawn",
                    help="live Rerun viewer (default: spawn)")
    ap.add_argument("--speed", choices=["recorded", "max"], default="recorded",
                    help="--fake/--demo pace: as recorded, or as fast as possible")
    ap.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    ap.add_argument("--bias-file", metavar="FILE.bias",
                    help="Metavision bias file (VALUE %% NAME lines); --bias values override it")
    ap.add_argument("--bias", type=name_int, action="append", default=[], metavar="NAME=VALUE",
                    help="sensor bias (IMX636: offset from the factory value); repeat for several")
    ap.add_argument("--roi", type=box, metavar="X,Y,WIDTH,HEIGHT", help="region of interest in pixels")
    ap.add_argument("--crop", type=box, metavar="X,Y,WIDTH,HEIGHT",
                    help="drop events outside this window in the sensor's digital readout (IMX636, Gen4.1), pixels")
    ap.add_argument("--erc", type=float, metavar="EV_S", help="event-rate cap, events per second")
    ap.add_argument("--anti-flicker", type=flicker_band, metavar="50Hz|60Hz|LOW,HIGH",
                    help="event camera: drop events of lights flickering in this band (mains frequency, or Hz)")
    add_sensor_mode_args(ap)
    ap.add_argument("--gopro-serial", help="GoPro serial (its wired-USB address is derived from it)")
    ap.add_argument("--gopro-fps", type=int, default=240, help="GoPro frame rate (default 240)")
    ap.add_argument("--gopro-res", default="1080", help="GoPro resolution (default 1080)")
    ap.add_argument("--mains", choices=["50Hz", "60Hz"], default="50Hz",
                    help="mains frequency of the hall lighting, for the GoPro's anti-flicker (default 50Hz)")
    ap.add_argument("--exposure", type=float, metavar="S",
                    help="GoPro shutter time in seconds when locked, e.g. 0.002 (default: estimated)")
    ap.add_argument("--led-roi", type=box, metavar="X0,Y0,X1,Y1",
                    help="sync-box LED region in GoPro pixels (default: found automatically)")
    add_ball_args(ap)
    ap.add_argument("--flicker-hz", type=flicker_hz, metavar="HZ|auto",
                    help="lights flicker at this frequency (100 on 50 Hz mains, 120 on 60 Hz; auto: find it in the "
                         "events): leave their events out of ball detection, live and in the analysis (use "
                         "--anti-flicker where the sensor has it)")
    ap.add_argument("--no-analysis", action="store_true", help="skip the offline analysis at the end")
    ap.add_argument("--quiet", action="store_true", help="no status line or progress bars")
    return ap


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.out is not None and not args.out.strip():
        parser.error("--out: the session directory must not be empty")
    out = Path(args.out or _dt.datetime.now().strftime("session_%Y%m%d_%H%M%S"))
    stop = threading.Event()

    def on_sigint(signum, frame):
        if stop.is_set():
            raise KeyboardInterrupt
        print("\nstopping: finishing the session (Ctrl-C again to abort)...", file=sys.stderr)
        stop.set()

    previous_handler = signal.signal(signal.SIGINT, on_sigint)
    try:
        return run_command(PROG, lambda: _run(args, out, stop))
    finally:
        signal.signal(signal.SIGINT, previous_handler)


def _run(args, out: Path, stop: threading.Event) -> int:
    """Record one session, then analyse it; the exit code."""
    try:
        with _devices(args, out) as (settings, truth):
            result = record_session(settings, stop)
    except KeyboardInterrupt:
        print(f"capture.run: aborted; what was committed is in {out} "
              f"(python -m capture.replay {out} analyses it)", file=sys.stderr)
        return 130
    analysis = None
    if not args.no_analysis and result.n_events:
        if not args.quiet:
            print("Analysing the session (detection, spin, Rerun recording)...", file=sys.stderr, flush=True)
        try:
            options = resolved_options(out, ReplayOptions(
                tracker={"flicker_hz": args.flicker_hz} if args.flicker_hz else {}))
            flicker = options.tracker.get("flicker_hz")
            if args.flicker_hz == "auto" and not args.quiet:
                print(f"Lights flicker at {flicker:g} Hz: detection leaves their events out" if flicker
                      else "No flickering light found", file=sys.stderr)
            analysis = replay(out, rrd_path=out / REVIEW_NAME, options=options, progress=not args.quiet)
        except Exception as exc:  # the recording is safe; say why the analysis did not finish
            result.messages.append(f"analysis failed ({type(exc).__name__}: {exc}); "
                                   f"retry with: python -m capture.replay {out}")
    print_summary(result, analysis)
    if truth is not None and analysis is not None:
        print_truth_comparison(analysis, truth)
    if result.error:
        print(f"capture.run: error: {result.error} (session {out} kept)", file=sys.stderr)
        return 1
    return 0


@contextlib.contextmanager
def _devices(args, out: Path):
    """The recorder's settings from the command line, and the simulator's truth (demo only)."""
    if args.demo:
        from capture.pipeline.demo import demo_devices

        with demo_devices(out, viewer=args.viewer, speed=args.speed, quiet=args.quiet) as (settings, truth):
            yield settings, truth
        return
    ball = ball_attr(args)
    settings = RecordSettings(out=out, serial=args.serial, viewer=args.viewer, biases=biases_of(args.bias_file, args.bias),
                              roi=args.roi, crop=args.crop, erc_ev_s=args.erc, anti_flicker_hz=args.anti_flicker,
                              trail_filter=args.trail_filter, sync_mode=args.sync, event_format=args.event_format,
                              usb_transfers=args.usb_transfers, flicker_hz=args.flicker_hz,
                              max_duration_s=args.duration,
                              exposure_s=args.exposure, led_roi=args.led_roi, quiet=args.quiet,
                              attrs={**({"ball": ball} if ball else {}),
                                     **({"flicker_hz": args.flicker_hz} if args.flicker_hz else {})})
    if args.fake:
        from capture.evk.fake import FakeEVK

        if not Path(args.fake).is_file():
            raise RecorderError(f"{args.fake}: no such RAW file")
        settings.backend = FakeEVK(args.fake, pace=args.speed)
        if settings.backend.format != "EVT3":  # stream the file's format unless told otherwise
            settings.event_format = args.event_format or settings.backend.format
    if args.gopro_serial:
        from capture.gopro import GoPro

        settings.gopro = GoPro(args.gopro_serial)
        settings.gopro_settings = {"resolution": args.gopro_res, "fps": args.gopro_fps, "anti_flicker": args.mains}
    yield settings, None


def print_summary(result: RecordResult, analysis: ReplayResult | None = None) -> None:
    """A few lines on what was recorded and found."""
    print(f"Session {result.session}: {result.n_events:,} events, {result.n_triggers} triggers, "
          f"{result.drops} drops; stopped: {result.stop_reason}")
    for m in result.messages:
        print(f"  note: {m}")
    if analysis is not None:
        print(f"  {len(analysis.track)} track rows, {len(analysis.spin['rps'])} spin estimates; "
              f"review: {analysis.rrd_path} (open with: rerun {analysis.rrd_path})")
        print(format_flight_table(session_results(result.session)[0]))


def print_truth_comparison(analysis: ReplayResult, truth: dict) -> None:
    """The demo's estimated spin beside the simulator's truth."""
    from capture.pipeline.demo import spin_summary

    s = spin_summary(analysis.spin, truth)
    print(f"True spin:      {truth['rps']:7.1f} rps, axis ({', '.join(f'{v:+.3f}' for v in truth['axis'])})")
    if s["n_confident"]:
        print(f"Estimated spin: {s['rps']:7.1f} rps, axis ({', '.join(f'{v:+.3f}' for v in s['axis'])})  "
              f"median of {s['n_confident']} confident windows of {s['n_windows']} "
              f"(each ±{s['rps_sigma_pct']:.1f} %, ±{s['axis_sigma_deg']:.1f} deg, 1 sigma)")
        print(f"Error:          {s['rps_error_pct']:.2f} % in rps, {s['axis_error_deg']:.2f} deg in axis")
    else:
        print(f"Estimated spin: no confident estimate in {s['n_windows']} windows")


if __name__ == "__main__":
    sys.exit(main())
