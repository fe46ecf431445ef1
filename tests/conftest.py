"""Shared test fixtures: where the shared real recordings live."""

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
