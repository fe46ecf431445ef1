"""Long fuzz of the RAW decoders: mutated recordings, failures counted by kind.

    PYTHONPATH=. python bench/fuzz_raw.py --seconds 600 [--seed 1]

Each case takes the first ``--bytes`` of a recording in ``../shared/data/raw`` (or of a
simulated EVT2/EVT3 stream when that folder is missing), applies 1-6 random mutations (bit
flips, inserted / deleted / spliced bytes, truncation) and decodes it with ``capture.raw.read``
under a one-second alarm. Outcomes:

- ``ok``: decoded (with or without a damage warning);
- ``refused``: a :class:`capture.raw.RawFormatError` (a documented one-line error);
- ``crash``: any other exception (a failure);
- ``hang``: the alarm fired (a failure);
- ``unwarned_reversal``: events decoded with time going back and no damage warning (a failure).

Prints cases tried, cases per second and the count of each outcome, and the first failing case
of each kind (file, seed) so it can be replayed.
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

import capture.raw as raw

SHARED_RAW = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "raw"


class _Hang(Exception):
    pass


def _samples(n_bytes: int) -> list[tuple[str, bytes]]:
    files = sorted(SHARED_RAW.glob("*.raw")) if SHARED_RAW.is_dir() else []
    if files:
        return [(p.name, p.read_bytes()[:n_bytes]) for p in files]
    import sim

    rec = sim.flight(width=320, height=240, radius_px=20, duration_s=0.05, seed=0)
    out = []
    for fmt in ("EVT3", "EVT2"):
        data = raw.header_bytes(fmt, width=320, height=240) + raw.encode(rec.events, format=fmt, width=320, height=240)
        out.append((f"sim_{fmt}", data[:n_bytes]))
    return out


def _mutate(data: bytes, rng: np.random.Generator) -> bytes:
    buf = bytearray(data)
    for _ in range(int(rng.integers(1, 7))):
        kind = rng.choice(["flip", "flip", "flip", "insert", "delete", "truncate", "splice"])
        pos = int(rng.integers(0, len(buf) + 1))
        n = int(rng.integers(1, 65))
        if kind == "flip" and pos < len(buf):
            buf[pos] ^= 1 << int(rng.integers(0, 8))
        elif kind == "insert":
            buf[pos:pos] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        elif kind == "delete":
            del buf[pos:pos + n]
        elif kind == "truncate":
            del buf[pos:]
        elif kind == "splice":
            buf[pos:pos + n] = buf[:n]
    return bytes(buf)


def _one(path: Path) -> str:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            f = raw.read(path)
        except raw.RawFormatError:
            return "refused"
    t = f.events["t"]
    warned = any(issubclass(w.category, raw.RawDamageWarning) for w in caught)
    if len(t) > 1 and np.any(t[1:] < t[:-1]) and not warned:
        return "unwarned_reversal"
    return "ok"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="how long to fuzz (default 60)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--bytes", type=int, default=8192, help="bytes of each recording mutated (default 8192)")
    args = ap.parse_args(argv)
    samples = _samples(args.bytes)
    rng = np.random.default_rng(args.seed)
    counts: Counter = Counter()
    first: dict[str, str] = {}
    signal.signal(signal.SIGALRM, lambda *_: (_ for _ in ()).throw(_Hang()))
    t_end = time.monotonic() + args.seconds
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "case.raw"
        case = 0
        while time.monotonic() < t_end:
            name, data = samples[case % len(samples)]
            case_seed = int(rng.integers(1 << 62))
            path.write_bytes(_mutate(data, np.random.default_rng(case_seed)))
            signal.alarm(1)
            try:
                outcome = _one(path)
            except _Hang:
                outcome = "hang"
            except Exception as exc:  # noqa: BLE001 - counting what escapes is the point
                outcome = "crash"
                first.setdefault("crash", f"{name} seed {case_seed}: {type(exc).__name__}: {exc}")
            finally:
                signal.alarm(0)
            counts[outcome] += 1
            if outcome in ("hang", "unwarned_reversal"):
                first.setdefault(outcome, f"{name} seed {case_seed}")
            case += 1
    dt = time.monotonic() - t0
    failures = counts["crash"] + counts["hang"] + counts["unwarned_reversal"]
    print(f"{case} cases in {dt:.0f} s ({case / dt:.0f} cases/s) over {len(samples)} recordings, seed {args.seed}")
    for kind in ("ok", "refused", "crash", "hang", "unwarned_reversal"):
        print(f"  {kind:18s} {counts[kind]:8d}" + (f"   first: {first[kind]}" if kind in first else ""))
    print(f"failures: {failures}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
