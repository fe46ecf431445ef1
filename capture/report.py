"""Per-flight results of an analysed session: ``python -m capture.report SESSION``.

Prints one line per flight (:func:`capture.results.format_flight_table`) and, on request, writes
the per-flight and per-window tables as CSV or Parquet (units in the column names) and a
self-contained HTML report (:func:`capture.pipeline.html_report.write_html`). With the ball (``--ball``
or ``--ball-diameter``, else the one recorded with the session) and the session's calibration, the
distance and the 3D speed in m/s and km/h too.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from capture.cliargs import add_ball_args, ball_attr, run_command
from capture.session import open_session
from capture.results import format_flight_table, session_results, stored_ball, write_csv, write_parquet

PROG = "python -m capture.report"


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
    ball = ball_attr(args)
    kind, diameter = (ball["type"], ball["diameter_m"]) if ball else stored_ball(session)
    flights, windows = session_results(session, ball_diameter_m=diameter, ball_type=kind)
    print(format_flight_table(flights))
    if session.damage:  # what the store lacks (a recording cut short, events left out): the table is of the rest
        print(f"note: {session.damage}")
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

        print(f"report: {write_html(args.session, args.html, ball_diameter_m=diameter, ball_type=kind)}")


if __name__ == "__main__":
    sys.exit(main())
