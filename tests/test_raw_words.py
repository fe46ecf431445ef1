"""Decoders on hand-built words: layouts, time wrap, vectors, triggers, EVT 2.1 both byte orders."""

import numpy as np
import pytest

import capture.raw as raw
from capture.events import make_events, make_triggers


def evt3(*words):
    return np.array(words, "<u2").tobytes()


def decode(fmt, data, **kw):
    dec = raw.StreamDecoder(fmt, **kw)
    ev, tr = dec.decode(data)
    dec.finish()
    return ev, tr, dec.stats


def rows(ev):
    return [tuple(int(v) for v in e) for e in ev]


def test_evt3_spec_examples():
    ev, _, _ = decode("EVT3", evt3(0x8ABC, 0x6123, 0x0005, 0x2801))
    assert rows(ev) == [(0xABC123, 1, 5, 1)]
    ev, _, _ = decode("EVT3", evt3(0x8001, 0x6002, 0x0009, 0x3100, 0x4FFF, 0x4001, 0x5080, 0x2805))
    t = (1 << 12) | 2
    assert rows(ev) == [(t, x, 9, 0) for x in [*range(256, 268), 268, 287]] + [(t, 5, 9, 1)]


def test_evt3_vector_base_keeps_advancing_without_new_base():
    # two triplets after one VECT_BASE_X: the second starts at base + 32
    ev, _, _ = decode("EVT3", evt3(0x8000, 0x6000, 0x0001, 0x3840, 0x4001, 0x4000, 0x5000,
                                   0x4001, 0x4000, 0x5080))
    assert rows(ev) == [(0, 64, 1, 1), (0, 96, 1, 1), (0, 127, 1, 1)]


def test_evt3_time_high_wrap_and_jitter():
    words = evt3(0x8FFE, 0x6FF0, 0x0002, 0x2003,      # t = 0xFFEFF0
                 0x8FFF, 0x6001, 0x2004,              # t = 0xFFF001
                 0x8000, 0x6005, 0x2005,              # wrap: t = 2^24 + 5
                 0x8001, 0x2006,                      # new TIME_HIGH resets TIME_LOW: 2^24 + 0x1000
                 0x8000, 0x6007, 0x2007,              # small step back: jitter, not a wrap
                 0x8001, 0x6008, 0x2008)
    ev, _, stats = decode("EVT3", words)
    w = 1 << 24
    assert ev["t"].tolist() == [0xFFEFF0, 0xFFF001, w + 5, w + 0x1000, w + 7, w + 0x1008]
    assert stats["time_loops"] == 1 and stats["time_backward"] == 1


def test_evt3_repeated_time_high_keeps_time_low():
    ev, _, _ = decode("EVT3", evt3(0x8002, 0x6050, 0x0001, 0x8002, 0x2001, 0x8003, 0x2002))
    assert ev["t"].tolist() == [0x2050, 0x3000]


def test_evt3_many_wraps_count_loops():
    # TIME_HIGH 0..4095 three times over, 1024 apart: three loops
    th = np.tile(np.arange(0, 4096, 1024), 3) | 0x8000
    words = np.stack([th, np.full_like(th, 0x0001), np.full_like(th, 0x2000)], axis=1).ravel()
    ev, _, stats = decode("EVT3", words.astype("<u2").tobytes())
    expected = np.arange(12) * (1024 << 12)
    assert ev["t"].tolist() == expected.tolist()
    assert stats["time_loops"] == 2


def test_evt3_drops_words_before_first_time_high():
    ev, _, stats = decode("EVT3", evt3(0x0003, 0x2001, 0x6123, 0x8010, 0x2002))
    # the ADDR_Y before the TIME_HIGH is dropped too, so the event after it has no y
    assert len(ev) == 0
    assert stats["words_before_time_high"] == 3 and stats["events_without_y"] == 1


