"""Benchmark the Rerun review: offline ``write_rrd`` and the live logger.

Run: ``python bench/review_bench.py [--seconds 1] [--rates 1,5,20]``

For sessions of ``--seconds`` of events at each rate (Mev/s), prints:
- ``write_rrd`` wall time, as a multiple of real time, and against the peer
  "read the same events from the store" (``Session.iter_events``) measured in the same run;
- the live logger: median and max time of a ``log_events`` call on the caller
  (against ``np.copy`` of the same batch, same run) and how fast its thread logs.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from capture import review
from capture.events import make_events
from capture.session import create_session, open_session


def make_session(path: Path, rate_mev_s: float, seconds: float, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    n_total = int(rate_mev_s * 1e6 * seconds)
    with create_session(path, width=1280, height=720) as w:
        step = 1 << 20
        for i0 in range(0, n_total, step):
            n = min(step, n_total - i0)
            t = (np.arange(i0, i0 + n) / rate_mev_s).astype(np.int64)  # µs, uniform rate
            w.append_events(make_events(t, rng.integers(0, 1280, n), rng.integers(0, 720, n),
                                        rng.integers(0, 2, n)))


def bench_offline(path: Path, rrd: Path, seconds: float) -> None:
    session = open_session(path)
    t0 = time.perf_counter()
    n = sum(len(b) for b in session.iter_events(1 << 20))
    t_read = time.perf_counter() - t0
    t0 = time.perf_counter()
    stats = review.write_rrd(session, rrd, progress=False)
    t_write = time.perf_counter() - t0
    print(f"  write_rrd: {n / 1e6:.1f} Mev in {t_write:.2f} s = {seconds / t_write:.2f}x real time, "
          f"{n / t_write / 1e6:.1f} Mev/s; peer store read {t_read:.2f} s "
          f"(write_rrd / read = {t_write / t_read:.1f}); logged {stats.n_events_logged / 1e6:.2f} Mev, "
          f"{stats.n_slices_decimated}/{stats.n_slices} slices decimated, rrd {rrd.stat().st_size / 1e6:.1f} MB")


def bench_live(path: Path, rrd: Path) -> None:
    session = open_session(path)
    batches = list(session.iter_events(100_000))
    live = review.LiveReview("rrd", rrd_path=rrd, width=1280, height=720, max_queue=1024)
    call_s, copy_s = [], []
    t_start = time.perf_counter()
    for b in batches:
        t0 = time.perf_counter()
        live.log_events(b)
        call_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        b.copy()
        copy_s.append(time.perf_counter() - t0)
    live.close(timeout_s=600)
    t_all = time.perf_counter() - t_start
    n = sum(len(b) for b in batches)
    print(f"  live: log_events median {np.median(call_s) * 1e6:.1f} µs, max {np.max(call_s) * 1e6:.1f} µs "
          f"per 100k-event batch (peer np.copy median {np.median(copy_s) * 1e6:.1f} µs); thread logged "
          f"{n / t_all / 1e6:.1f} Mev/s, skipped {live.skipped or 0}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=1.0)
    parser.add_argument("--rates", default="1,5,20", help="comma-separated Mev/s")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (float(r) for r in args.rates.split(",")):
            path = Path(tmp) / f"s{rate:g}"
            make_session(path, rate, args.seconds)
            print(f"{rate:g} Mev/s, {args.seconds:g} s:")
            bench_offline(path, Path(tmp) / f"s{rate:g}.rrd", args.seconds)
            bench_live(path, Path(tmp) / f"l{rate:g}.rrd")


if __name__ == "__main__":
    main()
