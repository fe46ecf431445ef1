"""Spin benchmark cases: simulated ball windows over textures, rates, motion, lens and sensor.

One case is one window of events of one spinning ball with its ground truth.  A row is
``(texture, rps, motion, lens, sensor)``; its cases differ by seed, which draws the
spin axis, the ball's radius (12-100 px), the event budget of the window (20k, 60k or
150k events, at most 20 ms: so windows cover anything from a few degrees to several
turns), the image velocity (translating: 1,500-6,000 px/s) and the ball's place on
the 1280x720 sensor (perspective: 0-25 deg off the optical axis, focal 600 px).

Seeds 0, 1, 2, ... form the tuning set; :data:`HELD_OUT_SEED0` onwards the held-out set,
never looked at while tuning.  Cases are cached on disk (``.npz`` per case) so that
reruns cost only the estimates.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

import sim
from calib.intrinsics import Intrinsics

WIDTH, HEIGHT = 1280, 720
FOCAL_PX = 600.0
HELD_OUT_SEED0 = 1000
TEXTURES = ("volleyball", "soccer", "basketball", "tennis", "logo", "baseball", "tabletennis")
# 8 rps: a float serve or a knuckle ball, whose image drifts faster than its rim turns (spin.fast.BLUR_SHIFT_FROM_DRIFT)
RATES_RPS = (8, 30, 200, 800, 1200)
MOTIONS = ("still", "translating")
LENSES = ("orthographic", "perspective")
SENSORS = ("ideal", "realistic")
EVENT_BUDGETS = (20_000, 60_000, 150_000)
MAX_WINDOW_S = 0.02
CACHE_VERSION = 1


def camera() -> Intrinsics:
    """The benchmark's event camera: 1280x720, focal 600 px, principal point at the centre, no distortion."""
    k = np.array([[FOCAL_PX, 0.0, (WIDTH - 1) / 2.0], [0.0, FOCAL_PX, (HEIGHT - 1) / 2.0], [0.0, 0.0, 1.0]])
    return Intrinsics(K=k, dist=np.zeros(5), width=WIDTH, height=HEIGHT)


def draw(row: tuple, seed: int) -> dict:
    """The random parameters of case ``seed`` of ``row`` (same row and seed: same case)."""
    texture, rps, motion, lens, sensor = row
    key = int.from_bytes(hashlib.sha256(repr((texture, rps, motion, lens, sensor)).encode()).digest()[:4], "little")
    rng = np.random.default_rng([key, seed])
    a = rng.normal(size=3)
    axis = a / np.linalg.norm(a)
    radius = float(np.exp(rng.uniform(np.log(12.0), np.log(100.0))))
    budget = int(rng.choice(EVENT_BUDGETS))
    speed = float(rng.uniform(1500.0, 6000.0)) if motion == "translating" else 0.0
    heading = rng.uniform(0, 2 * np.pi)
    velocity = (speed * np.cos(heading), speed * np.sin(heading))
    travel = speed * MAX_WINDOW_S
    margin = radius + 0.5 * travel + 4.0
    cx0, cy0 = (WIDTH - 1) / 2.0, (HEIGHT - 1) / 2.0
    for _ in range(1000):
        if lens == "perspective":
            off = np.radians(rng.uniform(0.0, 25.0))
            phi = rng.uniform(0, 2 * np.pi)
            centre = (cx0 + FOCAL_PX * np.tan(off) * np.cos(phi), cy0 + FOCAL_PX * np.tan(off) * np.sin(phi))
        else:
            off = 0.0
            centre = (rng.uniform(0, WIDTH - 1), rng.uniform(0, HEIGHT - 1))
        # start half the travel behind the middle: the window stays on the sensor
        start = (centre[0] - 0.5 * velocity[0] * MAX_WINDOW_S, centre[1] - 0.5 * velocity[1] * MAX_WINDOW_S)
        if margin <= centre[0] <= WIDTH - 1 - margin and margin <= centre[1] <= HEIGHT - 1 - margin:
            break
    return {"axis": axis, "radius_px": radius, "n_events": budget, "velocity_px_s": velocity, "center": start,
            "off_axis_deg": float(np.degrees(off)), "sim_seed": int(rng.integers(1 << 30))}


def _cache_path(cache_dir: Path, row: tuple, seed: int) -> Path:
    name = "_".join(str(x) for x in row) + f"_s{seed}_v{CACHE_VERSION}.npz"
    return cache_dir / name


def make_case(row: tuple, seed: int, cache_dir: str | os.PathLike | None = None) -> tuple[np.ndarray, dict]:
    """Events (EVENT_DTYPE) and truth of one case, from the cache when there.

    Truth: ``axis`` (3,), ``omega_rad_s``, ``rps``, ``center`` (2,) px and ``radius_px`` at the first
    event (perspective: the image of the sphere centre and ``f tan(angular radius)``, the
    simulator's convention), ``velocity_px_s`` (2,), ``off_axis_deg``, ``n_events``, ``span_us``.
    """
    texture, rps, motion, lens, sensor = row
    path = None if cache_dir is None else _cache_path(Path(cache_dir), row, seed)
    if path is not None and path.exists():
        with np.load(path, allow_pickle=False) as f:
            events = f["events"]
            truth = {k[6:]: (f[k] if f[k].ndim else f[k].item()) for k in f.files if k.startswith("truth_")}
        return events, truth
    p = draw(row, seed)
    kw = dict(projection="pinhole", focal_px=FOCAL_PX) if lens == "perspective" else {}
    events, t = sim.spinning_ball(texture, rps=rps, axis=p["axis"], radius_px=p["radius_px"], center=p["center"],
                                  velocity_px_s=p["velocity_px_s"], width=WIDTH, height=HEIGHT,
                                  n_events=p["n_events"], duration_s=MAX_WINDOW_S, seed=p["sim_seed"], sensor=sensor,
                                  **kw)
    truth = {"axis": np.asarray(t["axis"], float), "omega_rad_s": float(t["omega_rad_s"]), "rps": float(t["rps"]),
             "center": np.asarray(t["center"], float), "radius_px": float(t["radius_px"]),
             "velocity_px_s": np.asarray(t["velocity_px_s"], float), "off_axis_deg": p["off_axis_deg"],
             "n_events": int(len(events)),
             "span_us": int(events["t"][-1] - events["t"][0]) if len(events) else 0}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, events=events, **{f"truth_{k}": v for k, v in truth.items()})
        os.replace(tmp, path)
    return events, truth


def rows(textures=TEXTURES, rates=RATES_RPS, motions=MOTIONS, lenses=LENSES, sensors=SENSORS) -> list[tuple]:
    """Every row ``(texture, rps, motion, lens, sensor)`` of the matrix."""
    return [(tx, r, m, le, se) for tx in textures for r in rates for m in motions for le in lenses for se in sensors]
