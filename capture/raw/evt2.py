"""EVT 2.0 (32-bit words) and EVT 2.1 (64-bit vectorised words): vectorised decoders, EVT2 encoder.

EVT 2.0 word (little-endian u32): ``type[31:28]`` (0x0 CD OFF, 0x1 CD ON, 0x8 TIME_HIGH,
0xA EXT_TRIGGER, 0xD IMU, 0xE OTHERS, 0xF CONTINUED), ``ts[27:22]`` (t bits 5:0),
``x[21:11]``, ``y[10:0]``. TIME_HIGH carries t >> 6 in bits [27:0]; EXT_TRIGGER has the
edge in bit 0 and the channel in bits [12:8].

EVT 2.1 event = the same 32-bit header plus a 32-bit validity mask: a CD word stands for an
event at ``(x + k, y)`` for every set bit k. In the standard ("little") byte order the mask
is the first little-endian u32 and the header the second; in the "legacy" order (the EVK's
IMX636 default) they are swapped.

Time: ``t_us = (loops << 34) | (time_high << 6) | ts``; a TIME_HIGH smaller than the
previous one by 2^27 or more is a wrap. Words before the first TIME_HIGH are skipped.
"""

from __future__ import annotations

import numpy as np

from capture.raw._common import (EMPTY_EVENTS, EMPTY_TRIGGERS, DecoderState, check_events, check_time_order, in_bounds,
                                  first_of_type, make_events, merge_order, select, time_high_words,
                                  triggers_from, xy_view)

TIME_HIGH_WRAP = 1 << 28
"""TIME_HIGH values per loop; one loop is 2^34 µs."""

_CD_OFF, _CD_ON, _TIME_HIGH, _EXT_TRIGGER = 0x0, 0x1, 0x8, 0xA
_OTHER_TYPES = (0xD, 0xE, 0xF)
_UNKNOWN_TYPES = (0x2, 0x3, 0x4, 0x5, 0x6, 0x7, 0x9, 0xB, 0xC)


