"""Offline replay speed as a multiple of real time, for sessions at 1, 5 and 20 Mev/s.

One simulated ball flight (``sim.flight``, 1280x720, volleyball with spin) is
brought to each event rate (a random subset of its events below its own rate,
background-activity noise added above it), stored as a session, and replayed (detection + spin, no ``.rrd``). Printed per rate: the
recording's duration, the replay's wall time, the multiple of real time
(> 1: faster than real time) and the stages' shares, plus the peer figure in
the same run: reading the events back from the store alone.

Usage::

    PYTHONPATH=. python bench/replay_bench.py [--duration 0.4] [--rates 1 5 20] [--workers 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import sim
from capture.events import concatenate
from capture.replay import ReplayOptions, _spin_unit, replay, spin_units, track_session
from capture.session import create_session, open_session
from sim.esim import noise_events


def make_session(path: Path, rec, rate_ev_s: float, seed: int = 0) -> int:
    """Store ``rec``'s events brought to ``rate_ev_s``; returns the number of events."""
    t0, t1 = int(rec.events["t"][0]), int(rec.events["t"][-1]) + 1
    span_s = (t1 - t0) * 1e-6
    target = rate_ev_s * span_s
    rng = np.random.default_rng(seed)
    if target < len(rec.events):
        events = rec.events[rng.random(len(rec.events)) < target / len(rec.events)]
    else:
        rate_px = (target - len(rec.events)) / (rec.width * rec.height * span_s)
        noise, _ = noise_events(rec.width, rec.height, t0, t1, rng, rate_hz_per_px=rate_px)
        events = concatenate([rec.events, noise])
        events = events[np.argsort(events["t"], kind="stable")]
    with create_session(path, width=rec.width, height=rec.height) as w:
        for i in range(0, len(events), 1 << 20):
            w.append_events(events[i:i + (1 << 20)])
    return len(events)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=0.4, help="flight duration, s")
    ap.add_argument("--rates", type=float, nargs="+", default=[1, 5, 20], help="Mev/s")
    ap.add_argument("--workers", type=int, default=ReplayOptions.workers)
    args = ap.parse_args()
    print(f"simulating a {args.duration:.2f} s flight ...", flush=True)
    rec = sim.flight(rps=30.0, axis=(0.0, 0.0, -1.0), duration_s=args.duration, seed=1)
    native = len(rec.events) / args.duration / 1e6
    print(f"flight: {len(rec.events):,} events ({native:.1f} Mev/s of ball, player and noise)")
    print(f"{'rate':>8} {'events':>11} {'read-only':>10} {'track s':>8} {'spin s':>8} {'replay s':>9} "
          f"{'x real time':>11} {'windows':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        for rate in args.rates:
            path = Path(tmp) / f"s{len(list(Path(tmp).iterdir()))}"
            n = make_session(path, rec, rate * 1e6)
            s = open_session(path)
            duration_s = (int(s.events_range(n - 1, n)["t"][0]) - int(s.events_range(0, 1)["t"][0])) * 1e-6
            t = time.perf_counter()
            for _ in s.iter_events():
                pass
            t_read = time.perf_counter() - t
            opts = ReplayOptions(workers=args.workers)
            t = time.perf_counter()
            track = track_session(path, opts, progress=False)
            t_track = time.perf_counter() - t
            t = time.perf_counter()
            n_win = sum(len(_spin_unit(u)["rps"]) for u in spin_units(path, track, opts))
            t_spin = time.perf_counter() - t
            t = time.perf_counter()
            replay(path, options=opts, progress=False)
            t_replay = time.perf_counter() - t
            print(f"{rate:6g}M {n:11,} {t_read:9.2f}s {t_track:8.2f} {t_spin:8.2f} {t_replay:9.2f} "
                  f"{duration_s / t_replay:10.2f}x {n_win:8d}", flush=True)
    print("read-only = reading the events back from the store (the floor any replay pays);")
    print("track/spin = the two stages run alone in one process; replay = the whole unit with "
          f"{args.workers} worker(s).")


if __name__ == "__main__":
    main()
