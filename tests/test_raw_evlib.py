"""Files we write decode identically in an independent decoder (evlib, test-only dependency)."""

import numpy as np
import pytest

import capture.raw as raw
from capture.events import make_events

evlib = pytest.importorskip("evlib")


def _evlib_arrays(path):
    df = evlib.load_events(str(path), sort=False).collect()
    return (df["t"].dt.total_microseconds().to_numpy(), df["x"].to_numpy(), df["y"].to_numpy(),
            df["polarity"].to_numpy())


def _check_same(path, events):
    t, x, y, pol = _evlib_arrays(path)
    time_base = int(raw.read(path).header["fields"].get("time_base_us", 0))  # evlib does not know it
    assert len(t) == len(events)
    np.testing.assert_array_equal(t, events["t"] - time_base)
    np.testing.assert_array_equal(x, events["x"])
    np.testing.assert_array_equal(y, events["y"])
    np.testing.assert_array_equal(pol > 0, events["p"] == 1)


@pytest.mark.parametrize("fmt", ["EVT3", "EVT2"])
def test_evlib_reads_our_files_of_real_data(shared_raw_dir, tmp_path, fmt):
    r = raw.read(shared_raw_dir / "expelliarmus_evt3_sample_1280x720.raw")   # dense rows: vectors
    path = tmp_path / f"real_{fmt}.raw"
    raw.write(path, r.events, r.triggers, format=fmt, width=r.width, height=r.height)
    _check_same(path, r.events)


@pytest.mark.parametrize("fmt", ["EVT3", "EVT2"])
def test_evlib_reads_our_synthetic_files(tmp_path, fmt):
    rng = np.random.default_rng(2)
    n = 30000
    t = np.cumsum(rng.integers(0, 40, n))
    t[5000:6000] = t[5000]
    ev = make_events(t, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n))
    ev["y"][5000:6000] = np.repeat(np.arange(10), 100)
    ev["x"][5000:6000] = np.tile(np.arange(100, 300, 2), 10)
    ev["x"][-1] = 639                          # a vector-free event at the right edge
    path = tmp_path / f"syn_{fmt}.raw"
    raw.write(path, ev, format=fmt, width=640, height=480)
    if fmt == "EVT3":
        words = np.frombuffer(path.read_bytes()[raw.parse_header(path.read_bytes())[1]:], "<u2")
        assert np.count_nonzero(words >> 12 == 0x3) >= 10
    _check_same(path, ev)
