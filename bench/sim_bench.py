"""Simulator speed: 60,000 events of a 100 px ball at 500 rps (640x480, threshold 0.15).

Peer: the same ball drifting at 1 px/s, which takes the general renderer (sphere
points recomputed for every sub-step) instead of the static fast path.
Run: ``PYTHONPATH=. python bench/sim_bench.py``.
"""

import time

import numpy as np

import sim


def best_of(n, fn):
    times = []
    for _ in range(n):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def main():
    print(f"{'case':44s} {'events':>8s} {'sim span':>9s} {'wall s':>7s} {'Mev/s':>6s}")
    for tex in ("volleyball", "soccer"):
        for rps in (500.0, 10.0):
            kw = dict(texture=tex, rps=rps, axis=(1.0, 1.0, 0.3), radius_px=100, n_events=60000, seed=0)
            t_fast, (ev, _) = best_of(3, lambda: sim.spinning_ball(**kw))
            t_gen, (ev2, _) = best_of(3, lambda: sim.spinning_ball(velocity_px_s=(1.0, 0.0), **kw))
            span = (ev["t"][-1] - ev["t"][0]) * 1e-3
            print(f"{tex + f' {rps:g} rps static (fast path)':44s} {ev.size:8d} {span:7.2f}ms {t_fast:7.2f} "
                  f"{ev.size / t_fast / 1e6:6.2f}")
            print(f"{tex + f' {rps:g} rps drifting (general path)':44s} {ev2.size:8d} "
                  f"{(ev2['t'][-1] - ev2['t'][0]) * 1e-3:7.2f}ms {t_gen:7.2f} {ev2.size / t_gen / 1e6:6.2f}"
                  f"   general/fast = {t_gen / t_fast:.2f}x")
    if hasattr(sim, "rally"):
        t, rec = best_of(1, lambda: sim.rally(seed=0))
        print(f"{'rally (demo flight, events+frames)':44s} {rec.events.size:8d} "
              f"{(rec.events['t'][-1] - rec.events['t'][0]) * 1e-3:7.1f}ms {t:7.2f}")


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
