"""Decoding a file in parts at once (``capture.raw.read(threads=N)``, ``RawReader(threads=N)``) gives what one
thread gives."""

import warnings

import numpy as np
import pytest

import capture.raw as raw
import capture.raw.stream as stream
from capture.events import make_events, make_triggers
from tests.test_raw_words import evt21_words


@pytest.fixture(params=[1 << 12, 8 << 20], ids=["many windows", "one window"])
def small_parts(monkeypatch, request):
    """Parts for files of any size, guesses from a few words (so the guess must grow), and
    windows of 4 KiB per part (a file is decoded window after window) or of 8 MiB (one window)."""
    monkeypatch.setattr(stream, "PARALLEL_MIN_BYTES", 0)
    monkeypatch.setattr(stream, "GUESS_WORDS", 16)
    monkeypatch.setattr(stream, "PART_BYTES", request.param)


def _same(path, threads, **kw):
    with warnings.catch_warnings(record=True) as one_w:
        warnings.simplefilter("always")
        one = raw.read(path, threads=1, **kw)
    with warnings.catch_warnings(record=True) as many_w:
        warnings.simplefilter("always")
        many = raw.read(path, threads=threads, **kw)
    np.testing.assert_array_equal(many.events, one.events)
    np.testing.assert_array_equal(many.triggers, one.triggers)
    assert many.stats == one.stats, {k: (one.stats[k], many.stats[k]) for k in one.stats if one.stats[k] != many.stats[k]}
    assert many.time_shift_us == one.time_shift_us
    assert [str(w.message) for w in many_w] == [str(w.message) for w in one_w]
    return one


def _spy_follows(monkeypatch):
    """Record what every part's check returned (None: a wrong guess, decoded again)."""
    seen = []
    follows = stream.StreamDecoder.follows

    def spy(self, earlier):
        seen.append(follows(self, earlier))
        return seen[-1]
    monkeypatch.setattr(stream.StreamDecoder, "follows", spy)
    return seen


@pytest.mark.parametrize("threads", [2, 3, 7])
@pytest.mark.parametrize("time_shift", [False, True])
def test_every_shared_recording_decodes_the_same_in_parts(shared_raw_dir, small_parts, monkeypatch, threads,
                                                          time_shift):
    seen = _spy_follows(monkeypatch)
    for path in sorted(shared_raw_dir.glob("*.raw")):
        one = _same(path, threads, time_shift=time_shift)
        assert len(one.events) > 0
    assert any(s is not None for s in seen)  # guesses held: parts were really used


def test_parts_across_time_wraps_are_shifted_by_whole_periods(tmp_path, small_parts, monkeypatch):
    """EVT3 time wraps every 2^24 us: a part after wraps gets its loops from the parts before."""
    rng = np.random.default_rng(3)
    n = 40_000
    t = np.sort(rng.integers(3 << 24, 7 << 24, n))  # four wrap periods, starting after three
    ev = make_events(t, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n))
    tr = make_triggers(np.sort(rng.integers(3 << 24, 7 << 24, 9)), np.arange(9) % 4, np.arange(9) % 2)
    path = tmp_path / "wraps.raw"
    raw.write(path, ev, tr, format="EVT3", width=640, height=480)
    seen = _spy_follows(monkeypatch)
    for time_shift in (False, True):
        one = _same(path, 6, time_shift=time_shift)
    np.testing.assert_array_equal(one.events["t"] + one.time_shift_us, ev["t"])
    assert any(s for s in seen)  # some part was whole periods behind its guess


def test_evt2_and_evt21_decode_the_same_in_parts(tmp_path, small_parts):
    rng = np.random.default_rng(4)
    n = 30_000
    t = np.sort(rng.integers(0, 40_000_000, n))
    ev = make_events(t, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n))
    tr = make_triggers(np.sort(rng.integers(0, 40_000_000, 5)), [0, 1, 2, 3, 4], [1, 0, 1, 0, 1])
    evt2 = tmp_path / "a.raw"
    raw.write(evt2, ev, tr, format="EVT2", width=640, height=480)
    np.testing.assert_array_equal(_same(evt2, 4).events, ev)
    for order in ("little", "legacy"):
        evt21 = tmp_path / f"b_{order}.raw"
        evt21.write_bytes(raw.header_bytes("EVT21", width=640, height=480, endianness=order)
                          + evt21_words(ev, tr, order))
        assert len(_same(evt21, 3).events) == n


