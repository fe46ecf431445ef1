"""Fuzz: mutated real recordings fed to every decoder never hang or crash (hypothesis, bounded)."""

import io
import warnings
from functools import lru_cache

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import capture.raw as raw
from capture.events import EVENT_DTYPE, TRIGGER_DTYPE
from tests.conftest import SHARED
from tests.raw_cases import FILES

DECODERS = [("EVT3", "little"), ("EVT2", "little"), ("EVT21", "little"), ("EVT21", "legacy")]


@lru_cache
def _sample(i: int) -> bytes:
    """The first 6 KiB of a shared recording (header included)."""
    return (SHARED / "data" / "raw" / FILES[i]).read_bytes()[:6144]


mutation = st.tuples(st.sampled_from(["flip", "insert", "delete", "truncate", "splice"]),
                     st.integers(0, 6143), st.integers(0, 255), st.integers(1, 64))


def _mutate(data: bytes, ops) -> bytes:
    buf = bytearray(data)
    for kind, pos, value, length in ops:
        pos = pos % (len(buf) + 1)
        if kind == "flip" and pos < len(buf):
            buf[pos] ^= value or 1
        elif kind == "insert":
            buf[pos:pos] = bytes([value]) * length
        elif kind == "delete":
            del buf[pos:pos + length]
        elif kind == "truncate":
            del buf[pos:]
        elif kind == "splice":
            buf[pos:pos + length] = buf[:length]
    return bytes(buf)


def _check(events, triggers, width, height):
    assert events.dtype == EVENT_DTYPE and triggers.dtype == TRIGGER_DTYPE
    if width is not None and len(events):
        assert events["x"].max() < width and events["y"].max() < height


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(file_index=st.integers(0, max(len(FILES) - 1, 0)), ops=st.lists(mutation, max_size=6),
       decoder=st.sampled_from(DECODERS), chunk=st.one_of(st.integers(1, 3), st.integers(64, 3000)),
       geometry=st.booleans(),
       shift=st.booleans())
def test_stream_decoders_survive_mutated_real_data(file_index, ops, decoder, chunk, geometry, shift):
    if not FILES:
        return
    data = _mutate(_sample(file_index), ops)
    if chunk < 8:
        data = data[:600]                 # byte-by-byte feeding: keep it short
    fmt, order = decoder
    w, h = (640, 480) if geometry else (None, None)
    dec = raw.StreamDecoder(fmt, endianness=order, width=w, height=h, time_shift=shift)
    n, times = 0, [np.zeros(0, np.int64)]  # a file truncated to nothing feeds no chunk
    for i in range(0, len(data), chunk):
        ev, tr = dec.decode(data[i:i + chunk])
        _check(ev, tr, w, h)
        n += len(ev)
        times.append(ev["t"])
    dec.finish()
    stats = dec.stats
    assert stats["events"] == n
    t = np.concatenate(times)
    if np.any(t[1:] < t[:-1]):  # time going back is never silent
        assert stats["events_time_backward"] > 0 and dec.damaged
    assert stats["words"] == len(data) // dec.word_bytes


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(file_index=st.integers(0, max(len(FILES) - 1, 0)), ops=st.lists(mutation, min_size=1, max_size=4),
       chunk=st.integers(1, 5000))
def test_file_reader_on_mutated_files_raises_only_documented_errors(file_index, ops, chunk):
    if not FILES:
        return
    data = _mutate(_sample(file_index), ops)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", raw.RawDamageWarning)
            batches = list(raw.iter_chunks(io.BytesIO(data), chunk_bytes=chunk))
    except raw.RawFormatError as exc:
        assert str(exc).startswith("<stream>: ")      # names the source (and the byte, where known)
        return
    for ev, tr in batches:
        _check(ev, tr, None, None)
