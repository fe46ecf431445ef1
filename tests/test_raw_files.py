"""capture.raw on the shared real recordings: every value in expected.json, headers, read/write."""

import hashlib
import json

import numpy as np
import pytest

import capture.raw as raw
from capture.events import EVENT_DTYPE, TRIGGER_DTYPE, make_events, make_triggers
from tests.raw_cases import FILES, FILES_WITH_NPY


@pytest.fixture(scope="module")
def expected(shared_raw_dir):
    return json.loads((shared_raw_dir / "expected.json").read_text())["files"]




@pytest.fixture(scope="module")
def decoded(shared_raw_dir):
    return {name: raw.read(shared_raw_dir / name) for name in FILES}


@pytest.mark.parametrize("name", FILES)
def test_header(shared_raw_dir, expected, name):
    e = expected[name]
    data = (shared_raw_dir / name).read_bytes()
    header, size = raw.parse_header(data, source=name)
    assert size == e["header_bytes"]
    assert (header["format"], header["width"], header["height"]) == (e["format"], e["width"], e["height"])
    assert [f"{k} {v}".strip() for k, v in header["fields"].items()] == [
        line for line in e["header_lines"] if line != "end"]
    assert header["style"] == ("modern" if "end" in e["header_lines"] else "legacy")


@pytest.mark.parametrize("name", FILES)
def test_every_expected_value(decoded, expected, name):
    e = expected[name]
    r = decoded[name]
    assert r.events.dtype == EVENT_DTYPE and r.triggers.dtype == TRIGGER_DTYPE
    assert (r.format, r.width, r.height) == (e["format"], e["width"], e["height"])
    ev, cd = r.events, e["cd"]
    assert len(ev) == cd["count"]
    assert int(np.count_nonzero(ev["p"] == 1)) == cd["positive_p1"]
    assert int(np.count_nonzero(ev["p"] == 0)) == cd["negative_p0"]
    assert (int(ev["t"][0]), int(ev["t"][-1])) == (cd["t_first_us"], cd["t_last_us"])
    assert bool(np.all(np.diff(ev["t"]) >= 0)) == cd["t_nondecreasing"]
    rows = lambda a: [[int(v["t"]), int(v["x"]), int(v["y"]), int(v["p"])] for v in a]
    assert rows(ev[:5]) == cd["first5_t_x_y_p"]
    assert rows(ev[-5:]) == cd["last5_t_x_y_p"]
    assert int(ev["t"].sum()) == cd["sum_t_us"]
    assert int(ev["x"].sum(dtype=np.int64)) == cd["sum_x"]
    assert int(ev["y"].sum(dtype=np.int64)) == cd["sum_y"]
    assert [int(ev["x"].min()), int(ev["x"].max())] == cd["x_min_max"]
    assert [int(ev["y"].min()), int(ev["y"].max())] == cd["y_min_max"]
    digest = lambda a: hashlib.sha3_224(a.tobytes()).hexdigest()
    d = cd["sha3_224_of_field_arrays"]
    assert digest(ev["t"].astype("<u8")) == d["t_uint64_le"]
    assert digest(ev["x"].astype("<u2")) == d["x_uint16_le"]
    assert digest(ev["y"].astype("<u2")) == d["y_uint16_le"]
    assert digest(ev["p"].astype(bool)) == d["p_bool"]
    trig = e["ext_trigger"]
    assert len(r.triggers) == trig["count"]
    if trig["count"]:
        assert [[int(v["t"]), int(v["id"]), int(v["p"])] for v in r.triggers[:5]] == trig["first5_t_id_value"]
        assert sorted(set(r.triggers["id"].tolist())) == trig["ids"]
        assert {str(k): int(np.count_nonzero(r.triggers["p"] == int(k))) for k in trig["value_counts"]} == \
            trig["value_counts"]
    assert r.stats["events"] == cd["count"]
    assert r.stats["words_before_time_high"] == 0
    assert r.stats["words"] == sum(e["word_type_counts"].values())


@pytest.mark.parametrize("name", FILES)
def test_independent_references(decoded, expected, name):
    """Values published by other projects (event_camera_codecs sums in ns, faery digests...)."""
    r = decoded[name]
    for ref in expected[name]["independent_references"]:
        values = ref["values"]
        if not ref["match"] or not isinstance(values, dict):
            continue
        if "n_events" in values:
            assert len(r.events) == values["n_events"]
        if "sum_cd_t_ns" in values:
            assert int(r.events["t"].sum()) * 1000 == values["sum_cd_t_ns"]
            assert int(r.events["p"].sum()) == values["sum_cd_p"]
            assert int(r.triggers["t"].sum()) * 1000 == values["sum_trigger_t_ns"]
            assert int(r.triggers["p"].sum()) == values["sum_trigger_edge"]
            assert int(r.triggers["id"].sum()) == values["sum_trigger_id"]
        if "first_event_t_x_y_p" in values:
            v = r.events[0]
            assert [int(v["t"]), int(v["x"]), int(v["y"]), int(v["p"])] == values["first_event_t_x_y_p"]


@pytest.mark.parametrize("name", FILES_WITH_NPY)
def test_expelliarmus_npy_xyp(shared_raw_dir, decoded, expected, name):
    for ref_name in expected[name]["reference_files"]:
        ref = np.load(shared_raw_dir / ref_name)
        ev = decoded[name].events
        assert len(ref) == len(ev)
        for c in ("x", "y", "p"):
            np.testing.assert_array_equal(ref[c].astype(np.int64), ev[c].astype(np.int64))


