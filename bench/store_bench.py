"""Session-store ingest: Mev/s written against bytes per event, per compressor, and decode + store.

Usage::

    PYTHONPATH=. python bench/store_bench.py [--events 16000000] [--repeat 3]

The events are the shared EVT3 recording tiled in time (as in ``bench/raw_bench.py``). Runs
are alternated so that the machine's background load hits all alike; best of ``--repeat``.

1. The store alone: a :class:`capture.session.SessionWriter` fed 512 Ki-event batches, for
   several compressor settings (``capture.session.EVENT_COMPRESSION``). The named peer in
   the same run is Zarr's own write path (the chunk encoder switched off: how this project
   stored events before), with the settings of that time (zstd level 1 on every column).
   Printed: Mev/s written, bytes per event on disk, Mev/s read back (``Session.events()``:
   through Zarr's read path for the peer, through the store's own chunk decoder for the rest).
2. Decode + store: ``capture.ingest.convert_raw`` of the same events as an EVT3 file, with
   the store behind the decoder (two threads) and, as the peer, the same with Zarr's write
   path; decoding alone (``capture.raw.read``) for scale.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

import capture.raw as raw
import capture.session as S
from capture.ingest import convert_raw

sys.path.insert(0, str(Path(__file__).resolve().parent))
from raw_bench import synthetic  # noqa: E402

SETTINGS = {
    "zstd1 all": {"t": ("zstd", 1), "x": ("zstd", 1), "y": ("zstd", 1), "p": ("zstd", 1)},
    "t lz4, zstd1": {"t": ("lz4", 5), "x": ("zstd", 1), "y": ("zstd", 1), "p": ("zstd", 1)},
    "lz4 all (default)": dict(S.EVENT_COMPRESSION),
    "zstd3 all": {"t": ("zstd", 3), "x": ("zstd", 3), "y": ("zstd", 3), "p": ("zstd", 3)},
}


@contextmanager
def configured(compression: dict, zarr_path: bool):
    """The store with ``compression`` and (``zarr_path``) Zarr's own chunk writing."""
    saved, fits = dict(S.EVENT_COMPRESSION), S._ChunkCodec.fits
    S.EVENT_COMPRESSION.clear()
    S.EVENT_COMPRESSION.update(compression)
    if zarr_path:
        S._ChunkCodec.fits = staticmethod(lambda arr: False)
    try:
        yield
    finally:
        S.EVENT_COMPRESSION.clear()
        S.EVENT_COMPRESSION.update(saved)
        S._ChunkCodec.fits = fits


def disk_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def store_once(events: np.ndarray, path: Path) -> float:
    shutil.rmtree(path, ignore_errors=True)
    t0 = time.perf_counter()
    with S.create_session(path, width=1280, height=720) as w:
        for i in range(0, len(events), 1 << 19):
            w.append_events(events[i:i + (1 << 19)])
    return time.perf_counter() - t0


def read_once(path: Path, events: np.ndarray) -> float:
    t0 = time.perf_counter()
    back = S.open_session(path).events()
    dt = time.perf_counter() - t0
    assert np.array_equal(back, events), "the store did not give the events back"
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=16_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src = synthetic("EVT3", args.events, tmp)
        events = raw.read(src).events
        n = len(events)
        print(f"{n / 1e6:.1f} Mev ({src.stat().st_size / n:.2f} B/ev as EVT3); best of {args.repeat}, alternated")

        runs = [(name, comp, False) for name, comp in SETTINGS.items()]
        runs.insert(0, ("Zarr's write path, zstd1 all (peer)", SETTINGS["zstd1 all"], True))
        best = {name: [np.inf, np.inf, 0] for name, _, _ in runs}
        for _ in range(args.repeat):
            for name, comp, zarr_path in runs:
                with configured(comp, zarr_path):
                    path = tmp / "s"
                    dt = store_once(events, path)
                    rd = read_once(path, events)
                    b = best[name]
                    b[0], b[1], b[2] = min(b[0], dt), min(b[1], rd), disk_bytes(path)
        print("\n1. the store alone (SessionWriter.append_events, 512 Ki-event batches)")
        peer = best[runs[0][0]][0]
        for name, (dt, rd, size) in best.items():
            print(f"  {name:38s} write {n / dt / 1e6:6.1f} Mev/s ({peer / dt:4.2f}x peer)  "
                  f"{size / n:5.2f} B/ev  read back {n / rd / 1e6:6.1f} Mev/s")

        print("\n2. decode + store (capture.ingest.convert_raw of the EVT3 file)")
        ingest = {"decode + store (default)": False, "decode + store, Zarr's write path (peer)": True}
        best_i = dict.fromkeys(ingest, np.inf)
        best_decode = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            raw.read(src)
            best_decode = min(best_decode, time.perf_counter() - t0)
            for name, zarr_path in ingest.items():
                comp = S.EVENT_COMPRESSION if not zarr_path else SETTINGS["zstd1 all"]
                with configured(dict(comp), zarr_path):
                    shutil.rmtree(tmp / "i", ignore_errors=True)
                    t0 = time.perf_counter()
                    convert_raw(src, tmp / "i", progress=False)
                    best_i[name] = min(best_i[name], time.perf_counter() - t0)
        print(f"  {'decoding alone (capture.raw.read)':42s} {n / best_decode / 1e6:6.1f} Mev/s")
        peer = best_i["decode + store, Zarr's write path (peer)"]
        for name, dt in best_i.items():
            print(f"  {name:42s} {n / dt / 1e6:6.1f} Mev/s ({peer / dt:4.2f}x peer)")


if __name__ == "__main__":
    main()
