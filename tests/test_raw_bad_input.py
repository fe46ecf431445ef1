"""Bad RAW input: clear errors naming file and byte offset, or partial decodes with damage counted."""

import warnings

import numpy as np
import pytest

import capture.raw as raw
from capture.events import make_events


@pytest.fixture(scope="module")
def evt3_file(tmp_path_factory):
    """A small EVT3 file we wrote: rows of vectors and single events, 2 s long."""
    rng = np.random.default_rng(11)
    n = 4000
    t = np.sort(rng.integers(0, 2_000_000, n))
    ev = make_events(t, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n))
    ev["t"][-64:] = ev["t"][-64]
    ev["y"][-64:], ev["p"][-64:], ev["x"][-64:] = 5, 1, np.arange(64)      # ends with two triplets
    path = tmp_path_factory.mktemp("bad") / "good.raw"
    raw.write(path, ev, width=640, height=480)
    return path, ev


def test_empty_file(tmp_path):
    path = tmp_path / "empty.raw"
    path.write_bytes(b"")
    with pytest.raises(raw.RawFormatError, match=r"empty\.raw: empty file"):
        raw.read(path)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.raw"):
        raw.read(tmp_path / "nope.raw")


def test_unknown_format_in_header(tmp_path):
    path = tmp_path / "evt4.raw"
    path.write_bytes(b"% date 2020\n% format EVT4;height=480;width=640\n% end\n" + bytes(100))
    with pytest.raises(raw.RawFormatError, match=r"evt4\.raw: byte 12: unknown event format 'EVT4'"):
        raw.read(path)
    with pytest.raises(raw.RawFormatError, match="unknown event format"):
        raw.StreamDecoder("EVT4")


def test_headerless_file_needs_format(tmp_path, evt3_file):
    path, ev = evt3_file
    data = path.read_bytes()
    bare = tmp_path / "bare.raw"
    bare.write_bytes(data[raw.parse_header(data)[1]:])
    with pytest.raises(raw.RawFormatError, match=r"bare\.raw: byte 0: the header does not name the event format"):
        raw.read(bare)
    r = raw.read(bare, format="EVT3", width=640, height=480)
    np.testing.assert_array_equal(r.events, ev)


def test_missing_geometry(tmp_path):
    path = tmp_path / "nogeo.raw"
    path.write_bytes(b"% evt 3.0\n" + np.array([0x8000], "<u2").tobytes())
    with pytest.raises(raw.RawFormatError, match="no sensor geometry"):
        raw.read(path)


def test_truncated_mid_word(tmp_path, evt3_file):
    path, ev = evt3_file
    data = path.read_bytes()
    cut = tmp_path / "cut.raw"
    cut.write_bytes(data[:-1])
    # the cut word is the VECT_8 of the last triplet: the group (from its VECT_BASE_X) is damaged
    with pytest.warns(raw.RawDamageWarning, match=rf"cut\.raw: damaged EVT3 data from byte {len(data) - 8}: "
                                                  r"trailing_bytes=1, incomplete_group_words=3"):
        r = raw.read(cut)
    # everything before the damage is kept (the cut word was the last V8 of the last triplet)
    np.testing.assert_array_equal(r.events, ev[:len(r.events)])
    assert len(r.events) >= len(ev) - 8
    with pytest.raises(raw.RawFormatError, match=rf"cut\.raw: damaged EVT3 data from byte {len(data) - 8}"):
        raw.read(cut, strict=True)


def test_truncated_mid_vector_group(tmp_path, evt3_file):
    path, ev = evt3_file
    data = path.read_bytes()
    cut = tmp_path / "cutgroup.raw"
    cut.write_bytes(data[:-4])         # drops the final VECT_12 + VECT_8 of the last triplet
    with pytest.warns(raw.RawDamageWarning, match=rf"from byte {len(data) - 8}: incomplete_group_words=2"):
        r = raw.read(cut)
    np.testing.assert_array_equal(r.events, ev[:len(r.events)])
    assert len(r.events) == len(ev) - 20   # x = 44..63 of the last row came from the cut words