@pytest.mark.parametrize("name", FILES)
def test_metavision_time_shift(shared_raw_dir, decoded, expected, name):
    ref = expected[name]["metavision_default_time_shift_us_derived"]
    shifted = raw.read(shared_raw_dir / name, time_shift=True)
    assert shifted.time_shift_us == ref["shift_us"]
    assert int(shifted.events["t"][0]) == ref["first_cd_t_after_shift_us"]
    np.testing.assert_array_equal(shifted.events["t"], decoded[name].events["t"] - ref["shift_us"])
    np.testing.assert_array_equal(shifted.triggers["t"], decoded[name].triggers["t"] - ref["shift_us"])


@pytest.mark.parametrize("fmt", ["EVT3", "EVT2"])
@pytest.mark.parametrize("name", FILES)
def test_write_read_round_trip_real(tmp_path, decoded, name, fmt):
    r = decoded[name]
    path = tmp_path / f"out_{fmt}.raw"
    raw.write(path, r.events, r.triggers, format=fmt, width=r.width, height=r.height, serial_number="x1")
    back = raw.read(path)
    assert (back.format, back.width, back.height) == (fmt, r.width, r.height)
    assert back.header["fields"]["serial_number"] == "x1"
    np.testing.assert_array_equal(back.events, r.events)
    np.testing.assert_array_equal(back.triggers, r.triggers)
    assert not any(back.stats[k] for k in ("events_without_y", "unknown_words", "events_out_of_bounds"))


def test_evt3_writer_uses_vectors_when_they_save_bytes():
    # one row of 32 ON events at the same t: a vector triplet (4 words) beats 32 ADDR_X words
    ev = make_events(np.full(32, 5000), np.arange(64, 96), np.full(32, 7), np.ones(32))
    words = np.frombuffer(raw.encode(ev, format="EVT3", width=640, height=480), "<u2")
    types = (words >> 12).tolist()
    assert types == [0x8, 0x6, 0x0, 0x3, 0x4, 0x4, 0x5]
    assert int(words[3] & 0x7FF) == 64 and int(words[3] >> 11) & 1 == 1
    # four events: ADDR_X words are smaller than a triplet
    few = ev[:4]
    words = np.frombuffer(raw.encode(few, format="EVT3", width=640, height=480), "<u2")
    assert (words >> 12).tolist() == [0x8, 0x6, 0x0, 0x2, 0x2, 0x2, 0x2]


def test_evt3_writer_vectors_near_right_edge_stay_inside_sensor():
    # events at x = 630..639 on a 640-wide sensor: the triplet base must be <= 640 - 32
    ev = make_events(np.full(10, 9), np.arange(630, 640), np.full(10, 3), np.zeros(10))
    words = np.frombuffer(raw.encode(ev, format="EVT3", width=640, height=480), "<u2")
    base = [int(w & 0x7FF) for w in words if w >> 12 == 0x3]
    assert base == [608]
    dec = raw.StreamDecoder("EVT3", width=640, height=480)
    out, _ = dec.decode(words.tobytes())
    np.testing.assert_array_equal(out, ev)


def test_header_bytes_round_trip():
    data = raw.header_bytes("EVT21", width=1280, height=720, endianness="legacy", serial_number="00050423")
    header, size = raw.parse_header(data + b"\x00\x01")
    assert size == len(data) and data.endswith(b"% end\n")
    assert (header["format"], header["width"], header["height"], header["endianness"]) == ("EVT21", 1280, 720, "legacy")
    assert header["fields"]["serial_number"] == "00050423"
    assert header["fields"]["format"] == "EVT21;endianness=legacy;height=720;width=1280"
    with pytest.raises(ValueError, match="one printable ASCII line"):
        raw.header_bytes("EVT3", width=640, height=480, note="two\nlines")


@pytest.mark.parametrize("lines, geometry", [
    (b"% evt 3.0\n% system_ID 49\n", (1280, 720)),
    (b"% evt 2.0\n% plugin_name hal_plugin_gen31_evk3\n", (640, 480)),
    (b"% evt 3.0\n% plugin_name hal_plugin_genx320_evk3\n", (320, 320)),
    (b"% evt 3.0\n% geometry 304x240\n% end\n", (304, 240)),
    (b"% evt 3.0\n", (None, None)),
])
def test_legacy_geometry_inference(lines, geometry):
    header, size = raw.parse_header(lines + b"\x00\x80")
    assert (header["width"], header["height"]) == geometry
    assert size == len(lines)


def test_legacy_header_stops_at_binary_word_starting_with_percent():
    # an EVT3 TIME_HIGH word 0x8025 is stored as bytes 25 80: starts with '%' but is not a line
    data = b"% evt 3.0\n% system_ID 48\n" + bytes([0x25, 0x80, 0x00, 0x60])
    header, size = raw.parse_header(data)
    assert size == len(data) - 4 and header["format"] == "EVT3"


def test_trigger_only_and_empty_inputs_round_trip(tmp_path):
    tr = make_triggers([10, 20_000_000], [3, 3], [1, 0])
    path = tmp_path / "t.raw"
    raw.write(path, make_events([], [], [], []), tr, width=640, height=480)
    back = raw.read(path)
    assert len(back.events) == 0
    np.testing.assert_array_equal(back.triggers, tr)
