"""Batch replay on Dask distributed: sessions per minute and Mev/s on 1 and 2 workers, and the
scheduler's overhead against running the same units in one process.

``--sessions`` sessions, each ``--flights`` copies of one simulated flight (``sim.flight``,
1280x720, volleyball with spin, player and noise) ``--gap`` s apart at ``--rate`` Mev/s on average
(``replay_bench.make_session``), are analysed:

- in one process, unit after unit (``track_unit``, ``plan_unit``, every ``spin_unit``,
  ``store_unit``: the peer, one thread as each Dask worker; a spawned process doing nothing
  else, as this one runs the clusters' schedulers); and ``capture.pipeline.replay.replay`` of each
  session in that process (spin parts streamed from tracking, not read again);
- by ``capture.pipeline.batch.run_batch`` on a ``LocalCluster`` of 1, then 2 worker processes
  (one thread each; the clusters are started first and kept, their start-up and the workers'
  imports timed apart; a cluster's first run is cold, as is the peer's).

Printed: wall time, sessions per minute, Mev/s of every run; then, from the best of ``--repeat``
alternated runs of each kind (this machine's speed varies by 10-20 % from run to run), the
speed-up of N workers over 1 and the overhead of the 1-worker batch over the units in one process
(in all and per task, and split into the time outside the tasks and the tasks' own compute
time against the same units in one process).

Usage::

    PYTHONPATH=. python bench/batch_bench.py [--sessions 6] [--rate 2] [--flights 2] [--workers 1 2] [--repeat 2]
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import cv2
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))

import sim  # noqa: E402
from capture.pipeline.batch import (OneThreadPerWorker, local_cluster, plan_unit, run_batch, spin_unit,  # noqa: E402
                                    store_unit, track_unit)
from capture.pipeline.replay import ReplayOptions, replay  # noqa: E402
from capture.session import open_session  # noqa: E402
from replay_bench import make_session  # noqa: E402


def in_process(paths, options) -> tuple[float, int]:
    """Wall time (s) and task count of every session's units run one after another in this
    process, on one thread (as in a Dask worker)."""
    cv2.setNumThreads(1)
    threadpool_limits(1)
    t = time.perf_counter()
    n_tasks = 0
    for p in paths:
        track = track_unit(str(p), options, True)
        plan = plan_unit(track, options)
        spins = [spin_unit(str(p), track, fid, starts, options) for fid, starts in plan]
        store_unit(str(p), track, spins, options, None)
        n_tasks += 3 + len(spins)
    return time.perf_counter() - t, n_tasks


def replay_in_process(paths, options) -> float:
    """Wall time (s) of ``capture.pipeline.replay.replay`` on every session in this process alone
    (its spin parts streamed from tracking, no worker process), on one thread."""
    cv2.setNumThreads(1)
    threadpool_limits(1)
    t = time.perf_counter()
    for p in paths:
        replay(p, options=ReplayOptions(**{**options.__dict__, "workers": 1}), progress=False)
    return time.perf_counter() - t


def start_cluster(stack: contextlib.ExitStack, workers: int):
    """A client of a new LocalCluster of ``workers`` (closed with ``stack``) and its start-up time (s),
    the workers' imports included."""
    from distributed import Client

    t = time.perf_counter()
    cluster = stack.enter_context(local_cluster(workers))
    client = stack.enter_context(Client(cluster))
    client.register_plugin(OneThreadPerWorker())
    client.run(__import__, "capture.pipeline.batch")
    return client, time.perf_counter() - t