def test_damaged_words_decode_the_same_in_parts(tmp_path, small_parts, shared_raw_dir):
    """Flipped bits (damage counters, time reversals, the first damaged byte) come out the same."""
    data = bytearray((shared_raw_dir / "expelliarmus_evt3_sample_1280x720.raw").read_bytes())
    _, header = raw.parse_header(bytes(data))
    rng = np.random.default_rng(5)
    for k, pos in enumerate(rng.integers(header, len(data), 300)):
        data[pos] ^= 1 << int(rng.integers(0, 8))
        if k % 100 == 99:
            path = tmp_path / f"damaged_{k}.raw"
            path.write_bytes(bytes(data[:-1]))  # and a trailing half word
            one = _same(path, 4)
            assert one.stats["trailing_bytes"] == 1
    late = bytearray((shared_raw_dir / "expelliarmus_evt3_sample_1280x720.raw").read_bytes())
    for pos in rng.integers(len(late) * 8 // 10, len(late), 20):  # damage in the last part only
        late[pos] ^= 0x80
    (tmp_path / "late.raw").write_bytes(bytes(late))
    one = _same(tmp_path / "late.raw", 4)
    assert one.stats["first_damage_byte"] >= len(late) * 7 // 10


def test_a_wrong_guess_is_decoded_again_from_the_true_state(tmp_path, small_parts, monkeypatch, shared_raw_dir):
    speculative = stream.StreamDecoder.speculative

    def wrong_row(self, preceding, offset_bytes):
        guess = speculative(self, preceding, offset_bytes)
        guess._state.y = (guess._state.y + 1) % 720  # a guess that decodes rows wrongly
        guess._guessed = stream._decoding_state(guess._state)
        return guess
    monkeypatch.setattr(stream.StreamDecoder, "speculative", wrong_row)
    seen = _spy_follows(monkeypatch)
    _same(shared_raw_dir / "expelliarmus_evt3_sample_1280x720.raw", 3)
    assert seen[0] is None  # the first check failed, and the rest was decoded in one thread


def test_streamed_batches_are_those_of_one_thread(small_parts, shared_raw_dir):
    """``iter_chunks`` / ``RawReader`` batches (what ingest stores) come out in order, the same."""
    path = shared_raw_dir / "expelliarmus_evt2_sparklers_640x480.raw"
    one = list(raw.iter_chunks(path, threads=1))
    many = list(raw.iter_chunks(path, threads=3))
    for a, b in ((one, many),):
        np.testing.assert_array_equal(np.concatenate([e for e, _ in a]), np.concatenate([e for e, _ in b]))
    assert sum(len(e) for e, _ in many) == sum(len(e) for e, _ in one) > 0


def test_time_shift_from_a_first_time_high_in_a_later_part(tmp_path, small_parts):
    """Words without time (OTHERS) fill the first parts: the shift comes from a later part's
    first TIME_HIGH, and every part is shifted by it."""
    n = 20_000
    ev = make_events(5_000_000 + np.arange(n) * 7, np.arange(n) % 640, np.full(n, 3), np.arange(n) % 2)
    path = tmp_path / "late_time.raw"
    path.write_bytes(raw.header_bytes("EVT3", width=640, height=480) + np.full(60_000, 0xE000, "<u2").tobytes()
                     + raw.encode(ev, format="EVT3", width=640, height=480))
    for threads in (2, 4, 7):
        one = _same(path, threads, time_shift=True)
    assert one.time_shift_us > 0 and one.events["t"][0] == 5_000_000 - one.time_shift_us
