"""Synthetic datasets on disk: ``python -m sim.dataset --preset paper OUT``.

Presets
-------
paper
    The paper's protocol: volleyball at 10, 20, 30, 50, 100, 200, 300, 500 rps and
    soccer ball at 100 rps, ``--n`` sequences each with uniformly random spin axes,
    640x480, contrast threshold 0.15, static 100 px ball, ``--n-events`` events.
flights
    ``--n`` ballistic volleyball flights across 1280x720 with court background,
    noise, hot pixels, a walking player and a second ball, 120 fps frames and sync
    triggers; spin 2-15 rps about random axes.
flights640
    As ``flights`` on a 640x480 sensor (ball radius 20-30 px).
rally
    One demo recording (:func:`sim.rally`).

Every sequence goes to its own folder (``events.raw``, ``truth.json``, ``frames.mp4``
when there are frames); ``OUT/index.json`` lists them with their main parameters.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from capture import cliargs
from capture.events import TRIGGER_DTYPE
from .balls import spinning_ball
from .flight import flight, rally
from .recording import Recording, jsonable
from .rotation import random_axes

PAPER_VOLLEYBALL_RPS = (10, 20, 30, 50, 100, 200, 300, 500)
PAPER_SOCCER_RPS = (100,)
PRESETS = ("paper", "flights", "flights640", "rally")


def paper_specs(n: int, seed: int) -> list[dict]:
    """Parameters of the paper preset's sequences (texture, rps, axis, seed, name)."""
    rng = np.random.default_rng(seed)
    specs = []
    for texture, rps_list in (("volleyball", PAPER_VOLLEYBALL_RPS), ("soccer", PAPER_SOCCER_RPS)):
        for rps in rps_list:
            for i, axis in enumerate(random_axes(rng, n)):
                specs.append({"name": f"{texture}_{rps:03d}rps_{i:02d}", "texture": texture, "rps": float(rps),
                              "axis": axis, "seed": int(rng.integers(2**31))})
    return specs


def flight_specs(n: int, seed: int, width: int, height: int, radius_range) -> list[dict]:
    """Parameters of the flight presets' sequences."""
    rng = np.random.default_rng(seed)
    return [{"name": f"flight_{i:03d}", "rps": float(rng.uniform(2, 15)), "axis": random_axes(rng, 1)[0],
             "radius_px": float(rng.uniform(*radius_range)), "duration_s": float(rng.uniform(0.25, 0.4)),
             "width": width, "height": height, "seed": int(rng.integers(2**31))} for i in range(n)]


def generate(preset: str, out_dir, *, n: int = 10, seed: int = 0, n_events: int = 60000,
             session: bool = False, progress=None) -> list[dict]:
    """Write a preset's sequences under ``out_dir``; returns the index entries."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {PRESETS}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    index = []
    if preset == "paper":
        for spec in paper_specs(n, seed):
            ev, truth = spinning_ball(spec["texture"], rps=spec["rps"], axis=spec["axis"], radius_px=100,
                                      width=640, height=480, n_events=n_events, seed=spec["seed"], threshold=0.15)
            rec = Recording(ev, np.zeros(0, TRIGGER_DTYPE), 640, 480, truth)
            rec.save(out / spec["name"], session=session)
            index.append({**spec, "n_events": int(ev.size)})
            if progress:
                progress(spec["name"])
    elif preset in ("flights", "flights640"):
        big = preset == "flights"
        specs = flight_specs(n, seed, 1280 if big else 640, 720 if big else 480, (30, 40) if big else (20, 30))
        for spec in specs:
            kw = {k: v for k, v in spec.items() if k != "name"}
            rec = flight(distractors=("player", "ball"), fps=120.0, sync=True, **kw)
            rec.save(out / spec["name"], session=session)
            index.append({**spec, "n_events": int(rec.events.size)})
            if progress:
                progress(spec["name"])
    else:
        rec = rally(seed=seed)
        rec.save(out / "rally", session=session)
        index.append({"name": "rally", "seed": seed, "n_events": int(rec.events.size)})
    (out / "index.json").write_text(json.dumps(jsonable({"preset": preset, "seed": seed, "sequences": index}),
                                               indent=1))
    return index


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m sim.dataset`` command line."""
    ap = argparse.ArgumentParser(prog="python -m sim.dataset", description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="output directory")
    ap.add_argument("--preset", choices=PRESETS, default="paper")
    ap.add_argument("--n", type=cliargs.positive_int, default=10,
                    help="sequences per setting (paper) or flights (default 10)")
    ap.add_argument("--n-events", type=int, default=60000, help="events per paper sequence (default 60000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--session", action="store_true", help="also write a Zarr session store per sequence")
    ap.add_argument("--quiet", action="store_true", help="no per-sequence progress lines")
    return ap


def main(argv=None) -> int:
    """Write a dataset (see the module docstring); returns the exit code (0 ok, 1 error)."""
    ap = build_parser()
    args = ap.parse_args(argv)

    def body() -> None:
        t0 = time.perf_counter()
        progress = None if args.quiet else lambda name: print(f"  {name}", file=sys.stderr)
        index = generate(args.preset, args.out, n=args.n, seed=args.seed, n_events=args.n_events,
                         session=args.session, progress=progress)
        print(f"{len(index)} sequences in {args.out} ({time.perf_counter() - t0:.1f} s)")

    return cliargs.run_command(ap.prog, body)


if __name__ == "__main__":
    sys.exit(main())
