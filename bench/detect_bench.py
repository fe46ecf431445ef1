"""Ball detection/tracking benchmark on simulated flights.

Usage::

    PYTHONPATH=. python bench/detect_bench.py [--quick] [--seed N]

Each case is a ``sim.flight``: a textured court background, a volleyball of
radius ``r`` px flying into the sensor at an image-equivalent speed (m/s scaled
by ``r / 0.105 m``) under image gravity, with or without spin, a player-like
distractor walking through, noise events and hot pixels; half of the cases also
have 120 fps frames (exposure half the period) fused with the events. ``detect.track_ball`` tracks it and
the track is compared with the ball's true circle every 2 ms while the ball
is fully on the sensor.

Printed per case and overall: centre error (median, 95th percentile, px),
radius error (median |dr|, px), velocity error (median, % of speed), recall
(truth samples with a track row within 1 ms whose centre is within
``max(2 px, 0.25 r)``), false detections per second (rows farther than that),
and processing speed (events per CPU second, OpenCV on one thread) with its ratio to the input's own
event rate (real-time factor) and to 10 Mev/s.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

import sim
from detect import track_ball
from sim.esim import noise_events

VOLLEYBALL_RADIUS_M = 0.105


def make_case(width, height, radius_px, speed_mps, rps, seed, duration_s, frames_fps=None):
    """One simulated flight (``sim.flight``) at an image-equivalent speed of ``speed_mps``."""
    rng = np.random.default_rng(seed)
    v = speed_mps * radius_px / VOLLEYBALL_RADIUS_M
    ang = np.deg2rad(rng.uniform(-20, 20))
    vel = (v * np.cos(ang), -v * np.sin(ang))
    # enter through the left edge when the ball gets fully in early enough, else start inside
    x0 = -0.5 * radius_px if 2 * radius_px / vel[0] < duration_s / 3 else radius_px + 4.0
    dur = min(duration_s, (width - x0 - radius_px - 10) / vel[0])
    y0 = height / 2 - vel[1] * dur / 2
    rec = sim.flight(radius_px=radius_px, width=width, height=height, duration_s=dur, start_px=(x0, y0),
                     velocity_px_s=vel, rps=rps, axis=tuple(rng.normal(size=3)), noise_rate_hz=1.0,
                     hot_pixels=30, distractors=("player",), fps=frames_fps, seed=seed)
    return rec, dur


def evaluate(tr, rec):
    """Errors of track ``tr`` against the recording's true circle."""
    truth = rec.truth_track(visible_only=False)

    def at(t_us):
        return [np.interp(t_us, truth.t_us, getattr(truth, c)) for c in ("cx", "cy", "r", "vx", "vy")]

    tol = max(2.0, 0.25 * rec.truth["radius_px"])
    samples = np.arange(int(rec.events["t"][0]) + 1000, int(rec.events["t"][-1]) - 1000, 2000)
    cx, cy, r, _, _ = at(samples)
    inside = (cx - r >= 0) & (cy - r >= 0) & (cx + r <= rec.width - 1) & (cy + r <= rec.height - 1)
    samples = samples[inside]
    out = dict(err=np.zeros(0), rerr=np.zeros(0), verr=np.zeros(0), vabs=np.zeros(0),
               hit=np.zeros(len(samples), bool), false=0)
    tr = tr.select((tr.t_us >= truth.t_us[0]) & (tr.t_us <= truth.t_us[-1]))  # truth is sampled up to here
    if len(tr) == 0:
        return out
    cx, cy, r, vx, vy = at(tr.t_us)
    err = np.hypot(tr.cx - cx, tr.cy - cy)
    good = err <= tol
    out["false"] = int((~good).sum())
    out["err"], out["rerr"] = err[good], np.abs(tr.r - r)[good]
    dv = np.hypot(tr.vx - vx, tr.vy - vy)
    out["verr"], out["vabs"] = (dv / np.hypot(vx, vy))[good], dv[good]
    good_t = tr.t_us[good]
    if len(good_t) and len(samples):
        j = np.searchsorted(good_t, samples)
        near = np.minimum(np.abs(good_t[np.minimum(j, len(good_t) - 1)] - samples),
                          np.abs(good_t[np.maximum(j - 1, 0)] - samples))
        out["hit"] = near <= 1000
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer, shorter cases")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)  # one core: speeds are CPU time of this process
    sensors = [(1280, 720), (640, 480)]
    radii = [10, 40] if args.quick else [10, 25, 50, 80]
    speeds = [5.0, 30.0]
    spins = [0.0, 40.0]
    duration_s = 0.025 if args.quick else 0.05
    rows = {False: [], True: []}
    print(f"{'sensor':>9} {'r':>3} {'m/s':>4} {'rps':>4} {'frm':>3} {'events':>8} {'med':>6} {'p95':>6} {'dr':>5} "
          f"{'dv%':>5} {'recall':>7} {'FD/s':>6} {'Mev/s':>6} {'xRT':>6} {'fl':>2}")
    seed = args.seed
    for (w, h) in sensors:
        for r in radii:
            for s in speeds:
                for rps in spins:
                    seed += 1
                    with_frames = bool(seed % 2)  # half of the cases also get frames
                    rec, dur = make_case(w, h, r, s, rps, seed, duration_s,
                                         frames_fps=120.0 if with_frames else None)
                    t0 = time.process_time()
                    tr = track_ball(rec.events, width=w, height=h, frames=rec.frames,
                                    frame_times_us=rec.frame_times_us)
                    t_track = time.process_time() - t0
                    res = evaluate(tr, rec)
                    res.update(n_events=len(rec.events), span_s=dur, t_track=t_track,
                               n_flights=len(tr.flight_ids()))
                    rows[with_frames].append(res)
                    rate = res["n_events"] / t_track
                    med = lambda a, f=np.median: f(a) if len(a) else np.nan  # noqa: E731
                    print(f"{w}x{h:<4} {r:>3} {s:>4.0f} {rps:>4.0f} {'yes' if with_frames else 'no':>3} "
                          f"{res['n_events']:>8} {med(res['err']):>6.3f} "
                          f"{med(res['err'], lambda a: np.percentile(a, 95)):>6.3f} {med(res['rerr']):>5.2f} "
                          f"{100 * med(res['verr']):>5.2f} {100 * med(res['hit'], np.mean):>6.1f}% "
                          f"{res['false'] / dur:>6.1f} {rate / 1e6:>6.2f} {rate * dur / res['n_events']:>6.2f} "
                          f"{res['n_flights']:>2}", flush=True)
    # ball-free input: noise + hot pixels at ~10 Mev/s on the big sensor
    ev, _ = noise_events(1280, 720, 0, 300_000, np.random.default_rng(seed + 1), rate_hz_per_px=11.0,
                         hot_pixels=100)
    t0 = time.process_time()
    tr_noise = track_ball(ev, width=1280, height=720)
    t_noise = time.process_time() - t0
    for name, sel in (("events only", rows[False]), ("events + frames", rows[True]),
                      ("ALL", rows[False] + rows[True])):
        err = np.concatenate([r["err"] for r in sel])
        rerr = np.concatenate([r["rerr"] for r in sel])
        verr = np.concatenate([r["verr"] for r in sel])
        vabs = np.concatenate([r["vabs"] for r in sel])
        hit = np.concatenate([r["hit"] for r in sel])
        span = sum(r["span_s"] for r in sel)
        n_ev = sum(r["n_events"] for r in sel)
        t_tr = sum(r["t_track"] for r in sel)
        print(f"\n{name} ({len(sel)} cases, {n_ev / span / 1e6:.1f} Mev/s mean input rate)")
        print(f"  centre error median {np.median(err):.3f} px, p95 {np.percentile(err, 95):.3f} px (goal median <= 1)")
        print(f"  radius error median {np.median(rerr):.3f} px, p95 {np.percentile(rerr, 95):.3f} px (goal <= 1)")
        print(f"  velocity error median {100 * np.median(verr):.2f} %, p95 {100 * np.percentile(verr, 95):.2f} % "
              f"(median {np.median(vabs):.1f} px/s, p95 {np.percentile(vabs, 95):.1f} px/s)")
        print(f"  recall {100 * hit.mean():.2f} % (goal >= 99 %); false detections "
              f"{sum(r['false'] for r in sel) / span:.2f} /s")
        print(f"  speed {n_ev / t_tr / 1e6:.2f} Mev/s ({n_ev / t_tr / 1e7:.2f} x 10 Mev/s); "
              f"processing time / recorded time {t_tr / span:.2f}")
    print(f"\nball-free noise + hot pixels ({len(ev) / 0.3 / 1e6:.1f} Mev/s input, 1280x720): "
          f"{len(tr_noise) / 0.3:.2f} false detections/s, speed {len(ev) / t_noise / 1e6:.2f} Mev/s "
          f"({len(ev) / t_noise / 1e7:.2f} x 10 Mev/s)")
    # ball-free input with a walking player (the ball is parked off the sensor)
    for w, h in sensors:
        rec = sim.flight(radius_px=20, width=w, height=h, duration_s=0.1, start_px=(-1000.0, h / 2),
                         velocity_px_s=(0.0, 0.0), gravity_px_s2=0.0, rps=0, distractors=("player",),
                         noise_rate_hz=1.0, hot_pixels=30, seed=seed + 2)
        t0 = time.process_time()
        tr_p = track_ball(rec.events, width=w, height=h)
        t_p = time.process_time() - t0
        print(f"ball-free player + noise + hot pixels ({len(rec.events) / 0.1 / 1e6:.1f} Mev/s input, {w}x{h}): "
              f"{len(tr_p) / 0.1:.2f} false detections/s, speed {len(rec.events) / t_p / 1e6:.2f} Mev/s, "
              f"processing time / recorded time {t_p / 0.1:.2f}")


if __name__ == "__main__":
    main()
