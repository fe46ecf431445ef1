"""``python -m capture.review SESSION --rrd OUT.rrd``: write a stored session's Rerun review."""

from __future__ import annotations

import argparse

from capture import cliargs
from capture.pipeline.ball_view import ball_view
from capture.review.layout import DEFAULT_MAX_EVENTS_PER_SLICE, DEFAULT_SLICE_US
from capture.review.offline import write_rrd


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m capture.review``."""
    parser = argparse.ArgumentParser(prog="python -m capture.review",
                                     description="Write a session's Rerun review (.rrd).")
    parser.add_argument("session", help="session directory")
    parser.add_argument("--rrd", required=True, help="output .rrd file")
    parser.add_argument("--slice-us", type=cliargs.positive_int, default=DEFAULT_SLICE_US,
                        help="event slice length, µs")
    parser.add_argument("--max-events-per-slice", type=cliargs.positive_int, default=DEFAULT_MAX_EVENTS_PER_SLICE,
                        help="decimate slices above this many events")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv=None) -> int:
    """Write the review and print what it holds; see :func:`capture.cliargs.run_command` for errors."""
    parser = build_parser()
    args = parser.parse_args(argv)

    def body() -> None:
        stats = write_rrd(args.session, args.rrd, slice_us=args.slice_us,
                          max_events_per_slice=args.max_events_per_slice, progress=not args.quiet,
                          ball_view=ball_view)
        print(f"{args.rrd}: {stats.n_events_logged} of {stats.n_events} events in {stats.n_slices} slices "
              f"({stats.n_slices_decimated} decimated), {stats.n_track_rows} track rows, "
              f"{stats.n_spin_rows} spin estimates, {stats.n_frames} frames")

    return cliargs.run_command(parser.prog, body)
