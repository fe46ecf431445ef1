"""Per-flight results of an analysed session: ``python -m capture.report SESSION``.

Prints one line per flight (:func:`capture.results.format_flight_table`) and, on request, writes
the per-flight and per-window tables as CSV or Parquet (units in the column names) and a
self-contained HTML report (:func:`capture.pipeline.html_report.write_html`). With ``--ball`` (or
``--ball-diameter``) and the session's calibration, distances and speeds in m/s and km/h too.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from capture.cliargs import run_command
from capture.pipeline.replay import session_results, stored_ball_diameter_m
from capture.session import open_session
from capture.results import BALL_DIAMETER_M, format_flight_table, write_csv, write_parquet

PROG = "python -m capture.report"


def add_ball_args(ap: argparse.ArgumentParser) -> None:
    """``--ball`` (a preset) or ``--ball-diameter`` (metres); :func:`ball_diameter_m` reads them back."""
    ball = ap.add_mutually_exclusive_group()
    ball.add_argument("--ball", choices=sorted(BALL_DIAMETER_M), help="the ball, for distances and speeds")
    ball.add_argument("--ball-diameter", type=float, metavar="M", help="the ball's diameter in metres")


def ball_attr(args) -> dict | None:
    """The session attribute ``ball`` (``{"type": preset or None, "diameter_m": m}``) from the
    arguments of :func:`add_ball_args`, or None when neither is given."""
    diameter = ball_diameter_m(args)
    return None if diameter is None else {"type": args.ball, "diameter_m": diameter}


def ball_diameter_m(args) -> float | None:
    """The ball's diameter (m) from the arguments of :func:`add_ball_args`, or None when neither is given.

    Raises
    ------
    ValueError
        ``--ball-diameter`` is not positive.
    """
    if args.ball_diameter is not None and not args.ball_diameter > 0:
        raise ValueError(f"--ball-diameter must be positive, got {args.ball_diameter}")
    return args.ball_diameter or (BALL_DIAMETER_M[args.ball] if args.ball else None)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description="Print (and export) the per-flight results of a session.")
    ap.add_argument("session", help="session directory (analysed by capture.run or capture.replay)")
    add_ball_args(ap)
    ap.add_argument("--csv", metavar="FILE", help="write the per-flight table as CSV")
    ap.add_argument("--windows-csv", metavar="FILE", help="write the per-window table as CSV")
    ap.add_argument("--parquet", metavar="FILE", help="write the per-flight table as Parquet")
    ap.add_argument("--windows-parquet", metavar="FILE", help="write the per-window table as Parquet")
    ap.add_argument("--html", metavar="FILE", help="write a self-contained HTML report (table and plots)")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(PROG, lambda: _run(args))


def _run(args) -> None:
    session = open_session(args.session)
    diameter = ball_diameter_m(args) or stored_ball_diameter_m(session)
    flights, windows = session_results(session, ball_diameter_m=diameter)
    print(format_flight_table(flights))
    if diameter and len(flights["flight"]) and np.isnan(flights["speed_m_s"].astype(float)).all():
        print("note: no calibration of the event camera in the session: no distances or speeds")
    if args.csv:
        print(f"flights: {write_csv(flights, args.csv)}")
    if args.windows_csv:
        print(f"windows: {write_csv(windows, args.windows_csv)}")
    if args.parquet:
        print(f"flights: {write_parquet(flights, args.parquet)}")
    if args.windows_parquet:
        print(f"windows: {write_parquet(windows, args.windows_parquet)}")
    if args.html:
        from capture.pipeline.html_report import write_html

        print(f"report: {write_html(args.session, args.html, ball_diameter_m=diameter)}")


if __name__ == "__main__":
    sys.exit(main())
