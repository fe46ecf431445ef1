"""Ball detection/tracking benchmark on simulated flights.

Usage::

    PYTHONPATH=. python bench/detect_bench.py [--quick] [--seed N]

Each case is a scene rendered by the simulator (``sim.scene`` + ``sim.esim``):
a textured court background, a volleyball of radius ``r`` px flying across the
sensor at an image-equivalent speed (m/s scaled by ``r / 0.105 m``) under image
gravity, with or without spin, a player-like distractor walking through, noise
events and hot pixels; optionally camera frames (120 fps, 1 ms exposure, rendered
by the same scene) fused with the events. ``detect.track_ball`` tracks it and
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

from detect import track_ball
from sim.balls import make_ball
from sim.esim import SensorState, merge, noise_events, simulate
from sim.rotation import random_rotation
from sim.scene import Camera, Player, Scene, court_background

VOLLEYBALL_RADIUS_M = 0.105
GRAVITY_M_S2 = 9.81


def make_case(width, height, radius_px, speed_mps, rps, seed, duration_s, frames_fps=0.0):
    """Simulated events (+ frames) and the ball object for one case."""
    rng = np.random.default_rng(seed)
    cam = Camera(width, height)
    px_per_m = radius_px / VOLLEYBALL_RADIUS_M
    v = speed_mps * px_per_m
    ang = np.deg2rad(rng.uniform(-20, 20))
    vel = (v * np.cos(ang), -v * np.sin(ang))
    g = GRAVITY_M_S2 * px_per_m
    dur = min(duration_s, (width - 2 * radius_px - 10) / max(vel[0], 1.0))
    y0 = height / 2 - vel[1] * dur / 2
    ball = make_ball(cam, texture="volleyball", radius_px=radius_px, center_px=(radius_px + 4.0, y0),
                     velocity_px_s=vel, accel_px_s2=(0.0, g), axis=rng.normal(size=3),
                     omega_rad_s=2 * np.pi * rps, R0=random_rotation(rng))
    player = Player(x0=width * 0.6, y0=height - 10.0, vx=-300.0, height_px=0.8 * height)
    scene = Scene(cam, [player, ball], background=court_background(width, height, rng))
    ev = simulate(scene, SensorState.new(width, height, rng), 0.0, dur)
    noise, _ = noise_events(width, height, 0, int(dur * 1e6), rng, rate_hz_per_px=1.0, hot_pixels=30)
    ev = merge(ev, noise)
    frames, t_frames = [], []
    if frames_fps:
        v_pix, u_pix = np.divmod(np.arange(width * height), width)
        for tf in np.arange(0.5 / frames_fps, dur, 1.0 / frames_fps):
            ts = tf + np.linspace(-0.5e-3, 0.5e-3, 5)
            img = scene.render(u_pix.astype(float), v_pix.astype(float), ts, bg=scene.sensor_background()).mean(0)
            frames.append(np.clip(img.reshape(height, width) * 255, 0, 255).astype(np.uint8))
            t_frames.append(int(round(tf * 1e6)))
    return ev, cam, ball, dur, frames, t_frames


def evaluate(tr, cam, ball, span_us, width, height):
    """Errors of track ``tr`` against the ball's true circle."""
    r_true = ball.circle(cam, [0.0])[0, 2]
    tol = max(2.0, 0.25 * r_true)
    samples = np.arange(span_us[0] + 1000, span_us[1] - 1000, 2000)
    c = ball.circle(cam, samples * 1e-6)
    inside = (c[:, 0] - c[:, 2] >= 0) & (c[:, 1] - c[:, 2] >= 0) & (c[:, 0] + c[:, 2] <= width - 1) & \
             (c[:, 1] + c[:, 2] <= height - 1)
    samples = samples[inside]
    out = dict(err=np.zeros(0), rerr=np.zeros(0), verr=np.zeros(0), vabs=np.zeros(0), hit=np.zeros(len(samples), bool), false=0)
    if len(tr) == 0:
        return out
    c = ball.circle(cam, tr.t_us * 1e-6)
    v = ball.image_velocity(cam, tr.t_us * 1e-6)
    err = np.hypot(tr.cx - c[:, 0], tr.cy - c[:, 1])
    good = err <= tol
    out["false"] = int((~good).sum())
    out["err"], out["rerr"] = err[good], np.abs(tr.r - c[:, 2])[good]
    out["verr"] = (np.hypot(tr.vx - v[:, 0], tr.vy - v[:, 1]) / np.hypot(v[:, 0], v[:, 1]))[good]
    out["vabs"] = np.hypot(tr.vx - v[:, 0], tr.vy - v[:, 1])[good]
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
                    ev, cam, ball, dur, frames, t_frames = make_case(w, h, r, s, rps, seed, duration_s,
                                                                     frames_fps=120.0 if with_frames else 0.0)
                    t0 = time.process_time()
                    tr = track_ball(ev, width=w, height=h, frames=frames or None,
                                    frame_times_us=t_frames or None)
                    t_track = time.process_time() - t0
                    res = evaluate(tr, cam, ball, (int(ev["t"][0]), int(ev["t"][-1])), w, h)
                    res.update(n_events=len(ev), span_s=dur, t_track=t_track, n_flights=len(tr.flight_ids()))
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


if __name__ == "__main__":
    main()
