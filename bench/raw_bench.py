"""Decode speed of capture.raw against expelliarmus (C) and evlib (Rust), measured in the same run.

Usage::

    python bench/raw_bench.py [--shared DIR] [--events 20000000] [--repeat 15] [--no-synthetic]

For every shared recording (``../shared/data/raw``) and for two large synthetic files written
with our encoder (EVT3 and EVT2, ``--events`` events each, tiled from the real recordings), it
prints the best-of-``--repeat`` wall time and Mev/s of

* ours: ``capture.raw.read(path)`` (whole file, exact 64-bit timestamps),
* expelliarmus ``Wizard(encoding).read(path)`` (wrong EVT3 timestamps, fails on triggers),
* evlib ``load_events(path, sort=False).collect()`` (fewer repeats: it is slow),

and the ratios ours/peer from the best wall time (and, in brackets, from the best process CPU
time, steadier on a loaded machine). Runs are interleaved so background load hits all alike.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
import time
from pathlib import Path

import numpy as np

import capture.raw as raw

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "raw"


def _peers():
    peers = {}
    with contextlib.suppress(ImportError):
        import expelliarmus

        def expel(path, fmt):
            wizard = expelliarmus.Wizard(encoding={"EVT2": "evt2", "EVT3": "evt3"}[fmt])
            with open(os.devnull, "w") as null, contextlib.redirect_stdout(null):
                arr = wizard.read(str(path))
            return None if arr is None else len(arr)
        peers["expelliarmus"] = expel
    with contextlib.suppress(ImportError):
        import evlib

        def ev_lib(path, fmt):
            return evlib.load_events(str(path), sort=False).collect().height
        peers["evlib"] = ev_lib
    return peers


def _time(fn, *args):
    """Wall and process-CPU seconds of one call (CPU time is steadier on a shared machine)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args)
    return (time.perf_counter() - t0, time.process_time() - c0), out


def bench_file(path: Path, repeat: int, peers: dict) -> dict:
    fmt = raw.read(path).format
    best = {"ours": (np.inf, np.inf), **{k: (np.inf, np.inf) for k in peers}}
    counts = {}
    failed = set()
    for i in range(repeat):
        dt, r = _time(raw.read, path)
        best["ours"] = tuple(map(min, best["ours"], dt))
        counts["ours"] = len(r.events)
        for name, fn in peers.items():
            if name in failed or (name == "evlib" and i >= max(2, repeat // 5)):
                continue
            try:
                dt, n = _time(fn, path, fmt)
            except Exception:             # a peer that cannot decode this file
                n = None
            if n is None or n != counts["ours"]:
                failed.add(name)
                continue
            best[name] = tuple(map(min, best[name], dt))
    return {"format": fmt, "events": counts["ours"], "best_s": best, "failed": failed}


def synthetic(kind: str, n_events: int, out_dir: Path) -> Path:
    """A large file written by our encoder: the real recording's events tiled in time."""
    src = {"EVT3": "expelliarmus_evt3_sample_1280x720.raw", "EVT2": "expelliarmus_evt2_sparklers_640x480.raw"}[kind]
    base = raw.read(SHARED / src)
    ev = base.events
    span = int(ev["t"][-1] - ev["t"][0]) + 1
    reps = -(-n_events // len(ev))
    path = out_dir / f"synthetic_{kind}_{n_events // 1_000_000}M.raw"
    with open(path, "wb") as f:
        f.write(raw.header_bytes(kind, width=base.width, height=base.height))
        for k in range(reps):               # encode tile by tile (each tile restates its time and y)
            tile = ev.copy()
            tile["t"] += k * span - ev["t"][0]
            tile = tile[: n_events - k * len(ev)]
            f.write(raw.encode(tile, format=kind, width=base.width, height=base.height))
    return path


def report(label: str, res: dict) -> None:
    n = res["events"]
    (ours, ours_cpu) = res["best_s"]["ours"]
    line = f"{label:48s} {res['format']:5s} {n:>10,d} ev | ours {n / ours / 1e6:6.1f} Mev/s"
    for name, (dt, dt_cpu) in res["best_s"].items():
        if name == "ours":
            continue
        if name in res["failed"] or not np.isfinite(dt):
            line += f" | {name}: cannot decode"
        else:
            line += (f" | {name} {n / dt / 1e6:6.1f} Mev/s, ours/{name} {dt / ours:5.2f}x"
                     f" (cpu {dt_cpu / ours_cpu:5.2f}x)")
    print(line, flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shared", type=Path, default=SHARED)
    parser.add_argument("--events", type=int, default=20_000_000)
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--no-synthetic", action="store_true")
    args = parser.parse_args()
    peers = _peers()
    print(f"peers: {', '.join(peers) or 'none'}; best of {args.repeat} (evlib: fewer); ours: "
          f"{min(os.cpu_count() or 1, raw.stream.MAX_THREADS)} threads from {raw.stream.PARALLEL_MIN_BYTES >> 20} MiB of words")
    for path in sorted(args.shared.glob("*.raw")):
        report(path.name, bench_file(path, args.repeat, peers))
    if not args.no_synthetic:
        with tempfile.TemporaryDirectory() as tmp:
            for kind in ("EVT3", "EVT2"):
                path = synthetic(kind, args.events, Path(tmp))
                report(f"{path.name} ({path.stat().st_size / 1e6:.0f} MB)",
                       bench_file(path, max(3, args.repeat // 5), peers))


if __name__ == "__main__":
    main()