def test_evt3_system_type_bit_drops_other_camera():
    ev, _, stats = decode("EVT3", evt3(0x8000, 0x0805, 0x2001, 0x2002, 0x0005, 0x2003))
    assert rows(ev) == [(0, 3, 5, 0)]
    assert stats["events_other_system"] == 2
    assert stats["events_without_y"] == 0


def test_a_dropped_event_is_counted_once_for_its_first_reason():
    # x 100 is outside a 64-pixel sensor, but the event has no row yet / is another camera's
    ev, _, stats = decode("EVT3", evt3(0x8000, 0x2064, 0x0805, 0x2064, 0x0005, 0x2064, 0x2003), width=64, height=64)
    assert rows(ev) == [(0, 3, 5, 0)]
    assert (stats["events_without_y"], stats["events_other_system"], stats["events_out_of_bounds"]) == (1, 1, 1)


def test_streams_denser_than_one_event_per_word_decode_whole():
    # Full rows in vector groups (8 events per word) and a trigger after each: the decoder's
    # first output arrays (one event per word, a few triggers) fill up and it carries on.
    n_rows, width = 200, 1280
    t = np.repeat(np.arange(n_rows) * 7, width)
    ev = make_events(t, np.tile(np.arange(width), n_rows), np.repeat(np.arange(n_rows) % 720, width), t % 2)
    tr = make_triggers(np.arange(n_rows) * 7, np.arange(n_rows) % 16, np.arange(n_rows) % 2)
    data = raw.encode(ev, tr, format="EVT3", width=width, height=720)
    assert len(ev) > 7 * len(data) // 2 and len(tr) > 64
    for step in (len(data), 4096, 1000):
        dec = raw.StreamDecoder("EVT3", width=width, height=720)
        parts = [dec.decode(data[i:i + step]) for i in range(0, len(data), step)]
        np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), ev)
        np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), tr)
    # EVT 2.1: 32 events per word (rows of (mask, header) after a TIME_HIGH)
    words = np.tile(np.array([[0xFFFFFFFF, cd2(0, 0, 3, 1)]], "<u4"), (5000, 1))
    ev21, _, stats = decode("EVT21", evt2(0, 0x8 << 28) + words.tobytes(), width=32, height=4)
    assert ev21["x"].tolist() == list(range(32)) * 5000 and not stats["events_out_of_bounds"]


def test_evt3_triggers_and_others_groups():
    words = evt3(0x8001, 0x6010, 0xA801, 0xE014, 0xF123, 0xF456, 0x7003,   # trigger id 8 rising, OTHERS group
                 0x0002, 0x2804, 0xEFFF,                                   # OTHERS with no continuation
                 0x6011, 0xA000, 0xE016, 0xF001)                           # trigger; group cut short
    ev, tr, stats = decode("EVT3", words)
    assert rows(ev) == [(0x1010, 4, 2, 1)]
    assert rows(tr) == [(0x1010, 8, 1), (0x1011, 0, 0)]
    assert stats["others"] == 7 and not any(stats[k] for k in ("unknown_words", "incomplete_group_words"))


def test_evt3_time_shift():
    words = evt3(0x8003, 0x6005, 0x0001, 0x2002, 0xA001)
    ev, tr, _ = decode("EVT3", words, time_shift=True)
    assert ev["t"].tolist() == [(1 << 12) + 5] and tr["t"].tolist() == [(1 << 12) + 5]
    ev, _, _ = decode("EVT3", evt3(0x8000, 0x6005, 0x0001, 0x2002), time_shift=True)
    assert ev["t"].tolist() == [5]   # first TIME_HIGH 0: no shift


def evt2(*words):
    return np.array(words, "<u4").tobytes()


def cd2(t, x, y, p, typ=None):
    return ((p if typ is None else typ) << 28) | ((t & 63) << 22) | (x << 11) | y


