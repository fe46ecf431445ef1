"""Command line: ``python -m capture.raw info FILE`` (header, format, geometry, counts, rate).

Getting a RAW file into a session store is ingest's: ``python -m capture.ingest raw FILE SESSION``.
"""

from __future__ import annotations

import argparse

from capture.cliargs import print_fields, run_command
from capture.raw.files import info


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m capture.raw",
                                     description="Prophesee RAW files (EVT 2.0 / 2.1 / 3.0)")
    sub = parser.add_subparsers(dest="command", required=True)
    p_info = sub.add_parser("info", help="header, format, geometry, event counts, duration, rate")
    p_info.add_argument("file")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(build_parser().prog, lambda: print_fields(info(args.file)))
