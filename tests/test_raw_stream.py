"""StreamDecoder / iter_chunks: any chunking of the byte stream gives the arrays of one call."""

import io
import json

import numpy as np
import pytest

import capture.raw as raw
from capture.events import make_events, make_triggers
from tests.raw_cases import FILES


def _concat(batches):
    ev = [b[0] for b in batches]
    tr = [b[1] for b in batches]
    return np.concatenate(ev), np.concatenate(tr)


def _decode_chunks(fmt, payload, sizes, **kw):
    dec = raw.StreamDecoder(fmt, **kw)
    out, pos = [], 0
    for n in sizes:
        out.append(dec.decode(payload[pos:pos + n]))
        pos += n
    out.append(dec.decode(payload[pos:]))
    dec.finish()
    return (*_concat(out), dec)


@pytest.fixture(scope="module")
def whole(shared_raw_dir):
    return {name: raw.read(shared_raw_dir / name) for name in FILES}


def test_real_usb_packet_chunking(shared_raw_dir, whole):
    name = "ros_codecs_evt3_trigger_1280x720.raw"
    exp = json.loads((shared_raw_dir / "expected.json").read_text())["files"][name]
    data = (shared_raw_dir / name).read_bytes()
    payload = data[exp["header_bytes"]:]
    sizes = exp["chunk_sizes_bytes"]
    assert sum(sizes) == len(payload)
    ev, tr, dec = _decode_chunks("EVT3", payload, sizes, width=1280, height=720)
    np.testing.assert_array_equal(ev, whole[name].events)
    np.testing.assert_array_equal(tr, whole[name].triggers)
    assert dec.stats == whole[name].stats


@pytest.mark.parametrize("name", FILES)
def test_random_chunkings(shared_raw_dir, whole, name):
    r = whole[name]
    data = (shared_raw_dir / name).read_bytes()
    payload = data[raw.parse_header(data)[1]:]
    rng = np.random.default_rng(len(payload))
    for sizes in (rng.integers(1, 4000, size=len(payload) // 1000),          # random, odd splits
                  rng.integers(1, 3, size=min(len(payload), 4000))):         # 1-2 byte chunks at the start
        ev, tr, dec = _decode_chunks(r.format, payload, sizes.tolist(), width=r.width, height=r.height)
        np.testing.assert_array_equal(ev, r.events)
        np.testing.assert_array_equal(tr, r.triggers)
        assert not dec.damaged


def test_splits_inside_every_vector_word_of_a_group(shared_raw_dir, whole):
    """Cut the EVT3 stream right after every word of the first vector groups."""
    name = "expelliarmus_evt3_sample_1280x720.raw"
    data = (shared_raw_dir / name).read_bytes()
    payload = data[raw.parse_header(data)[1]:]
    words = np.frombuffer(payload, "<u2")
    vec = np.flatnonzero(np.isin(words >> 12, (3, 4, 5)))[:24]
    for cut_word in vec:
        for extra in (0, 1):  # after the word, or in its middle
            cut = 2 * int(cut_word) + 1 + extra
            ev, tr, _ = _decode_chunks("EVT3", payload, [cut], width=1280, height=720)
            np.testing.assert_array_equal(ev, whole[name].events)


def test_iter_chunks_file_object_and_byte_iterator(shared_raw_dir, whole):
    name = "expelliarmus_evt2_sparklers_640x480.raw"
    data = (shared_raw_dir / name).read_bytes()
    for source in (shared_raw_dir / name, io.BytesIO(data),
                   (data[i:i + 777] for i in range(0, len(data), 777))):
        batches = list(raw.iter_chunks(source, chunk_bytes=50_001))
        assert len(batches) > 1
        ev, tr = _concat(batches)
        np.testing.assert_array_equal(ev, whole[name].events)
    # header split into 1-byte pieces
    batches = list(raw.iter_chunks([data[i:i + 1] for i in range(300)] + [data[300:]]))
    np.testing.assert_array_equal(_concat(batches)[0], whole[name].events)


def test_reader_exposes_header_and_stats(shared_raw_dir):
    reader = raw.RawReader(shared_raw_dir / "ros_codecs_evt3_trigger_1280x720.raw", chunk_bytes=100_000)
    n = sum(len(ev) for ev, _ in reader)
    assert reader.header["format"] == "EVT3" and reader.header_size == 72
    assert n == reader.decoder.stats["events"] == 82469
    assert reader.decoder.stats["others"] == 15688 + 25024 + 12512


def test_one_big_call_equals_small_chunks():
    """A decode() call of 1.4 M words gives the same arrays as many small calls."""
    rng = np.random.default_rng(9)
    n = 700_000
    t = np.cumsum(rng.integers(0, 3, n))
    ev = make_events(t, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n))
    tr = make_triggers(t[::100_000], np.arange(7), np.arange(7) % 2)
    data = raw.encode(ev, tr, format="EVT3", width=640, height=480)
    whole = raw.StreamDecoder("EVT3", width=640, height=480, time_shift=True).decode(data)
    dec = raw.StreamDecoder("EVT3", width=640, height=480, time_shift=True)
    parts = [dec.decode(data[i:i + 65537]) for i in range(0, len(data), 65537)]
    np.testing.assert_array_equal(whole[0], _concat(parts)[0])
    np.testing.assert_array_equal(whole[1], _concat(parts)[1])
    np.testing.assert_array_equal(whole[0]["t"] + dec.time_shift_us, ev["t"])
