"""Ball detection/tracking benchmark on simulated flights.

Usage::

    PYTHONPATH=. python bench/detect_bench.py [--quick] [--seed N]

For each case (sensor size, ball radius, image-equivalent speed, spin on/off)
the simulator renders a ball crossing a textured court background with noise
and hot pixels; ``detect.track_ball`` tracks it and the track is compared with
the simulator's truth every 2 ms while the ball is fully on the sensor.

Printed per case and overall: centre error (median, 95th percentile, px),
radius error (median |dr|, px), velocity error (median, % of speed), recall
(truth samples with a track row within 1 ms whose centre is within
``max(2 px, 0.25 r)``), false detections per second (rows farther than that),
and processing speed (events/s on one core) with its ratio to the input's own
event rate (real-time factor) and to 10 Mev/s.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import sim
from detect import track_ball
from sim.esim import noise_events

VOLLEYBALL_RADIUS_M = 0.105


def evaluate(tr, truth_fn, t_samples_us, radius_px):
    """Errors of track ``tr`` against ``truth_fn(t_us) -> (cx, cy, r, vx, vy)`` at ``t_samples_us``."""
    tol = max(2.0, 0.25 * radius_px)
    out = dict(err=np.zeros(0), rerr=np.zeros(0), verr=np.zeros(0), hit=np.zeros(len(t_samples_us), bool),
               false=0)
    if len(tr) == 0:
        return out
    cx, cy, r, vx, vy = truth_fn(tr.t_us)
    err = np.hypot(tr.cx - cx, tr.cy - cy)
    good = err <= tol
    out["false"] = int((~good).sum())
    out["err"], out["rerr"] = err[good], np.abs(tr.r - r)[good]
    out["verr"] = (np.hypot(tr.vx - vx, tr.vy - vy) / np.maximum(np.hypot(vx, vy), 1e-9))[good]
    good_t = tr.t_us[good]
    if len(good_t):
        j = np.clip(np.searchsorted(good_t, t_samples_us), 1, len(good_t) - 1) if len(good_t) > 1 else 0
        near = np.minimum(np.abs(good_t[j] - t_samples_us),
                          np.abs(good_t[np.maximum(j - 1, 0)] - t_samples_us)) if len(good_t) > 1 \
            else np.abs(good_t[0] - t_samples_us)
        out["hit"] = near <= 1000
    return out


def run_case(width, height, radius_px, speed_mps, rps, seed, duration_s):
    v_px_s = speed_mps * radius_px / VOLLEYBALL_RADIUS_M
    ang = np.deg2rad(12.0)
    vel = np.array([v_px_s * np.cos(ang), -v_px_s * np.sin(ang)])
    travel = np.abs(vel) * duration_s
    c0 = np.array([radius_px + 4.0, min(height - radius_px - 4.0, height / 2 + travel[1] / 2)])
    dur = min(duration_s, (width - 2 * radius_px - 10) / max(vel[0], 1.0))
    t0 = time.perf_counter()
    ev, truth = sim.spinning_ball(radius_px=radius_px, rps=rps, axis=(0.2, 1.0, 0.3), center=tuple(c0),
                                  velocity_px_s=tuple(vel), width=width, height=height, n_events=None,
                                  duration_s=dur, background="court", noise_rate_hz=1.0, hot_pixels=30,
                                  seed=seed)
    t_sim = time.perf_counter() - t0
    t0 = time.perf_counter()
    tr = track_ball(ev, width=width, height=height, r_range=(5.0, 100.0))
    t_track = time.perf_counter() - t0
    c_first, v = np.asarray(truth["center"]), np.asarray(truth["velocity_px_s"])

    def truth_fn(t_us):
        dt = (np.asarray(t_us) - truth["t_first_us"]) * 1e-6
        n = np.ones_like(dt)
        return c_first[0] + v[0] * dt, c_first[1] + v[1] * dt, radius_px * n, v[0] * n, v[1] * n

    span = (int(ev["t"][0]), int(ev["t"][-1]))
    samples = np.arange(span[0] + 1000, span[1] - 1000, 2000)
    res = evaluate(tr, truth_fn, samples, radius_px)
    res.update(n_events=len(ev), span_s=(span[1] - span[0]) * 1e-6, t_track=t_track, t_sim=t_sim,
               n_flights=len(tr.flight_ids()))
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer, shorter cases")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    sensors = [(1280, 720), (640, 480)]
    radii = [10, 40] if args.quick else [10, 25, 50, 80]
    speeds = [5.0, 30.0]
    spins = [0.0, 40.0]
    duration_s = 0.02 if args.quick else 0.04
    rows = []
    print(f"{'sensor':>9} {'r':>3} {'m/s':>4} {'rps':>4} {'events':>8} {'med':>6} {'p95':>6} {'dr':>5} "
          f"{'dv%':>5} {'recall':>7} {'FD/s':>6} {'Mev/s':>6} {'xRT':>6} {'fl':>2}")
    seed = args.seed
    for (w, h) in sensors:
        for r in radii:
            if 2 * r + 20 > h:
                continue
            for s in speeds:
                for rps in spins:
                    seed += 1
                    res = run_case(w, h, r, s, rps, seed, duration_s)
                    rows.append(res)
                    rate = res["n_events"] / res["t_track"]
                    print(f"{w}x{h:<4} {r:>3} {s:>4.0f} {rps:>4.0f} {res['n_events']:>8} "
                          f"{np.median(res['err']) if len(res['err']) else np.nan:>6.3f} "
                          f"{np.percentile(res['err'], 95) if len(res['err']) else np.nan:>6.3f} "
                          f"{np.median(res['rerr']) if len(res['rerr']) else np.nan:>5.2f} "
                          f"{100 * np.median(res['verr']) if len(res['verr']) else np.nan:>5.2f} "
                          f"{100 * res['hit'].mean() if len(res['hit']) else np.nan:>6.1f}% "
                          f"{res['false'] / res['span_s']:>6.1f} {rate / 1e6:>6.2f} "
                          f"{rate * res['span_s'] / res['n_events']:>6.2f} {res['n_flights']:>2}", flush=True)
    # ball-free input: noise + hot pixels at ~10 Mev/s on the big sensor
    ev, _ = noise_events(1280, 720, 0, 300_000, np.random.default_rng(seed + 1), rate_hz_per_px=11.0,
                         hot_pixels=100)
    t0 = time.perf_counter()
    tr = track_ball(ev, width=1280, height=720)
    t_noise = time.perf_counter() - t0
    err = np.concatenate([r["err"] for r in rows])
    rerr = np.concatenate([r["rerr"] for r in rows])
    verr = np.concatenate([r["verr"] for r in rows])
    hit = np.concatenate([r["hit"] for r in rows])
    span = sum(r["span_s"] for r in rows)
    n_ev = sum(r["n_events"] for r in rows)
    t_tr = sum(r["t_track"] for r in rows)
    print("\nOVERALL (all ball cases)")
    print(f"  centre error median {np.median(err):.3f} px, p95 {np.percentile(err, 95):.3f} px   (goal median <= 1)")
    print(f"  radius error median {np.median(rerr):.3f} px, p95 {np.percentile(rerr, 95):.3f} px   (goal <= 1)")
    print(f"  velocity error median {100 * np.median(verr):.2f} %, p95 {100 * np.percentile(verr, 95):.2f} %")
    print(f"  recall {100 * hit.mean():.2f} %   (goal >= 99 %)")
    print(f"  false detections {sum(r['false'] for r in rows) / span:.2f} /s on ball cases; "
          f"{len(tr) / 0.3:.2f} /s on ball-free noise+hot pixels ({len(ev) / 0.3 / 1e6:.1f} Mev/s input)")
    print(f"  speed {n_ev / t_tr / 1e6:.2f} Mev/s on ball cases ({n_ev / t_tr / 1e7:.2f} x 10 Mev/s), "
          f"{len(ev) / t_noise / 1e6:.2f} Mev/s on the noise-only input ({len(ev) / t_noise / 1e7:.2f} x 10 Mev/s)")


if __name__ == "__main__":
    main()
