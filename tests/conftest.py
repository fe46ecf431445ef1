"""Shared test fixtures: where the shared real recordings live; a simulated ball crossing the sensor twice; two
balls crossing it at once."""

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"
"""The ``shared/`` folder that sits beside the repository checkout."""


@pytest.fixture(scope="session")
def shared_raw_dir() -> Path:
    """``../shared/data/raw``: real Prophesee recordings with ``expected.json``."""
    d = SHARED / "data" / "raw"
    if not (d / "expected.json").is_file():
        pytest.skip(f"shared test recordings not found at {d}")
    return d


@pytest.fixture(scope="session")
def two_crossings():
    """A small ball (r = 12 px, 480x320) crossing the sensor left to right within 40 ms, then
    again from 70 ms: two ``sim.flight`` recordings."""
    import sim

    common = dict(radius_px=12, width=480, height=320, duration_s=0.04, rps=20, distractors=(), noise_rate_hz=1.0,
                  hot_pixels=10)
    a = sim.flight(start_px=(-6.0, 150.0), velocity_px_s=(13_000.0, -1500.0), seed=11, **common)
    b = sim.flight(start_px=(-6.0, 220.0), velocity_px_s=(13_000.0, -2500.0), seed=12, t0_us=70_000, **common)
    return a, b


@pytest.fixture(scope="session")
def two_balls_at_once():
    """Two small balls (r = 12 and 10 px, 480x320) crossing the sensor at the same time within 40 ms,
    one left to right, the other right to left, passing over each other mid-way: two ``sim.flight``
    recordings."""
    import sim

    common = dict(width=480, height=320, duration_s=0.04, rps=20, distractors=(), noise_rate_hz=1.0, hot_pixels=10)
    a = sim.flight(radius_px=12, start_px=(-6.0, 150.0), velocity_px_s=(13_000.0, 500.0), seed=31, **common)
    b = sim.flight(radius_px=10, start_px=(485.0, 170.0), velocity_px_s=(-12_500.0, -500.0), seed=32, **common)
    return a, b
