"""The ``courtside`` command: one entry point for every module's command line.

``courtside COMMAND [ARGS...]`` runs ``python -m <module> [ARGS...]`` of the module named in
:data:`COMMANDS`, e.g. ``courtside run --demo --out demo_session --viewer none`` is
``python -m capture.run --demo --out demo_session --viewer none``.
"""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "run": ("capture.run", "record a session (event camera + GoPro), then analyse it"),
    "replay": ("capture.replay", "detection and spin again over a session or a RAW file"),
    "batch": ("capture.batch", "replay many sessions on Dask distributed into one season table"),
    "report": ("capture.report", "per-flight results of an analysed session (table, CSV)"),
    "review": ("capture.review.cli", "write a session's Rerun review (.rrd)"),
    "ingest": ("capture.ingest", "a RAW file or a GoPro video into a session"),
    "raw": ("capture.raw.cli", "Prophesee RAW file information"),
    "evk": ("capture.evk.cli", "list or record Prophesee EVK3/EVK4 cameras over USB"),
    "gopro": ("capture.gopro.cli", "GoPro over wired USB: state, settings, record, download"),
    "sim": ("sim.dataset", "simulated datasets with ground truth"),
}
"""Subcommand -> (module whose ``main(argv)`` runs it, one-line help)."""


def usage() -> str:
    lines = ["usage: courtside COMMAND [ARGS...]   (courtside COMMAND --help for a command's options)", "",
             "commands:"]
    lines += [f"  {name:<8} {help_}" for name, (_, help_) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"{usage()}\n\ncourtside: error: unknown command {name!r}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    return module.main(rest)


if __name__ == "__main__":
    sys.exit(main())
