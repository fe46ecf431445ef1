"""Offline replay speed as a multiple of real time, for sessions at 1, 5 and 20 Mev/s.

A session is ``--flights`` ball flights (one simulated ``sim.flight``, 1280x720,
volleyball with spin, ball + player + noise, repeated with fresh subsamples) separated by
``--gap`` seconds without a ball; it is brought to each average event rate (the
flights' events subsampled where they exceed 80 % of it, uniform background activity
making up the rest), stored as a session and replayed (detection + spin, no ``.rrd``).
Printed per rate: the session's duration, the replay's wall time, the multiple of real time
(> 1: faster than real time) and the stages alone in one process, plus the peer figure in
the same run: reading the events back from the store alone.

Usage::

    PYTHONPATH=. python bench/replay_bench.py [--duration 0.4] [--flights 4] [--gap 0.3]
                                              [--rates 1 5 20] [--workers 2]
    PYTHONPATH=. python bench/replay_bench.py --flights 1 --gap 0   # one flight, nothing else
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import sim
from capture.events import concatenate
from capture.pipeline.replay import ReplayOptions, replay, spin_part, track_session
from capture.session import create_session, open_session
from sim.esim import noise_events


def make_session(path: Path, rec, rate_ev_s: float, n_flights: int, gap_s: float, seed: int = 0) -> int:
    """Store ``n_flights`` copies of ``rec`` ``gap_s`` apart at an average ``rate_ev_s``; returns the events."""
    t0 = int(rec.events["t"][0])
    span_us = int(rec.events["t"][-1]) + 1 - t0
    period_us = span_us + int(gap_s * 1e6)
    total_s = n_flights * period_us * 1e-6
    target = rate_ev_s * total_s
    rng = np.random.default_rng(seed)
    keep = min(1.0, 0.8 * target / (n_flights * len(rec.events)))
    parts = []
    for k in range(n_flights):
        ev = rec.events[rng.random(len(rec.events)) < keep].copy()
        ev["t"] += k * period_us
        parts.append(ev)
    n_noise = target - sum(len(p) for p in parts)
    noise, _ = noise_events(rec.width, rec.height, t0, t0 + n_flights * period_us, rng,
                            rate_hz_per_px=n_noise / (rec.width * rec.height * total_s))
    events = concatenate([*parts, noise])
    events = events[np.argsort(events["t"], kind="stable")]
    with create_session(path, width=rec.width, height=rec.height) as w:
        for i in range(0, len(events), 1 << 20):
            w.append_events(events[i:i + (1 << 20)])
    return len(events)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=0.4, help="flight duration, s")
    ap.add_argument("--flights", type=int, default=4, help="flights per session")
    ap.add_argument("--gap", type=float, default=0.3, help="time without a ball between flights, s")
    ap.add_argument("--rates", type=float, nargs="+", default=[1, 5, 20], help="Mev/s")
    ap.add_argument("--workers", type=int, default=ReplayOptions.workers)
    args = ap.parse_args()
    print(f"simulating a {args.duration:.2f} s flight ...", flush=True)
    rec = sim.flight(rps=30.0, axis=(0.0, 0.0, -1.0), duration_s=args.duration, seed=1)
    native = len(rec.events) / args.duration / 1e6
    print(f"flight: {len(rec.events):,} events ({native:.1f} Mev/s of ball, player and noise)")
    print(f"{'rate':>8} {'events':>11} {'session s':>9} {'flights':>7} {'read-only':>10} {'track s':>8} {'spin s':>8} {'replay s':>9} "
          f"{'x real time':>11} {'windows':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        for rate in args.rates:
            path = Path(tmp) / f"s{len(list(Path(tmp).iterdir()))}"
            n = make_session(path, rec, rate * 1e6, args.flights, args.gap)
            s = open_session(path)
            duration_s = s.duration_s
            t = time.perf_counter()
            for _ in s.iter_events():
                pass
            t_read = time.perf_counter() - t
            opts = ReplayOptions(workers=args.workers)
            t = time.perf_counter()
            parts = []
            track = track_session(path, opts, progress=False, on_part=parts.append)
            t_track = time.perf_counter() - t
            t = time.perf_counter()
            n_win = sum(len(spin_part(p, opts)["rps"]) for p in parts)
            t_spin = time.perf_counter() - t
            t = time.perf_counter()
            replay(path, options=opts, progress=False)
            t_replay = time.perf_counter() - t
            print(f"{rate:6g}M {n:11,} {duration_s:9.2f} {len(track.flight_ids()):7d} {t_read:9.2f}s {t_track:8.2f} {t_spin:8.2f} {t_replay:9.2f} "
                  f"{duration_s / t_replay:10.2f}x {n_win:8d}", flush=True)
    print("read-only = reading the events back from the store (the floor any replay pays);")
    print("track/spin = the two stages run alone in one process; replay = the whole unit with "
          f"{args.workers} worker(s).")


if __name__ == "__main__":
    main()
