"""EVT 3.0: vectorised decoder and encoder for 16-bit little-endian words.

Word types (``type = word >> 12``; payload = low 12 bits):
``0x0`` ADDR_Y (y[10:0], system-type bit 11), ``0x2`` ADDR_X (x[10:0], polarity bit 11, one
event), ``0x3`` VECT_BASE_X (x[10:0], polarity bit 11), ``0x4`` VECT_12 / ``0x5`` VECT_8
(validity masks: event at base+k for each set bit k, then base += 12 / 8), ``0x6`` TIME_LOW
(t[11:0]), ``0x8`` TIME_HIGH (t[23:12]), ``0xA`` EXT_TRIGGER (edge bit 0, channel bits 11:8),
``0x7``/``0xE``/``0xF``/``0xD`` CONTINUED_4 / OTHERS / CONTINUED_12 / IMU (no CD events).

Every word is decoded on its own against the state left by the words before it, so a
vector triplet or an OTHERS group split between two batches decodes exactly as in one batch.
Time: ``t_us = (loops << 24) | (time_high << 12) | time_low``; a TIME_HIGH that is smaller
than the previous one by 2048 or more is a wrap (one more loop of 2^24 µs); a TIME_HIGH
that differs from the previous one resets time_low to 0 until the next TIME_LOW (as
Metavision's decoder does). Words before the first TIME_HIGH are skipped.
"""

from __future__ import annotations

import numpy as np

from capture.raw._common import (EMPTY_EVENTS, EMPTY_TRIGGERS, DecoderState, drop_out_of_bounds,
                                  make_events, triggers_from)

TIME_HIGH_WRAP = 1 << 12
"""TIME_HIGH values per loop; one loop is 2^24 µs."""

_ADDR_Y, _ADDR_X, _VECT_BASE_X, _VECT_12, _VECT_8 = 0x0, 0x2, 0x3, 0x4, 0x5
_TIME_LOW, _TIME_HIGH, _EXT_TRIGGER = 0x6, 0x8, 0xA
_OTHER_TYPES = (0x7, 0xD, 0xE, 0xF)
_UNKNOWN_TYPES = (0x1, 0x9, 0xB, 0xC)


