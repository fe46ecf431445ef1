"""The built-in demo's inputs: a simulated rally served by the fake EVK and the fake GoPro.

:func:`demo_devices` simulates a volleyball flight with a known spin (``sim.rally``),
writes its events as an EVT3 RAW file and its frames as an MP4, and yields recorder
settings whose devices are the fake EVK (a pyusb backend streaming the RAW file) and
the fake GoPro (a loopback HTTP server serving the MP4). ``python -m capture.run --demo``
records them exactly as live devices (:mod:`capture.pipeline.record`), analyses the
session (:mod:`capture.pipeline.replay`) and prints the estimate beside the truth
(:func:`spin_summary`).
"""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

import sim
from capture.evk.fake import FakeEVK
from capture.gopro import FakeGoPro, GoPro
from capture.pipeline.record import RecordSettings
from capture.events import BALL_DIAMETER_M

DEMO_SPIN = {"rps": 30.0, "axis": (0.0, 0.0, -1.0)}
"""Spin of the demo ball: 30 rev/s of topspin for a ball flying to the right (+x)."""
DEMO_DURATION_S: float | None = None
"""Length of the demo rally, s (None: ``sim.rally``'s)."""


def make_demo_files(folder, *, seed: int = 0, duration_s: float | None = None,
                    quiet: bool = False) -> tuple[Path, Path, dict]:
    """Simulate the demo rally into ``folder``: ``(raw_path, mp4_path, truth)``.

    ``duration_s`` shortens the rally (default: ``sim.rally``'s).
    """
    if not quiet:
        print("Simulating a volleyball rally (events, 120 fps frames, sync box)...", flush=True)
    kw = {} if duration_s is None else {"duration_s": duration_s}
    rec = sim.rally(seed=seed, **DEMO_SPIN, **kw)
    paths = rec.save(folder, raw=True, video=True)
    return paths["raw"], paths["video"], rec.truth


@contextlib.contextmanager
def demo_devices(out, *, viewer: str = "none", speed: str = "recorded", quiet: bool = False,
                 seed: int = 0) -> Iterator[tuple[RecordSettings, dict]]:
    """Recorder settings for the demo rally on the fake devices, and the simulator's truth.

    Yields ``(settings, truth)`` while the fake GoPro serves the rally's video; the simulated
    files are removed afterwards. ``speed`` is the fake EVK's pace (``recorded`` or ``max``).
    """
    with tempfile.TemporaryDirectory(prefix="courtside-demo-") as tmp:
        raw_path, mp4_path, truth = make_demo_files(tmp, seed=seed, duration_s=DEMO_DURATION_S, quiet=quiet)
        with FakeGoPro(mp4_path) as fake_gopro:
            settings = RecordSettings(
                out=Path(out), backend=FakeEVK(raw_path, pace=speed), viewer=viewer, quiet=quiet,
                gopro=GoPro(host=fake_gopro.host, port=fake_gopro.port),
                gopro_settings={"resolution": "1080", "fps": 120},
                led_roi=tuple(truth["sync"]["led_box_px"]),  # the exposure comes from the video's GPMF
                attrs={"ball": {"type": "volleyball", "diameter_m": BALL_DIAMETER_M["volleyball"]},
                       "demo": {"truth_rps": float(truth["rps"]),
                                "truth_axis": [float(v) for v in truth["axis"]],
                                "truth_frame_t_us": [int(v) for v in truth["frames"]["t_us"]]}})
            yield settings, truth


def _axis_error_deg(a, b) -> float:
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def spin_summary(spin: dict, truth: dict, min_confidence: float = 0.5) -> dict:
    """Median estimate over confident spin windows, with its errors against the truth and the windows'
    median uncertainty (1 sigma, ``rps_sigma_pct`` %, ``axis_sigma_deg`` deg)."""
    ok = np.asarray(spin["confidence"]) >= min_confidence
    if not ok.any():
        return {"n_windows": len(spin["rps"]), "n_confident": 0}
    axis = np.median(np.asarray(spin["axis"])[ok], axis=0)
    axis /= np.linalg.norm(axis)
    rps = float(np.median(np.asarray(spin["rps"])[ok]))
    return {"n_windows": len(spin["rps"]), "n_confident": int(ok.sum()), "rps": rps, "axis": axis,
            "axis_error_deg": _axis_error_deg(axis, truth["axis"]),
            "rps_error_pct": 100.0 * abs(rps - truth["rps"]) / truth["rps"],
            "rps_sigma_pct": float(np.nanmedian(np.asarray(spin["rps_sigma_pct"], dtype=float)[ok])),
            "axis_sigma_deg": float(np.nanmedian(np.asarray(spin["axis_sigma_deg"], dtype=float)[ok]))}
