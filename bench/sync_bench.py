"""Clock sync error against the simulator's truth, by where the GoPro's exposure comes from.

    PYTHONPATH=. python bench/sync_bench.py [--fps 60 120 240] [--seeds 2]

For each frame rate and each of two set-ups, a simulated flight with a sync box (LED in the
frames, wired to the EVK trigger input) is written as an MP4 carrying GPMF (as a GoPro writes
it, and as the fake camera serves it), with a frame-clock offset and drift:

- ``periodic, fixed``: a box blinking every 50 ms (a multiple of the frame period: every edge
  at one phase against the frames) and one exposure of 1/(3 fps) for the clip;
- ``random, auto``: a box whose pulses start at pseudo-random times (``SyncBox(jitter_s=...)``)
  and auto-exposure: the exposure swings between 1/(5 fps) and 1/(2 fps) over the clip, each
  exposure ending on the frame cadence as a camera reads its frames.

The sync-box fit (``calib.sync.fit_sync_box``) then runs with the exposure

- ``gpmf``: each frame's, read from the clip's GPMF (``SHUT``; what ``capture.ingest.attach_video``
  does when ``--exposure`` is not typed),
- ``gpmf median``: the median of the GPMF values, one for the clip (what it did before),
- ``estimated``: left to the fit (the exposure that best explains the LED edges),
- ``wrong``: a fixed exposure of one frame period (a user typing the wrong value),

the LED (8 px in a 320 x 240 frame, beside a moving player) found in the frames as ingest finds it,

and prints the largest error of the stored frame times (each exposure's centre on the event
clock, ``calib.store.frame_times_us``) against the truth (µs), the fit's own 1-sigma (largest
over the seeds), and the largest ratio of a clip's error to its own sigma.

``--activity``: the activity method (no sync box) on clips of tuning seeds 1-3 and held-out
seeds 101-103: its largest error against its sigma.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from calib.store import frame_times_us
from calib.sync import fit_activity, fit_sync_box, frame_difference_energy, led_brightness, refine_led_roi
from capture.gopro import gpmf, read_video
from capture.gopro.mp4 import gpmf_samples

LED = (4, 4, 12, 12)


SETUPS = ("periodic, fixed", "random, auto")


def one(fps: float, seed: int, tmp: Path, setup: str) -> dict:
    from sim import SyncBox, flight

    if setup == "periodic, fixed":
        box = SyncBox(period_s=0.05, pulse_s=0.013, phase_s=0.007, led_box_px=LED)
        exposure = 1.0 / (3.0 * fps)
    else:
        box = SyncBox(period_s=0.05, pulse_s=0.013, phase_s=0.007, led_box_px=LED, jitter_s=0.03, seed=seed)

        def exposure(t_s):  # auto-exposure: a light level changing over the clip
            return (0.35 + 0.15 * np.sin(2 * np.pi * t_s / 0.5)) / fps

    rec = flight(width=320, height=240, radius_px=18, duration_s=0.6, fps=fps, exposure_s=exposure, sync=box,
                 frame_clock_offset_s=12.345, frame_clock_drift_ppm=40.0, seed=seed)
    video_path = rec.save(tmp / f"{fps:g}_{seed}_{setup[:4]}", raw=False, video=True)["video"]
    v = read_video(video_path)
    truth_us = np.asarray(rec.truth["frames"]["t_us"], np.float64)  # each exposure's centre
    e_med = float(np.median(rec.truth["frames"]["exposure_s"]))
    energy = frame_difference_energy(img[16:] for _, _, img in v.frames(gray=True))
    coarse = fit_activity(rec.events["t"], v.t_s, energy, exposure_s=e_med)
    b, roi = led_brightness(v.frames(gray=True))  # the LED found in the frames, as ingest finds it
    b, roi = refine_led_roi(v.frames(gray=True), roi)
    meta = gpmf.frame_metadata(*gpmf_samples(video_path))
    per_frame = meta.exposure_at(v.t_s - v.t_s[0])
    exposures = {"gpmf": per_frame, "gpmf median": float(np.median(per_frame)), "estimated": None,
                 "wrong": 1.0 / fps}
    out = {}
    for name, e in exposures.items():
        tmap, e_used = fit_sync_box(b, v.t_s, rec.triggers, exposure_s=e, channel=0, prior=coarse)
        err = np.abs(frame_times_us(v.t_s, tmap, exposure_s=e if name == "gpmf" else e_used) - truth_us)
        out[name] = (float(err.max()), float(tmap.sigma_us(v.t_s).max()), e_used)
    return out


def activity(fps: float, seed: int, tmp: Path) -> tuple[float, float]:
    """Largest stored-frame-time error (µs) and the fit's sigma of the activity method (no sync
    box: event activity against frame motion) on a 0.6 s clip."""
    from sim import flight

    exposure = 1.0 / (2.0 * fps)
    rec = flight(width=320, height=240, radius_px=18, duration_s=0.6, fps=fps, exposure_s=exposure,
                 frame_clock_offset_s=12.345, frame_clock_drift_ppm=40.0, seed=seed)
    video_path = rec.save(tmp / f"a{fps:g}_{seed}", raw=False, video=True)["video"]
    v = read_video(video_path)
    energy = frame_difference_energy(img for _, _, img in v.frames(gray=True))
    tmap = fit_activity(rec.events["t"], v.t_s, energy, exposure_s=exposure)
    err = np.abs(frame_times_us(v.t_s, tmap, exposure_s=exposure) - rec.truth["frames"]["t_us"])
    return float(err.max()), float(tmap.sigma_us(v.t_s).max())


def main_activity(fps_list, seed_sets) -> None:
    print(f"{'fps':>5} {'seeds':>9} {'max err us':>11} {'sigma us':>9} {'max err/sigma':>13} {'within 1 sigma':>14}")
    with tempfile.TemporaryDirectory() as tmp:
        for fps in fps_list:
            for label, seeds in seed_sets:
                rows = [activity(fps, seed, Path(tmp)) for seed in seeds]
                ratio = [e / s for e, s in rows]
                print(f"{fps:5.0f} {label:>9} {max(e for e, _ in rows):11.0f} {max(s for _, s in rows):9.0f} "
                      f"{max(ratio):13.2f} {sum(r <= 1 for r in ratio):9d} of {len(rows)}", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fps", type=float, nargs="+", default=[60.0, 120.0, 240.0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--activity", action="store_true",
                    help="the activity method instead (no sync box): error against its sigma on tuning "
                         "seeds 1-3 and held-out seeds 101-103")
    args = ap.parse_args(argv)
    if args.activity:
        main_activity(args.fps, [("tuning", (1, 2, 3)), ("held-out", (101, 102, 103))])
        return
    print(f"{'fps':>5} {'set-up':>16} {'exposure from':>14} {'max err us':>11} {'sigma us':>9} {'max err/sigma':>13} "
          f"{'exposure used ms':>17}")
    with tempfile.TemporaryDirectory() as tmp:
        for fps in args.fps:
            for setup in SETUPS:
                rows = [one(fps, seed, Path(tmp), setup) for seed in range(args.seeds)]
                for name in rows[0]:
                    worst = max(r[name][0] for r in rows)
                    sigma = max(r[name][1] for r in rows)
                    ratio = max(r[name][0] / r[name][1] for r in rows)  # each clip's error against its own sigma
                    used = np.mean([r[name][2] for r in rows])
                    print(f"{fps:5.0f} {setup:>16} {name:>14} {worst:11.1f} {sigma:9.1f} {ratio:13.2f} {used * 1e3:17.3f}",
                          flush=True)


if __name__ == "__main__":
    main()