def test_header_lying_about_format(tmp_path, evt3_file):
    path, ev = evt3_file
    data = path.read_bytes()
    size = raw.parse_header(data)[1]
    liar = tmp_path / "liar.raw"
    liar.write_bytes(raw.header_bytes("EVT2", width=640, height=480) + data[size:])
    with pytest.raises(raw.RawFormatError, match=r"liar\.raw: damaged EVT2 data from byte \d+"):
        raw.read(liar, strict=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", raw.RawDamageWarning)
        r = raw.read(liar)
    assert len(r.events) < len(ev)
    assert r.stats["unknown_words"] + r.stats["events_out_of_bounds"] > 0
    assert np.all(r.events["x"] < 640) and np.all(r.events["y"] < 480)


def test_garbage_payload(tmp_path):
    rng = np.random.default_rng(5)
    junk = rng.integers(0, 256, 50_000, dtype=np.uint8).tobytes()
    for fmt in ("EVT3", "EVT2", "EVT21"):
        path = tmp_path / f"junk_{fmt}.raw"
        path.write_bytes(raw.header_bytes(fmt, width=320, height=240) + junk)
        with pytest.warns(raw.RawDamageWarning, match=rf"junk_{fmt}\.raw: damaged {fmt} data from byte"):
            r = raw.read(path)
        assert np.all(r.events["x"] < 320) and np.all(r.events["y"] < 240)


def test_garbage_without_header(tmp_path):
    path = tmp_path / "noise.bin"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(raw.RawFormatError, match=r"noise\.bin: byte 0: the header does not name"):
        raw.read(path)


def test_bad_time_base_in_header(tmp_path):
    path = tmp_path / "tb.raw"
    path.write_bytes(raw.header_bytes("EVT3", width=64, height=64, time_base_us=12345) + bytes(4))
    with pytest.raises(raw.RawFormatError, match="not a multiple"):
        raw.read(path)


@pytest.mark.parametrize("field, match", [
    ("% format EVT3;height=1000000000;width=1000000000\n", r"bad geometry 1000000000x1000000000 in header \(event formats address 1\.\.2048"),
    ("% geometry 0x720\n", r"bad geometry 0x720"),
    (f"% format EVT3;height=64;width=64\n% time_base_us {1 << 63}\n", r"time_base_us=9223372036854775808 is outside 0\.\.2\^62 us"),
    ("% format EVT3;height=64;width=64\n% time_base_us -16777216\n", r"time_base_us=-16777216 is outside"),
])
def test_header_values_are_range_checked(tmp_path, field, match):
    path = tmp_path / "h.raw"
    path.write_bytes(field.encode() + b"% end\n" + bytes(8))
    with pytest.raises(raw.RawFormatError, match=match):
        raw.read(path)
    from capture.raw.cli import main
    assert main(["info", str(path)]) != 0  # one line, no traceback (checked in test_raw_cli for the form)


@pytest.mark.parametrize("fmt", ["EVT3", "EVT2"])
def test_flipped_time_low_bit_is_warned_not_silent(tmp_path, fmt):
    # A flipped bit in a time word sends events back in time (EVT3 TIME_LOW bit 11: 2 ms; EVT2
    # ts bit 5: 32 µs): counted and warned, like TIME_HIGH damage, never silent.
    n = 2000
    ev = make_events(np.arange(n) // 10 + 1000, np.arange(n) % 640, np.arange(n) % 480, np.arange(n) % 2)
    words = np.frombuffer(raw.encode(ev, format=fmt, width=640, height=480), "<u2" if fmt == "EVT3" else "<u4").copy()
    header = raw.header_bytes(fmt, width=640, height=480)
    good = tmp_path / "good.raw"
    good.write_bytes(header + words.tobytes())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert raw.read(good).stats["events_time_backward"] == 0
    if fmt == "EVT3":
        k = np.flatnonzero(((words >> 12) == 0x6) & ((words & 0x800) == 0))  # TIME_LOW words, bit 11 clear
        words[k[len(k) // 2]] |= 0x800
    else:
        k = np.flatnonzero(((words >> 28) <= 1) & ((words >> 27) & 1 == 0))  # CD words, ts bit 5 clear
        words[k[len(k) // 2]] |= 1 << 27
    bad = tmp_path / "flipped.raw"
    bad.write_bytes(header + words.tobytes())
    with pytest.warns(raw.RawDamageWarning, match=r"events_time_backward=\d+"):
        f = raw.read(bad)
    assert f.stats["events_time_backward"] > 0