def test_evt2_words_wrap_and_trigger():
    top = (1 << 28) - 1
    data = evt2(cd2(0, 1, 1, 1),                        # before the first TIME_HIGH: skipped
                (8 << 28) | top, cd2(5, 639, 479, 1), cd2(63, 0, 0, 0),
                (0xA << 28) | (7 << 22) | (17 << 8) | 1,  # trigger channel 17 rising
                (8 << 28) | 0, cd2(1, 2, 3, 0),           # 28-bit wrap
                (0xE << 28) | 0x14, (0xF << 28) | 99)     # OTHERS / CONTINUED
    ev, tr, stats = decode("EVT2", data)
    assert rows(ev) == [((top << 6) | 5, 639, 479, 1), ((top << 6) | 63, 0, 0, 0), ((1 << 34) | 1, 2, 3, 0)]
    assert rows(tr) == [((top << 6) | 7, 17, 1)]
    assert stats["words_before_time_high"] == 1 and stats["time_loops"] == 1 and stats["others"] == 2


def evt21_words(events, triggers, order):
    """EVT 2.1 words built by hand from the layout: one 64-bit word per (t, y, p, 32-px block)."""
    out = []
    th = None
    items = sorted([(int(e["t"]), 0, i) for i, e in enumerate(events)] +
                   [(int(t["t"]), 1, i) for i, t in enumerate(triggers)])
    i = 0
    while i < len(items):
        t, kind, k = items[i]
        if t >> 6 != th:
            th = t >> 6
            out.append(((8 << 28) | (th & 0x0FFFFFFF), 0))
        if kind == 1:
            trig = triggers[k]
            out.append(((0xA << 28) | ((t & 63) << 22) | (int(trig["id"]) << 8) | int(trig["p"]), 0))
            i += 1
            continue
        e = events[k]
        x0, y, p = int(e["x"]) // 32 * 32, int(e["y"]), int(e["p"])
        mask = 0
        while i < len(items) and items[i][1] == 0:
            f = events[items[i][2]]
            if (int(f["t"]), int(f["y"]), int(f["p"])) != (t, y, p) or not x0 <= int(f["x"]) < x0 + 32 \
                    or (mask >> (int(f["x"]) - x0)) != 0:
                break
            mask |= 1 << (int(f["x"]) - x0)
            i += 1
        out.append(((p << 28) | ((t & 63) << 22) | (x0 << 11) | y, mask))
    pairs = np.array(out, np.uint64).reshape(-1, 2).astype("<u4")
    if order == "little":
        pairs = pairs[:, ::-1]
    return np.ascontiguousarray(pairs).tobytes()


@pytest.mark.parametrize("order", ["little", "legacy"])
def test_evt21_hand_built_round_trip_both_byte_orders(order):
    rng = np.random.default_rng(7)
    n = 3000
    t = np.sort(rng.integers(0, 5_000_000, n))
    t[100:400] = t[100]                             # a burst sharing one timestamp
    ev = make_events(t, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n))
    ev["x"][100:400], ev["y"][100:400], ev["p"][100:400] = np.arange(0, 600, 2), 10, 1   # one row
    tr = make_triggers(np.sort(rng.integers(0, 5_000_000, 5)), [0, 1, 2, 31, 4], [1, 0, 1, 0, 1])
    data = evt21_words(ev, tr, order)
    head = np.frombuffer(data, "<u4").reshape(-1, 2)[:, 1 if order == "little" else 0]
    assert np.count_nonzero(head >> 28 <= 1) < n - 250     # the row really was vectorised
    out, trig, stats = decode("EVT21", data, endianness=order, width=640, height=480)
    # vectors come out in x order within each (t, y, p) block: compare as multisets per t
    np.testing.assert_array_equal(np.sort(out, order=["t", "y", "p", "x"]), np.sort(ev, order=["t", "y", "p", "x"]))
    np.testing.assert_array_equal(trig, tr)
    wrong = "legacy" if order == "little" else "little"
    bad, _, stats = decode("EVT21", data, endianness=wrong, width=640, height=480)
    assert len(bad) != len(ev) or not np.array_equal(bad, out)
    # any chunking gives the same arrays
    dec = raw.StreamDecoder("EVT21", endianness=order, width=640, height=480)
    cuts = np.sort(rng.integers(0, len(data), 300))
    parts = [dec.decode(data[a:b]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(data)])]
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), out)