def _time_table(typ, pay, st: DecoderState, w0: int):
    """Times (µs) after each TIME_LOW / TIME_HIGH word, and those words' positions.

    Returns ``(tpos, t_after)``: ``t_after[i]`` is the time in force right after word
    ``tpos[i]``. Updates the time part of ``st`` and the time statistics.
    """
    is_th = typ == _TIME_HIGH
    tpos = np.flatnonzero(is_th | (typ == _TIME_LOW))
    tth = is_th[tpos]
    tpay = pay[tpos].astype(np.int64)
    thv = tpay[tth]
    if len(thv):
        step = np.diff(thv, prepend=st.th_raw)
        wrap = step < -(TIME_HIGH_WRAP // 2)
        loops = st.loops + np.cumsum(wrap)
        high = thv + loops * TIME_HIGH_WRAP
        back = (step < 0) & ~wrap
        if back.any():
            st.damage("time_backward", np.count_nonzero(back), w0 + int(tpos[tth][np.argmax(back)]))
        st.stats["time_jumps"] += int(np.count_nonzero(step > 1))
        st.stats["time_loops"] += int(loops[-1] - st.loops)
        # TIME_LOW resets to 0 when TIME_HIGH changes; a repeated TIME_HIGH keeps it.
        setter = ~tth
        setter[tth] = step != 0
    else:
        high = thv
        setter = ~tth
    high_ord = np.cumsum(tth) - 1
    high_now = np.concatenate(([st.t_us >> 12], high))[high_ord + 1]
    low_val = np.where(tth, 0, tpay)
    low_ord = np.cumsum(setter) - 1
    low_now = np.concatenate(([st.tl], low_val[setter]))[low_ord + 1]
    t_after = (high_now << 12) | low_now
    if len(thv):
        st.th_raw = int(thv[-1])
        st.loops = int(loops[-1])
    if len(tpos):
        st.t_us = int(t_after[-1])
        st.tl = int(low_now[-1])
    return tpos, t_after


def decode_words(words: np.ndarray, st: DecoderState) -> tuple[np.ndarray, np.ndarray]:
    """Decode EVT3 words, continuing from ``st`` (updated in place).

    Parameters
    ----------
    words : ndarray of uint16, shape (N,)
        Whole words in stream order (native byte order already applied).
    st : DecoderState
        State left by the previous call (fresh for a new stream).

    Returns
    -------
    events : ndarray of EVENT_DTYPE
        CD events in stream order, t in µs (64-bit, unshifted).
    triggers : ndarray of TRIGGER_DTYPE
        External trigger events in stream order.
    """
    w = words
    w0 = st.words_seen
    st.words_seen += len(w)
    st.stats["words"] += len(w)
    if len(w):
        st.last_words = (st.last_words + tuple(int(v) for v in w[-3:]))[-3:]
    if not st.started:
        hits = np.flatnonzero((w >> 12) == _TIME_HIGH)
        if len(hits) == 0:
            st.stats["words_before_time_high"] += len(w)
            return EMPTY_EVENTS, EMPTY_TRIGGERS
        skip = int(hits[0])
        st.stats["words_before_time_high"] += skip
        w = w[skip:]
        w0 += skip
        st.started = True
        st.first_th = st.th_raw = int(w[0] & 0xFFF)
        st.t_us = st.th_raw << 12
        st.tl = 0
    if len(w) == 0:
        return EMPTY_EVENTS, EMPTY_TRIGGERS
    typ = w >> 12
    counts = np.bincount(typ, minlength=16)
    st.stats["others"] += int(counts[list(_OTHER_TYPES)].sum())
    n_unknown = int(counts[list(_UNKNOWN_TYPES)].sum())
    if n_unknown:
        first = int(np.argmax(np.isin(typ, _UNKNOWN_TYPES)))
        st.damage("unknown_words", n_unknown, w0 + first)
    pay = w & 0x0FFF
    t_start = st.t_us
    if counts[_TIME_LOW] or counts[_TIME_HIGH]:
        tpos, t_after = _time_table(typ, pay, st, w0)
        t_table = np.concatenate(([t_start], t_after))
    else:
        tpos, t_table = None, np.array([t_start], dtype=np.int64)

    def times_at(pos):
        if tpos is None:
            return np.full(len(pos), t_start, dtype=np.int64)
        return t_table[np.searchsorted(tpos, pos)]

    triggers = EMPTY_TRIGGERS
    if counts[_EXT_TRIGGER]:
        tr = np.flatnonzero(typ == _EXT_TRIGGER)
        tp = pay[tr]
        triggers = triggers_from(times_at(tr), (tp >> 8) & 0xF, tp & 1)
        st.stats["triggers"] += len(triggers)

    n_vec = int(counts[_VECT_12] + counts[_VECT_8])
    y_before = st.y
    if counts[_ADDR_Y]:
        ypos = np.flatnonzero(typ == _ADDR_Y)
        y_table = np.concatenate((np.array([y_before], np.uint16), pay[ypos]))
        st.y = int(y_table[-1])
    else:
        ypos, y_table = None, np.array([y_before], np.uint16)
    if n_vec == 0:
        _update_vector_base(typ, pay, st, counts)
        if counts[_ADDR_X] == 0:
            return EMPTY_EVENTS, triggers
    if n_vec:
        epos = np.flatnonzero((typ == _ADDR_X) | ((typ >> 1) == (_VECT_12 >> 1)))
    else:
        epos = np.flatnonzero(typ == _ADDR_X)
    pe = pay[epos]
    t_e = times_at(epos)
    y_e = y_table[np.searchsorted(ypos, epos)] if ypos is not None else np.full(len(epos), y_before, np.uint16)
    y_ok = y_e < 2048

    if n_vec == 0:
        if not y_ok.all():
            _count_bad_y(y_e, y_ok, np.ones(len(epos), np.int64), epos, w0, st)
            epos, pe, t_e, y_e = epos[y_ok], pe[y_ok], t_e[y_ok], y_e[y_ok]
        ev = make_events(len(epos))
        ev["t"] = t_e
        ev["x"] = pe & 0x7FF
        ev["y"] = y_e
        ev["p"] = pe >> 11
        ev = drop_out_of_bounds(ev, st, lambda i: w0 + int(epos[i]))
        st.stats["events"] += len(ev)
        return ev, triggers

    # Vectors: per vector word, its base x is the last VECT_BASE_X plus the widths of the
    # vector words between it and this word (12 per VECT_12, 8 per VECT_8).
    isv = (typ[epos] >> 1) == (_VECT_12 >> 1)
    vsel = np.flatnonzero(isv)
    vpos = epos[vsel]
    is12 = typ[vpos] == _VECT_12
    widths = np.where(is12, 12, 8)
    cw = np.cumsum(widths)
    cw_excl = cw - widths
    total = int(cw[-1])
    vmask = pe[vsel]
    vmask = np.where(is12, vmask, vmask & 0xFF)
    if counts[_VECT_BASE_X]:
        vbpos = np.flatnonzero(typ == _VECT_BASE_X)
        vbpay = pay[vbpos]
        jb = np.searchsorted(vbpos, vpos) - 1
        start_cw = np.concatenate((cw_excl, [total]))[np.searchsorted(vpos, vbpos)]
        has = jb >= 0
        jbc = np.maximum(jb, 0)
        base = np.where(has, (vbpay[jbc] & 0x7FF).astype(np.int64) + cw_excl - start_cw[jbc],
                        st.base_x + cw_excl)
        pol = np.where(has, vbpay[jbc] >> 11, st.base_pol)
        no_base = ~has & (st.base_x < 0)
        st.base_x = int(vbpay[-1] & 0x7FF) + total - int(start_cw[-1])
        st.base_pol = int(vbpay[-1] >> 11)
    else:
        base = st.base_x + cw_excl
        pol = np.full(len(vpos), st.base_pol)
        no_base = np.full(len(vpos), st.base_x < 0)
        if st.base_x >= 0:
            st.base_x += total
    base_e = (pe & 0x7FF).astype(np.int64)
    base_e[vsel] = base
    p_e = pe >> 11
    p_e[vsel] = pol
    cnt = np.ones(len(epos), np.int64)
    cnt[vsel] = np.bitwise_count(vmask)
    if no_base.any():
        lost = vsel[no_base]
        st.damage("vectors_without_base", int(cnt[lost].sum()), w0 + int(vpos[no_base][0]))
        cnt[lost] = 0
        vmask[no_base] = 0
    if not y_ok.all():
        _count_bad_y(y_e, y_ok, cnt, epos, w0, st)
        cnt[~y_ok] = 0
        vmask[~y_ok[vsel]] = 0
    ev = make_events(int(cnt.sum()))
    ev["t"] = np.repeat(t_e, cnt)
    ev["y"] = np.repeat(y_e, cnt)
    ev["p"] = np.repeat(p_e, cnt)
    xs = np.repeat(base_e, cnt)
    bits = np.unpackbits(vmask.astype("<u2").view(np.uint8).reshape(-1, 2), axis=1, bitorder="little")
    xs[np.repeat(isv, cnt)] += np.nonzero(bits)[1]
    ev["x"] = np.minimum(xs, 0xFFFF)
    ends = np.cumsum(cnt)
    ev = drop_out_of_bounds(ev, st, lambda i: w0 + int(epos[np.searchsorted(ends, i, side="right")]))
    st.stats["events"] += len(ev)
    return ev, triggers


def finish(st: DecoderState) -> None:
    """End of stream: count a vector triplet cut short (``VECT_BASE_X [VECT_12 [VECT_12]]``) as damage."""
    types = [v >> 12 for v in st.last_words]
    for k in (3, 2, 1):
        if types[-k:] == [_VECT_BASE_X, _VECT_12, _VECT_12][:k] and len(types) >= k:
            st.damage("incomplete_group_words", k, st.words_seen - k)
            return


def _count_bad_y(y_e, y_ok, cnt, epos, w0, st: DecoderState) -> None:
    """Count events dropped for a missing ADDR_Y (damage) or another system's ADDR_Y."""
    none = y_e == 0xFFFF
    if none.any():
        st.damage("events_without_y", int(cnt[none].sum()), w0 + int(epos[np.argmax(none)]))
    other = ~y_ok & ~none
    st.stats["events_other_system"] += int(cnt[other].sum())


def _update_vector_base(typ, pay, st: DecoderState, counts) -> None:
    """Carry the vector base across a batch that has VECT_BASE_X words but no vectors."""
    if counts[_VECT_BASE_X]:
        last = int(pay[np.flatnonzero(typ == _VECT_BASE_X)[-1]])
        st.base_x, st.base_pol = last & 0x7FF, last >> 11


_MIN_VECTOR_EVENTS = 5
"""A vector group (4 words) replaces this many or more ADDR_X words."""


def encode(events: np.ndarray, triggers: np.ndarray | None = None, *, width: int, height: int) -> np.ndarray:
    """Encode events (and triggers) as EVT3 words; decoding them gives the same arrays back.

    Runs of at least five events with equal t, y and polarity and increasing x inside a
    32-pixel window become one ``VECT_BASE_X, VECT_12, VECT_12, VECT_8`` group (the triplet
    Metavision's decoder expects, base + 32 <= width); other events become ADDR_X words.
    ADDR_Y, TIME_LOW and TIME_HIGH words are written only when their value changes.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE, shape (N,)
        t non-decreasing, ``x < width``, ``y < height``.
    triggers : ndarray of TRIGGER_DTYPE, optional
        Channel ids 0..15; placed after the events with the same t.
    width, height : int
        Sensor geometry in pixels (at most 2048).

    Returns
    -------
    ndarray of uint16
        The words, to be written little-endian after a header.
    """
    from capture.raw._common import check_events, merge_order, time_high_words

    events, triggers = check_events(events, triggers, width, height, max_channel=15)
    n_ev = len(events)
    t = events["t"]
    x = events["x"].astype(np.int64)
    y = events["y"]
    p = events["p"]
    # Vector windows: consecutive events with equal (t, y, p), increasing x, in a 32-px window.
    first_of_window = np.ones(n_ev, bool)
    base = x.copy()
    if n_ev > 1 and width >= 32:
        same = (t[1:] == t[:-1]) & (y[1:] == y[:-1]) & (p[1:] == p[:-1]) & (x[1:] > x[:-1])
        seg_start = np.concatenate(([True], ~same))
        seg_x0 = x[seg_start][np.cumsum(seg_start) - 1]
        window = (x - seg_x0) // 32
        first_of_window = seg_start.copy()
        first_of_window[1:] |= window[1:] != window[:-1]
        starts = np.flatnonzero(first_of_window)
        size = np.diff(np.append(starts, n_ev))
        wbase = np.minimum(seg_x0[starts] + 32 * window[starts], width - 32)
        vec_window = size >= _MIN_VECTOR_EVENTS
        base = np.repeat(wbase, size)
    else:
        starts = np.arange(n_ev)
        size = np.ones(n_ev, np.int64)
        vec_window = np.zeros(n_ev, bool)
    in_vector = np.repeat(vec_window, size)
    body = np.where(in_vector, 0, 1)
    body[starts[vec_window]] = 4
    need_y = np.ones(n_ev, np.int64)
    if n_ev > 1:
        need_y[1:] = y[1:] != y[:-1]
    need_y[in_vector & ~first_of_window] = 0

    # Merge with triggers into stream order.
    order = merge_order(t, triggers["t"])
    is_ev = order < n_ev
    t_all = np.concatenate((t, triggers["t"]))[order]
    high = t_all >> 12
    th_count, th_item, th_value = time_high_words(high, TIME_HIGH_WRAP // 4)
    need_tl = np.ones(len(order), np.int64)
    if len(order) > 1:
        need_tl[1:] = (t_all[1:] != t_all[:-1]) | (th_count[1:] > 0)
    n_y = np.zeros(len(order), np.int64)
    n_body = np.ones(len(order), np.int64)
    ev_items = np.flatnonzero(is_ev)
    ev_index = order[ev_items]
    n_y[ev_items] = need_y[ev_index]
    n_body[ev_items] = body[ev_index]
    n_words = th_count + need_tl + n_y + n_body
    start = np.cumsum(n_words) - n_words
    out = np.empty(int(n_words.sum()), np.uint16)
    th_first = np.repeat(start, th_count)
    th_rank = np.arange(len(th_item)) - np.repeat(np.cumsum(th_count) - th_count, th_count)
    out[th_first + th_rank] = (_TIME_HIGH << 12) | (th_value & 0xFFF)
    tl_items = np.flatnonzero(need_tl)
    out[start[tl_items] + th_count[tl_items]] = (_TIME_LOW << 12) | (t_all[tl_items] & 0xFFF)
    y_items = np.flatnonzero(n_y)
    out[start[y_items] + th_count[y_items] + need_tl[y_items]] = y[order[y_items]]
    at = start + th_count + need_tl + n_y
    single = ev_items[n_body[ev_items] == 1]
    k = order[single]
    out[at[single]] = (_ADDR_X << 12) | (p[k].astype(np.uint16) << 11) | x[k]
    vec = ev_items[n_body[ev_items] == 4]
    if len(vec):
        k = order[vec]
        w_of = np.cumsum(first_of_window) - 1       # window of each event
        bits = np.left_shift(np.uint32(1), (x - base).astype(np.uint32))
        mask = np.bitwise_or.reduceat(bits, starts)[w_of[k]]
        out[at[vec]] = (_VECT_BASE_X << 12) | (p[k].astype(np.uint16) << 11) | base[k]
        out[at[vec] + 1] = (_VECT_12 << 12) | (mask & 0xFFF)
        out[at[vec] + 2] = (_VECT_12 << 12) | ((mask >> 12) & 0xFFF)
        out[at[vec] + 3] = (_VECT_8 << 12) | ((mask >> 24) & 0xFF)
    tr_items = np.flatnonzero(~is_ev)
    if len(tr_items):
        k = order[tr_items] - n_ev
        out[at[tr_items]] = ((_EXT_TRIGGER << 12) | (triggers["id"][k].astype(np.uint16) << 8)
                             | triggers["p"][k].astype(np.uint16))
    return out
