"""Replay a season of sessions on Dask distributed:
``python -m capture.batch SESSIONS... --out season.parquet [--scheduler ADDRESS] [--workers N]``.

Runs every session's tracking and spin parts as Dask tasks (:mod:`capture.pipeline.batch`) on a
local cluster of worker processes, or on a running scheduler (``--scheduler tcp://host:8786``)
whose workers see the sessions at the same paths. Each session's store gets its results exactly
as ``python -m capture.replay`` writes them; sessions already analysed with the same settings and
software are skipped (``--force`` redoes them). The per-flight table of every session goes to
``--out`` and the per-window table to ``--windows-out`` (Parquet, a ``session`` column first).
Needs the ``cluster`` extra: ``pip install -e ".[cluster]"``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import os
import sys
from pathlib import Path

from capture.cliargs import add_ball_args, ball_diameter_m, positive_int, run_command
from capture.pipeline.batch import OneThreadPerWorker, local_cluster, run_batch
from capture.replay import add_spin_args, spin_options
from capture.results import write_parquet

PROG = "python -m capture.batch"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description="Run detection and spin over many sessions on Dask "
                                 "distributed and write one season table.")
    ap.add_argument("sessions", nargs="+", help="session directories")
    ap.add_argument("--out", required=True, help="season table of flights to write (Parquet)")
    ap.add_argument("--windows-out", help="season table of spin windows (Parquet; default: OUT's name + _windows)")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="a running Dask scheduler, e.g. tcp://host:8786 (default: a local cluster)")
    where.add_argument("--workers", type=positive_int, metavar="N",
                       help=f"worker processes of the local cluster (default: {os.cpu_count()}, the cores)")
    ap.add_argument("--force", action="store_true", help="analyse sessions again that already hold results "
                    "of the same settings and software")
    add_ball_args(ap)
    add_spin_args(ap)
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(PROG, lambda: _run(args))


def _write(table: dict, path: Path) -> Path:
    """Write a Parquet table whole or not at all (a temporary file renamed into place)."""
    tmp = path.with_name(path.name + ".part")
    write_parquet(table, tmp)
    os.replace(tmp, path)
    return path


def _run(args) -> int:
    try:
        from distributed import Client
    except ImportError as exc:
        raise ImportError(f"the batch runs on Dask distributed, which is not installed ({exc}); "
                          "install it with: pip install 'courtside-spin[cluster]'") from None
    diameter = ball_diameter_m(args)
    options = spin_options(args)
    options.check()
    out = Path(args.out)
    windows_out = Path(args.windows_out) if args.windows_out else out.with_name(out.stem + "_windows" + out.suffix)
    for p in (out, windows_out):
        if not p.parent.is_dir():
            raise FileNotFoundError(f"{p.parent}: no such directory for {p.name}")
    missing = [s for s in args.sessions if not Path(s).is_dir()]
    if missing and args.scheduler is None:  # remote workers may see paths this machine does not
        raise FileNotFoundError(f"{missing[0]}: no such session directory")
    with contextlib.ExitStack() as stack:
        if args.scheduler:
            client = stack.enter_context(Client(args.scheduler))
        else:
            dashboard = ":8787" if importlib.util.find_spec("bokeh") else None
            cluster = stack.enter_context(local_cluster(args.workers or os.cpu_count(), dashboard_address=dashboard))
            client = stack.enter_context(Client(cluster))
        client.register_plugin(OneThreadPerWorker())
        n_workers = len(client.scheduler_info()["workers"])
        link = client.dashboard_link if client.scheduler_info().get("services", {}).get("dashboard") else None
        print(f"Dask scheduler {client.scheduler.address}, {n_workers} worker(s); dashboard: "
              + (link or "none (pip install bokeh)"))
        result = run_batch(args.sessions, client, options, force=args.force, ball_diameter_m=diameter,
                           progress=not args.quiet)
    _write(result.flights, out)
    _write(result.windows, windows_out)
    n = len(result.analysed) + len(result.skipped) + len(result.failed)
    print(f"{n} session(s): {len(result.analysed)} analysed, {len(result.skipped)} skipped (already analysed "
          f"with these settings), {len(result.failed)} failed; {len(result.flights['session'])} flight(s) in "
          f"{out}, {len(result.windows['session'])} spin window(s) in {windows_out}")
    return 1 if result.failed else 0


if __name__ == "__main__":
    sys.exit(main())