def test_evt21_mask_layout_single_word():
    head = (1 << 28) | (5 << 22) | (64 << 11) | 7
    mask = (1 << 0) | (1 << 3) | (1 << 31)
    th = (8 << 28) | 2
    little = np.array([[0, th], [mask, head]], "<u4").tobytes()
    legacy = np.array([[th, 0], [head, mask]], "<u4").tobytes()
    for order, data in (("little", little), ("legacy", legacy)):
        ev, _, _ = decode("EVT21", data, endianness=order)
        assert rows(ev) == [((2 << 6) | 5, 64, 7, 1), ((2 << 6) | 5, 67, 7, 1), ((2 << 6) | 5, 95, 7, 1)]


def test_evt3_encoder_random_round_trip_with_chunking():
    rng = np.random.default_rng(3)
    n = 20000
    t = np.cumsum(rng.integers(0, 3000, n)) + (5 << 24) + 17       # crosses several wraps
    t[1000:2000] = t[1000]
    ev = make_events(t, rng.integers(0, 1280, n), rng.integers(0, 720, n), rng.integers(0, 2, n))
    # a burst: 10 rows of 100 events at one t, x increasing with gaps (some windows too sparse)
    ev["y"][1000:2000] = np.repeat(np.arange(10), 100)
    ev["p"][1000:2000] = 0
    ev["x"][1000:2000] = np.tile(np.sort(rng.choice(1280, 100, replace=False)), 10)
    tr = make_triggers(np.sort(rng.choice(t, 20)), rng.integers(0, 16, 20), rng.integers(0, 2, 20))
    data = raw.encode(ev, tr, format="EVT3", width=1280, height=720)
    base = (t[0] >> 24) << 24
    dec = raw.StreamDecoder("EVT3", time_base_us=base, width=1280, height=720)
    cuts = np.sort(rng.integers(0, len(data), 500))
    parts = [dec.decode(data[a:b]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(data)])]
    dec.finish()
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), ev)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), tr)
    assert not dec.damaged
    words = np.frombuffer(data, "<u2")
    assert np.count_nonzero(words >> 12 == 0x3) > 0      # vectors used for the burst


def test_long_gaps_are_bridged_by_time_high_words():
    # 30 s and 5 h gaps: more than half a wrap in both formats
    t = np.array([0, 30_000_000, 30_000_000 + 5 * 3600 * 10**6])
    ev = make_events(t, [1, 2, 3], [1, 2, 3], [1, 0, 1])
    for fmt in ("EVT3", "EVT2"):
        out, _, stats = decode(fmt, raw.encode(ev, format=fmt, width=64, height=64))
        np.testing.assert_array_equal(out, ev)


def test_encoder_rejects_bad_arrays():
    ev = make_events([5, 4], [0, 0], [0, 0], [0, 1])
    with pytest.raises(ValueError, match="non-decreasing"):
        raw.encode(ev, width=64, height=64)
    with pytest.raises(ValueError, match="x must be < width"):
        raw.encode(make_events([0], [64], [0], [1]), width=64, height=64)
    with pytest.raises(ValueError, match="channel id"):
        raw.encode(make_events([], [], [], []), make_triggers([0], [16], [1]), width=64, height=64)
    with pytest.raises(TypeError, match="EVENT_DTYPE"):
        raw.encode(np.zeros(3), width=64, height=64)
    with pytest.raises(ValueError, match="not supported"):
        raw.encode(make_events([], [], [], []), format="EVT21", width=64, height=64)