def on_cluster(paths, options, client) -> tuple[float, float, int]:
    """Batch wall time (s), time spent computing in tasks (s, all workers) and windows found."""
    from distributed import get_task_stream

    with get_task_stream(client) as stream:
        t = time.perf_counter()
        result = run_batch(paths, client, options, force=True, progress=False)
        wall = time.perf_counter() - t
    assert not result.failed, result.failed
    computing = sum(s["stop"] - s["start"] for task in stream.data for s in task["startstops"]
                    if s["action"] == "compute")
    return wall, computing, len(result.windows["session"])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sessions", type=int, default=6)
    ap.add_argument("--rate", type=float, default=2.0, help="average event rate of a session, Mev/s")
    ap.add_argument("--duration", type=float, default=0.4, help="flight duration, s")
    ap.add_argument("--flights", type=int, default=2, help="flights per session")
    ap.add_argument("--gap", type=float, default=0.2, help="time without a ball between flights, s")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=2, help="runs of each kind, alternated; the best counts")
    args = ap.parse_args()
    options = ReplayOptions()
    print(f"simulating a {args.duration:.2f} s flight ...", flush=True)
    rec = sim.flight(rps=30.0, axis=(0.0, 0.0, -1.0), duration_s=args.duration, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i in range(args.sessions):
            paths.append(Path(tmp) / f"s{i}")
            make_session(paths[-1], rec, args.rate * 1e6, args.flights, args.gap, seed=i)
        n_events = sum(open_session(p).n_events for p in paths)
        span_s = sum(open_session(p).duration_s for p in paths)
        print(f"{args.sessions} sessions, {n_events / 1e6:.1f} Mev, {span_s:.1f} s of recording")

        stack = contextlib.ExitStack()
        # the peer in a process of its own: this one runs the clusters' schedulers in threads
        peer_process = stack.enter_context(ProcessPoolExecutor(1, mp_context=get_context("spawn")))
        peer_process.submit(in_process, [], options).result()  # its imports, outside the timing
        clients = {}
        for n in args.workers:
            clients[n], started = start_cluster(stack, n)
            print(f"LocalCluster of {n} worker(s) started in {started:.2f} s (the workers' imports included)")
        print(f"{'run':<22} {'wall s':>7} {'in tasks s':>10} {'sessions/min':>12} {'Mev/s':>6}")
        walls, peer, replays = {}, [], []
        with stack:
            # alternated (a busy spell of the machine hits every kind of run), each cluster kept warm
            for _ in range(args.repeat):
                replay_s = peer_process.submit(replay_in_process, paths, options).result()
                print(f"{'replay, one process':<22} {replay_s:7.2f} {replay_s:10.2f} "
                      f"{60 * len(paths) / replay_s:12.1f} {n_events / replay_s / 1e6:6.2f}", flush=True)
                replays.append(replay_s)
                peer_s, n_tasks = peer_process.submit(in_process, paths, options).result()
                peer.append(peer_s)
                windows = sum(len(open_session(p).spin()["t_start_us"]) for p in paths)
                print(f"{'one process (peer)':<22} {peer_s:7.2f} {peer_s:10.2f} {60 * len(paths) / peer_s:12.1f} "
                      f"{n_events / peer_s / 1e6:6.2f}", flush=True)
                for n, client in clients.items():
                    wall, computing, n_windows = on_cluster(paths, options, client)
                    assert n_windows == windows, (n_windows, windows)
                    walls.setdefault(n, []).append((wall, computing))
                    print(f"{f'Dask, {n} worker(s)':<22} {wall:7.2f} {computing:10.2f} {60 * len(paths) / wall:12.1f} "
                          f"{n_events / wall / 1e6:6.2f}", flush=True)
        best = {n: min(w) for n, w in walls.items()}  # (wall, computing) of the fastest run
        print(f"best of {args.repeat}: replay {min(replays):.2f} s, the units in one process {min(peer):.2f} s "
              f"({100 * (min(peer) / min(replays) - 1):+.1f} % against replay: each spin part reads its own events), "
              + ", ".join(f"{n} worker(s) {w:.2f} s" for n, (w, _) in best.items()))
        first = args.workers[0]
        for n in args.workers[1:]:
            print(f"{n} workers vs {first}: {best[first][0] / best[n][0]:.2f}x")
        if 1 in best:
            wall, computing = best[1]
            over = wall - min(peer)
            print(f"overhead on 1 worker: {over:+.2f} s = {100 * over / min(peer):+.1f} % of the work, "
                  f"{1e3 * over / n_tasks:+.1f} ms per task ({n_tasks} tasks, {windows} spin windows); "
                  f"outside the tasks (scheduling, transfers) {100 * (wall - computing) / min(peer):.1f} %, "
                  f"computing in the tasks against one process {100 * (computing - min(peer)) / min(peer):+.1f} %")

if __name__ == "__main__":
    main()