def _time_high(thv: np.ndarray, thpos: np.ndarray, w0: int, st: DecoderState) -> np.ndarray:
    """Extended TIME_HIGH values (loops counted) for the TIME_HIGH payloads ``thv``."""
    step = np.diff(thv, prepend=st.th_raw)
    wrap = step < -(TIME_HIGH_WRAP // 2)
    loops = st.loops + np.cumsum(wrap)
    back = (step < 0) & ~wrap
    if back.any():
        st.damage("time_backward", np.count_nonzero(back), w0 + int(thpos[np.argmax(back)]))
    st.stats["time_jumps"] += int(np.count_nonzero(step > 1))
    st.stats["time_loops"] += int(loops[-1] - st.loops)
    st.th_raw, st.loops = int(thv[-1]), int(loops[-1])
    return thv + loops * TIME_HIGH_WRAP


def _decode(head: np.ndarray, mask: np.ndarray | None, st: DecoderState) -> tuple[np.ndarray, np.ndarray]:
    """Shared EVT2 / EVT2.1 decoder: ``head`` are the u32 headers, ``mask`` the EVT2.1 masks.

    CD words are nearly all words, so every other word type is classified on the small
    subset of non-CD words only.
    """
    w0 = st.words_seen
    st.words_seen += len(head)
    st.stats["words"] += len(head)
    if not st.started:
        skip = first_of_type(head, 28, _TIME_HIGH)
        if skip < 0:
            st.stats["words_before_time_high"] += len(head)
            return EMPTY_EVENTS, EMPTY_TRIGGERS
        st.stats["words_before_time_high"] += skip
        st.started = True
        st.first_th = st.th_raw = int(head[skip] & 0x0FFFFFFF)
        st.t_us = st.th_raw << 6
        head = head[skip:]
        mask = mask[skip:] if mask is not None else None
        w0 += skip
    n = len(head)
    cd = head < (2 << 28)                      # types 0x0 (OFF) and 0x1 (ON)
    n_cd = int(np.count_nonzero(cd))
    high_start = st.t_us >> 6
    triggers = EMPTY_TRIGGERS
    if n_cd < n:
        noncd = np.flatnonzero(head >= (2 << 28))
        ntyp = head[noncd] >> 28
        counts = np.bincount(ntyp, minlength=16)
        st.stats["others"] += int(counts[list(_OTHER_TYPES)].sum())
        n_unknown = int(counts[list(_UNKNOWN_TYPES)].sum())
        if n_unknown:
            st.damage("unknown_words", n_unknown, w0 + int(noncd[np.argmax(np.isin(ntyp, _UNKNOWN_TYPES))]))
        th_k = np.flatnonzero(ntyp == _TIME_HIGH)
        thpos = noncd[th_k]
        if len(thpos):
            high = _time_high((head[thpos] & 0x0FFFFFFF).astype(np.int64), thpos, w0, st)
            high_table = np.concatenate(([high_start], high))
            st.t_us = int(high[-1]) << 6
        else:
            high_table = np.array([high_start], np.int64)
        if counts[_EXT_TRIGGER]:
            tr = noncd[ntyp == _EXT_TRIGGER]
            h = head[tr]
            t_tr = (high_table[np.searchsorted(thpos, tr)] << 6) | ((h >> 22) & 0x3F)
            triggers = triggers_from(t_tr, (h >> 8) & 0x1F, h & 1)
            st.stats["triggers"] += len(triggers)
        cd_before_th = thpos - th_k            # CD words before each TIME_HIGH
    else:
        noncd = None
        high_table = np.array([high_start], np.int64)
        cd_before_th = np.zeros(0, np.int64)
    if n_cd == 0:
        return EMPTY_EVENTS, triggers
    hc = head if noncd is None else head[cd]   # boolean compress: fast when nearly all are CD
    seg = np.diff(cd_before_th, prepend=0, append=n_cd)
    t = np.repeat(high_table << 6, seg)        # TIME_HIGH part of t for every CD word
    scratch = np.right_shift(hc, 22)           # one reused temporary keeps the working set small
    scratch &= 0x3F
    t |= scratch

    def word_of(j):                            # stream word index of CD word j
        return w0 + (j if noncd is None else int(np.flatnonzero(cd)[j]))

    check_time_order(t, st, word_of)

    if mask is None:
        events = make_events(n_cd)
        events["t"] = t
        np.right_shift(hc, 11, out=scratch)
        scratch &= 0x7FF                       # x
        x_max = int(scratch.max())
        y = hc & 0x7FF
        y_max = int(y.max())
        y <<= 16
        scratch |= y
        xy_view(events)[:] = scratch           # x and y in one strided write
        np.right_shift(hc, 28, out=scratch)
        events["p"] = scratch
        if st.width is not None and st.height is not None and (x_max >= st.width or y_max >= st.height):
            keep = in_bounds((hc >> 11) & 0x7FF, hc & 0x7FF, st, word_of)
            events = select(events, keep)
    else:
        mc = mask if noncd is None else mask[cd]
        cnt = np.bitwise_count(mc)
        bits = np.unpackbits(mc.astype("<u4").view(np.uint8).reshape(-1, 4), axis=1, bitorder="little")
        x = np.repeat((hc >> 11) & 0x7FF, cnt) + (np.flatnonzero(bits.view(bool)) & 31).astype(np.uint32)
        y = np.repeat(hc & 0x7FF, cnt)
        ends = np.cumsum(cnt, dtype=np.int64)
        keep = in_bounds(x, y, st, lambda i: word_of(int(np.searchsorted(ends, i, side="right"))))
        events = make_events(int(ends[-1]))
        events["t"] = np.repeat(t, cnt)
        events["x"] = np.minimum(x, 0xFFFF)
        events["y"] = y
        events["p"] = np.repeat(hc >> 28, cnt)
        if keep is not None:
            events = select(events, keep)
    st.stats["events"] += len(events)
    return events, triggers


def decode_words(words: np.ndarray, st: DecoderState) -> tuple[np.ndarray, np.ndarray]:
    """Decode EVT 2.0 words (uint32, shape (N,)), continuing from ``st`` (updated in place).

    Returns ``(events, triggers)`` (EVENT_DTYPE, TRIGGER_DTYPE), t in µs, unshifted.
    """
    return _decode(words, None, st)


def decode_words_21(words: np.ndarray, st: DecoderState, *, endianness: str = "little") -> tuple[np.ndarray, np.ndarray]:
    """Decode EVT 2.1 events, continuing from ``st`` (updated in place).

    Parameters
    ----------
    words : ndarray of uint32, shape (N, 2)
        Each row is one 64-bit event as two little-endian u32 in file order.
    endianness : str
        ``"little"``: row = (mask, header); ``"legacy"``: row = (header, mask).
    """
    head_col = 1 if endianness == "little" else 0
    return _decode(np.ascontiguousarray(words[:, head_col]), np.ascontiguousarray(words[:, 1 - head_col]), st)


def encode(events: np.ndarray, triggers: np.ndarray | None = None, *, width: int, height: int) -> np.ndarray:
    """Encode events (and triggers) as EVT 2.0 words; decoding gives the same arrays back.

    One CD word per event and a TIME_HIGH word whenever t >> 6 changes.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE, shape (N,)
        t non-decreasing, ``x < width``, ``y < height``.
    triggers : ndarray of TRIGGER_DTYPE, optional
        Channel ids 0..31; placed after the events with the same t.
    width, height : int
        Sensor geometry in pixels (at most 2048).

    Returns
    -------
    ndarray of uint32
        The words, to be written little-endian after a header.
    """
    events, triggers = check_events(events, triggers, width, height, max_channel=31)
    n_ev = len(events)
    order = merge_order(events["t"], triggers["t"])
    t_all = np.concatenate((events["t"], triggers["t"]))[order]
    th_count, _, th_value = time_high_words(t_all >> 6, TIME_HIGH_WRAP // 4)
    start = np.cumsum(th_count + 1) - 1             # index of each item's own word
    out = np.empty(len(order) + len(th_value), np.uint32)
    is_th = np.ones(len(out), bool)
    is_th[start] = False
    out[is_th] = (_TIME_HIGH << 28) | (th_value & 0x0FFFFFFF)
    ts = (t_all & 0x3F).astype(np.uint32) << 22
    is_ev = order < n_ev
    k = order[is_ev]
    out[start[is_ev]] = (ts[is_ev] | (events["p"][k].astype(np.uint32) << 28)
                         | (events["x"][k].astype(np.uint32) << 11) | events["y"][k])
    k = order[~is_ev] - n_ev
    out[start[~is_ev]] = (ts[~is_ev] | np.uint32(_EXT_TRIGGER << 28)
                          | (triggers["id"][k].astype(np.uint32) << 8) | triggers["p"][k].astype(np.uint32))
    return out
