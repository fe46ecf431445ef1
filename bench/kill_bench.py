"""What a kill loses: SIGKILL a recording at random moments and compare its store with the
data it had received (run on demand; prints numbers, asserts nothing).

    PYTHONPATH=. python bench/kill_bench.py [--kills 25] [--rates-mev-s 1,16] [--seconds 6]

For each rate, a synthetic EVT3 stream (``bench/evk_bench.py``'s) of ``--seconds`` is played
through the fake EVK at the recorded pace by ``python -m capture.run --fake``; each run is
killed (SIGKILL) at a random moment while streaming. Then:

- received: the events in the session's ``events.raw`` (written as the bytes arrive, before
  any decoding), decoded; the peer the store is measured against;
- lag: sensor time from the store's last committed event to the last event received, s
  (the pace is the recorded one, so sensor time is wall time): what the kill lost from the
  store (the RAW file keeps it);
- prefix: whether the store's events are exactly the first events received;
- recovered: whether ``capture.ingest.recover_session`` (what ``capture.replay`` runs first on
  such a session) then made the store exactly the events received: nothing lost, none twice;
  recover s: the longest it took, s.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from evk_bench import synth_stream  # noqa: E402

from capture import raw  # noqa: E402
from capture.ingest import recover_session  # noqa: E402
from capture.session import open_session  # noqa: E402


def one_kill(src: Path, out: Path, seconds: float, rng: random.Random) -> dict:
    """Record ``src`` into ``out`` and SIGKILL the recorder at a random moment while streaming."""
    proc = subprocess.Popen([sys.executable, "-m", "capture.run", "--fake", str(src), "--out", str(out),
                             "--viewer", "none", "--no-analysis", "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    raw_path = out / "events.raw"
    deadline = time.monotonic() + 120
    while not (raw_path.exists() and raw_path.stat().st_size > 4096) and time.monotonic() < deadline:
        time.sleep(0.005)
    time.sleep(rng.uniform(0.3, seconds - 0.5))
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with warnings.catch_warnings():  # a kill cuts the last words short: expected
        warnings.simplefilter("ignore")
        received = raw.read(raw_path).events
    s = open_session(out)
    n = s.n_events
    store = s.events()
    t_recv = int(received["t"][-1]) if len(received) else 0
    t_store = int(store["t"][-1]) if n else (int(received["t"][0]) if len(received) else 0)
    prefix = bool(n <= len(received) and np.array_equal(store, received[:n]))
    t = time.perf_counter()
    recover_session(out, progress=False)
    recover_s = time.perf_counter() - t
    return {"received": len(received), "stored": n, "prefix": prefix,
            "lag_s": (t_recv - t_store) * 1e-6, "recover_s": recover_s,
            "recovered": bool(np.array_equal(open_session(out).events(), received))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=25, help="kills per rate")
    ap.add_argument("--rates-mev-s", default="1,16", help="comma-separated event rates, Mev/s")
    ap.add_argument("--seconds", type=float, default=6.0, help="stream length, s")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    print(f"{'rate Mev/s':>10} {'kills':>5} {'prefix':>6} {'lag median s':>12} {'lag p90 s':>9} "
          f"{'lag max s':>9} {'> 0.5 s':>7} {'stored/received':>15} {'recovered':>9} {'recover s':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for rate in [float(r) for r in args.rates_mev_s.split(",")]:
            src = tmp / f"stream_{rate:g}.raw"
            synth_stream(src, rate * args.seconds, rate * 1e6)
            rows = []
            for k in range(args.kills):
                out = tmp / f"s_{rate:g}_{k}"
                rows.append(one_kill(src, out, args.seconds, rng))
                subprocess.run(["rm", "-rf", str(out)], check=True)
            lag = np.array([r["lag_s"] for r in rows])
            stored = sum(r["stored"] for r in rows) / max(1, sum(r["received"] for r in rows))
            print(f"{rate:10g} {len(rows):5d} {sum(r['prefix'] for r in rows):6d} {np.median(lag):12.3f} "
                  f"{np.percentile(lag, 90):9.3f} {lag.max():9.3f} {int((lag > 0.5).sum()):7d} {stored:15.3f} "
                  f"{sum(r['recovered'] for r in rows):9d} {max(r['recover_s'] for r in rows):9.2f}",
                  flush=True)
    print(f"(lag: the store's last event behind the last event received in events.raw; cpu count "
          f"{os.cpu_count()}, load {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
