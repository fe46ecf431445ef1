"""Offline replay: ``python -m capture.replay SESSION_OR_RAW [--mp4 VIDEO] [--rrd OUT.rrd]``.

Runs detection and spin again over a stored session (:func:`capture.pipeline.replay.replay`),
or first makes a session of a bare RAW file and its video (:func:`capture.ingest.session_from_raw`).
A recording cut short (killed, crashed) is first completed from its RAW file
(:func:`capture.ingest.complete_cut_short`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from capture.cliargs import add_ball_args, ball_attr, box, flicker_hz, positive_int, run_command
from capture.ingest import complete_cut_short, session_from_raw
from capture.pipeline.replay import ReplayOptions, replay, resolved_options
from capture.results import format_flight_table, session_results
from capture.session import open_session, update_session

PROG = "python -m capture.replay"


def add_spin_args(ap: argparse.ArgumentParser) -> None:
    """The options of an analysis (``--window-us``, ``--max-window-us``, ``--step-us``,
    ``--method``, ``--flicker-hz``); :func:`spin_options` reads them back."""
    ap.add_argument("--window-us", type=int, default=ReplayOptions.window_us, help="shortest spin window, µs")
    ap.add_argument("--max-window-us", type=int, default=ReplayOptions.max_window_us,
                    help="longest spin window (for balls that fire few events), µs")
    ap.add_argument("--step-us", type=int, default=ReplayOptions.step_us,
                    help="time between spin windows, µs")
    ap.add_argument("--method", choices=["fast", "paper"], default="fast")
    ap.add_argument("--flicker-hz", type=flicker_hz, metavar="HZ|auto",
                    help="lights flickered at this frequency (100 on 50 Hz mains, 120 on 60 Hz; auto: find "
                         "it in the events) and the sensor's anti-flicker was off: leave their events out of "
                         "ball detection (replay: default, what capture.run --flicker-hz stored)")


def spin_options(args, **options) -> ReplayOptions:
    """:class:`ReplayOptions` from the arguments of :func:`add_spin_args` (and ``options``)."""
    tracker = {"flicker_hz": args.flicker_hz} if args.flicker_hz else {}
    return ReplayOptions(window_us=args.window_us, max_window_us=args.max_window_us, step_us=args.step_us,
                         method=args.method, tracker=tracker, **options)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description="Run detection and spin over a stored session or a RAW file.")
    ap.add_argument("source", help="session directory, or a Prophesee RAW file")
    ap.add_argument("--mp4", help="GoPro video to attach when SOURCE is a RAW file")
    ap.add_argument("--led-roi", type=box, metavar="X0,Y0,X1,Y1",
                    help="sync-box LED region in video pixels (default: automatic)")
    ap.add_argument("--exposure", type=float, metavar="S",
                    help="video shutter time in seconds when locked (default: estimated)")
    ap.add_argument("--out", help="session directory to create from a RAW file (default: next to it)")
    ap.add_argument("--rrd", help="write a Rerun recording here")
    add_ball_args(ap)
    add_spin_args(ap)
    ap.add_argument("--workers", type=positive_int, default=ReplayOptions.workers,
                    help="processes in all, this one included (spin runs in the others while this one tracks)")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(PROG, lambda: _run(args))


def _run(args) -> None:
    progress = not args.quiet
    ball = ball_attr(args)
    src = Path(args.source)
    if not src.exists():
        raise FileNotFoundError(f"{src}: no such file or directory")
    if src.is_file():
        out = Path(args.out) if args.out else src.with_name(src.stem + "_session")
        session_path, note = session_from_raw(src, out, args.mp4, progress=progress, led_roi=args.led_roi,
                                              exposure_s=args.exposure, ball=ball)
        if note:
            print(note)
    else:
        session_path = src
        completed = complete_cut_short(session_path, progress=progress)
        if completed:
            print(f"note: {session_path}: {completed}", file=sys.stderr)
        if ball:
            with update_session(session_path) as writer:
                writer.set_attrs(ball=ball)
    damage = open_session(session_path).damage
    if damage:
        print(f"note: {session_path}: {damage}", file=sys.stderr)
    opts = spin_options(args, workers=args.workers)
    recorded_flicker = open_session(session_path).attrs.get("flicker_hz")
    if args.flicker_hz is None and recorded_flicker:  # the recording was made under flickering lights
        opts.tracker = {"flicker_hz": recorded_flicker}
        print(f"note: {session_path}: recorded with --flicker-hz {recorded_flicker}", file=sys.stderr)
    if opts.tracker.get("flicker_hz") == "auto":
        opts = resolved_options(session_path, opts)
        found = opts.tracker.get("flicker_hz")
        print(f"note: {session_path}: " + (f"lights flicker at {found:g} Hz: detection leaves their events out"
                                           if found else "no flickering light found"), file=sys.stderr)
    elif opts.tracker.get("flicker_hz"):
        print(f"note: {session_path}: detection leaves the events of a light flickering at "
              f"{float(opts.tracker['flicker_hz']):g} Hz out", file=sys.stderr)
    result = replay(session_path, rrd_path=args.rrd, options=opts, progress=progress)
    n_flights = len(result.track.flight_ids())
    print(f"{session_path}: {len(result.track)} track rows in {n_flights} flight(s), "
          f"{len(result.spin['rps'])} spin estimates"
          + (f"; Rerun recording {result.rrd_path}" if result.rrd_path else ""))
    print(format_flight_table(session_results(session_path)[0]))


if __name__ == "__main__":
    sys.exit(main())
