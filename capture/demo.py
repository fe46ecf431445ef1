"""The built-in demo: a simulated rally recorded through the fake EVK and the fake GoPro.

``python -m capture.run --demo --out DIR`` simulates a volleyball flight with a
known spin (``sim.rally``), writes its events as an EVT3 RAW file and its frames
as an MP4, then records them exactly as live devices would be recorded: the RAW
file is streamed by the fake EVK (a pyusb backend), the MP4 is served by the
fake GoPro (a loopback HTTP server), and the recorder, the time sync, the
detection and the spin estimation run unchanged. It ends by printing the
estimated spin beside the truth.
"""

from __future__ import annotations

import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

DEMO_SPIN = {"rps": 30.0, "axis": (0.0, 0.0, -1.0)}
"""Spin of the demo ball: 30 rev/s of topspin for a ball flying to the right (+x)."""


def make_demo_files(folder, *, seed: int = 0, duration_s: float | None = None,
                    quiet: bool = False) -> tuple[Path, Path, dict]:
    """Simulate the demo rally into ``folder``: ``(raw_path, mp4_path, truth)``.

    ``duration_s`` shortens the rally (default: ``sim.rally``'s).
    """
    import sim

    if not quiet:
        print("Simulating a volleyball rally (events, 120 fps frames, sync box)...", flush=True)
    kw = {} if duration_s is None else {"duration_s": duration_s}
    rec = sim.rally(seed=seed, **DEMO_SPIN, **kw)
    paths = rec.save(folder, raw=True, video=True)
    return paths["raw"], paths["video"], rec.truth


def _axis_error_deg(a, b) -> float:
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def spin_summary(spin: dict, truth: dict, min_confidence: float = 0.5) -> dict:
    """Median estimate over confident spin windows, with its errors against the truth."""
    ok = np.asarray(spin["confidence"]) >= min_confidence
    if not ok.any():
        return {"n_windows": len(spin["rps"]), "n_confident": 0}
    axis = np.median(np.asarray(spin["axis"])[ok], axis=0)
    axis /= np.linalg.norm(axis)
    rps = float(np.median(np.asarray(spin["rps"])[ok]))
    return {"n_windows": len(spin["rps"]), "n_confident": int(ok.sum()), "rps": rps, "axis": axis,
            "axis_error_deg": _axis_error_deg(axis, truth["axis"]),
            "rps_error_pct": 100.0 * abs(rps - truth["rps"]) / truth["rps"]}


def run_demo(out, *, viewer: str = "none", speed: str = "recorded", quiet: bool = False,
             analyse: bool = True, stop: threading.Event | None = None, seed: int = 0,
             duration_s: float | None = None) -> int:
    """Run the demo end to end into session directory ``out``; returns the exit code."""
    from capture.evk.fake import FakeEVK
    from capture.gopro import FakeGoPro, GoPro
    from capture.run import RecordSettings, print_summary, record_session

    with tempfile.TemporaryDirectory(prefix="courtside-demo-") as tmp:
        raw_path, mp4_path, truth = make_demo_files(tmp, seed=seed, duration_s=duration_s, quiet=quiet)
        with FakeGoPro(mp4_path) as fake_gopro:
            settings = RecordSettings(
                out=Path(out), backend=FakeEVK(raw_path, pace=speed), viewer=viewer, quiet=quiet,
                analyse=analyse, gopro=GoPro(host=fake_gopro.host, port=fake_gopro.port),
                gopro_settings={"resolution": "1080", "fps": 120},
                led_roi=tuple(truth["sync"]["led_box_px"]), exposure_s=float(truth["frames"]["exposure_s"]),
                attrs={"demo": {"truth_rps": float(truth["rps"]),
                                "truth_axis": [float(v) for v in truth["axis"]],
                                "truth_frame_t_us": [int(v) for v in truth["frames"]["t_us"]]}})
            result = record_session(settings, stop)
    print_summary(result)
    if result.replay is not None:
        s = spin_summary(result.replay.spin, truth)
        print(f"True spin:      {truth['rps']:7.1f} rps, axis ({', '.join(f'{v:+.3f}' for v in truth['axis'])})")
        if s["n_confident"]:
            print(f"Estimated spin: {s['rps']:7.1f} rps, axis ({', '.join(f'{v:+.3f}' for v in s['axis'])})  "
                  f"median of {s['n_confident']} confident windows of {s['n_windows']}")
            print(f"Error:          {s['rps_error_pct']:.2f} % in rps, {s['axis_error_deg']:.2f} deg in axis")
        else:
            print(f"Estimated spin: no confident estimate in {s['n_windows']} windows")
    if result.error:
        print(f"capture.run: error: {result.error} (session {out} kept)", file=sys.stderr)
        return 1
    return 0
