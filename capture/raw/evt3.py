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

from capture.raw._common import (EMPTY_EVENTS, EMPTY_TRIGGERS, DecoderState, in_bounds, make_events,
                                  triggers_from)

TIME_HIGH_WRAP = 1 << 12
"""TIME_HIGH values per loop; one loop is 2^24 µs."""

_ADDR_Y, _ADDR_X, _VECT_BASE_X, _VECT_12, _VECT_8 = 0x0, 0x2, 0x3, 0x4, 0x5
_TIME_LOW, _TIME_HIGH, _EXT_TRIGGER = 0x6, 0x8, 0xA
_OTHER_TYPES = (0x7, 0xD, 0xE, 0xF)
_UNKNOWN_TYPES = (0x1, 0x9, 0xB, 0xC)


def _time_table(is_th, is_tl, pay, st: DecoderState, w0: int):
    """Time (µs) in force after each TIME_LOW / TIME_HIGH word of the batch.

    Returns ``t_table`` with ``t_table[0]`` = the time before the batch and ``t_table[k]`` =
    the time after the k-th time word. Updates the time part of ``st`` and its statistics.
    """
    tpos = np.flatnonzero(is_th | is_tl)
    tth = is_th.take(tpos)
    tpay = pay.take(tpos)
    thk = np.flatnonzero(tth)                   # TIME_HIGH words among the time words
    setter = ~tth                               # words that set time_low (TIME_LOW, changed TIME_HIGH)
    high_table = np.empty(len(thk) + 1, np.int64)
    high_table[0] = st.t_us >> 12
    if len(thk):
        thv = tpay.take(thk).astype(np.int64)
        step = np.diff(thv, prepend=st.th_raw)
        wrap = step < -(TIME_HIGH_WRAP // 2)
        loops = st.loops + np.cumsum(wrap)
        np.add(thv, loops * TIME_HIGH_WRAP, out=high_table[1:])
        back = (step < 0) & ~wrap
        if back.any():
            st.damage("time_backward", np.count_nonzero(back), w0 + int(tpos[thk[np.argmax(back)]]))
        st.stats["time_jumps"] += int(np.count_nonzero(step > 1))
        st.stats["time_loops"] += int(loops[-1] - st.loops)
        st.th_raw, st.loops = int(thv[-1]), int(loops[-1])
        # TIME_LOW resets to 0 when TIME_HIGH changes; a repeated TIME_HIGH keeps it.
        setter[thk] = step != 0
    low_sel = np.flatnonzero(setter)
    low_table = np.empty(len(low_sel) + 1, np.int64)
    low_table[0] = st.tl
    low_table[1:] = tpay.take(low_sel)
    low_table[1:][tth.take(low_sel)] = 0
    t_table = np.empty(len(tpos) + 1, np.int64)
    t_table[0] = st.t_us
    np.left_shift(high_table.take(_index_before(tth)), 12, out=t_table[1:])
    t_table[1:] |= low_table.take(_index_before(setter))
    st.t_us, st.tl = int(t_table[-1]), int(t_table[-1] & 0xFFF)
    return t_table


def _index_before(mask: np.ndarray) -> np.ndarray:
    """Inclusive running count of ``mask`` (int32 when it fits: much faster than int64)."""
    return np.cumsum(mask, dtype=np.int32 if len(mask) < (1 << 31) else np.int64)


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

    Notes
    -----
    The state in force at each word (time, y) is found with running counts of the words
    that set it (``cumsum`` of a mask) used as indices into small per-batch tables; a
    vector word's events are expanded with ``unpackbits`` of its mask.
    """
    w = words
    w0 = st.words_seen
    st.words_seen += len(w)
    st.stats["words"] += len(w)
    if len(w):
        st.last_words = (st.last_words + tuple(int(v) for v in w[-3:]))[-3:]
    if not st.started:
        is_th = (w >> 12) == _TIME_HIGH
        skip = int(np.argmax(is_th)) if len(w) else 0
        if len(w) == 0 or not is_th[skip]:
            st.stats["words_before_time_high"] += len(w)
            return EMPTY_EVENTS, EMPTY_TRIGGERS
        st.stats["words_before_time_high"] += skip
        w = w[skip:]
        w0 += skip
        st.started = True
        st.first_th = st.th_raw = int(w[0] & 0xFFF)
        st.t_us = st.th_raw << 12
        st.tl = 0
    typ = w >> 12
    pay = w & 0x0FFF
    is_y = typ == _ADDR_Y
    is_x = typ == _ADDR_X
    is_vec = (typ >> 1) == (_VECT_12 >> 1)          # VECT_12 or VECT_8
    is_th = typ == _TIME_HIGH
    is_tl = typ == _TIME_LOW
    is_vb = typ == _VECT_BASE_X
    is_tr = typ == _EXT_TRIGGER
    n_y, n_x, n_vec, n_th, n_tl, n_vb, n_tr = (int(np.count_nonzero(m)) for m in
                                               (is_y, is_x, is_vec, is_th, is_tl, is_vb, is_tr))
    n_other = int(np.count_nonzero((typ == 0x7) | (typ >= 0xD)))
    st.stats["others"] += n_other
    n_unknown = len(w) - (n_y + n_x + n_vec + n_th + n_tl + n_vb + n_tr + n_other)
    if n_unknown:
        first = int(np.argmax(np.isin(typ, _UNKNOWN_TYPES)))
        st.damage("unknown_words", n_unknown, w0 + first)

    t_table = _time_table(is_th, is_tl, pay, st, w0) if n_th + n_tl else np.array([st.t_us], np.int64)
    y_table = np.empty(n_y + 1, np.uint16)
    y_table[0] = st.y
    if n_y:
        y_table[1:] = pay.take(np.flatnonzero(is_y))
        st.y = int(y_table[-1])

    def state_at(pos):
        """(t_us, y payload) in force at word positions ``pos``."""
        t = t_table.take(_index_before(is_th | is_tl).take(pos)) if len(t_table) > 1 else \
            np.full(len(pos), t_table[0])
        y = y_table.take(_index_before(is_y).take(pos)) if n_y else np.full(len(pos), y_table[0], np.uint16)
        return t, y

    triggers = EMPTY_TRIGGERS
    if n_tr:
        tr = np.flatnonzero(is_tr)
        tp = pay[tr]
        triggers = triggers_from(state_at(tr)[0], (tp >> 8) & 0xF, tp & 1)
        st.stats["triggers"] += len(triggers)

    if n_vec == 0:
        if n_vb:
            last = int(pay[np.flatnonzero(is_vb)[-1]])
            st.base_x, st.base_pol = last & 0x7FF, last >> 11
        if n_x == 0:
            return EMPTY_EVENTS, triggers
        src = np.flatnonzero(is_x)               # the word that made each event
        t, y = state_at(src)
        ps = pay.take(src)
        x = ps & 0x7FF
        p = ps >> 11
    else:
        src, x, p, vec_events = _expand_vectors(typ, pay, is_x | is_vec, is_vb, n_vb, st, w0)
        if len(src) == 0:
            return EMPTY_EVENTS, triggers
        t, y = state_at(src)
    keep = None
    if int(y.max()) >= 2048:                     # no ADDR_Y yet (0xFFFF) or another system's
        keep = y < 2048
        none = y == 0xFFFF
        if none.any():
            st.damage("events_without_y", np.count_nonzero(none), w0 + int(src[np.argmax(none)]))
        st.stats["events_other_system"] += int(len(y) - np.count_nonzero(keep) - np.count_nonzero(none))
        x = np.where(keep, x, 0)
    if n_vec and vec_events is not None:
        keep = vec_events if keep is None else keep & vec_events
    bounds = in_bounds(x, y if keep is None else np.where(keep, y, 0), st, lambda i: w0 + int(src[i]))
    if bounds is not None:
        keep = bounds if keep is None else keep & bounds
    ev = make_events(len(src))
    ev["t"] = t
    ev["x"] = x
    ev["y"] = y
    ev["p"] = p
    if keep is not None:
        ev = ev[keep]
    st.stats["events"] += len(ev)
    return ev, triggers


def _expand_vectors(typ, pay, is_event, is_vb, n_vb, st: DecoderState, w0: int):
    """Events of ADDR_X and vector words in stream order.

    Returns ``(src, x, p, valid)``: the word position, x and polarity of every event, and a
    mask that is False for events of vector words with no VECT_BASE_X yet (or None).
    """
    epos = np.flatnonzero(is_event)
    etyp = typ.take(epos)
    vsel = np.flatnonzero(etyp != _ADDR_X)       # vector words among the event words
    vpos = epos.take(vsel)
    is12 = etyp[vsel] == _VECT_12
    widths = np.where(is12, 12, 8)
    cw = np.cumsum(widths)
    cw_excl = cw - widths
    total = int(cw[-1])
    vmask = pay.take(vpos)
    vmask[~is12] &= 0xFF
    # base x of each vector word: its VECT_BASE_X plus the widths of the vector words since
    if n_vb:
        vbpos = np.flatnonzero(is_vb)
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
    n_v = np.bitwise_count(vmask).astype(np.int64)
    cnt = np.ones(len(epos), np.int64)
    cnt[vsel] = n_v
    src = np.repeat(epos, cnt)
    ps = pay.take(src)
    x = (ps & 0x7FF).astype(np.int64)
    p = ps >> 11
    # where each vector word's events land in the output, and which bit each one is
    extra = n_v - 1
    out_first = vsel + np.cumsum(extra) - extra
    bits = np.unpackbits(vmask.astype("<u2").view(np.uint8).reshape(-1, 2), axis=1, bitorder="little")
    flat = np.flatnonzero(bits.view(bool))
    row, col = flat >> 4, flat & 15
    at = out_first[row] + (np.arange(len(row)) - (np.cumsum(n_v) - n_v)[row])
    x[at] = base[row] + col
    p[at] = pol[row]
    valid = None
    if no_base.any():
        valid = np.ones(len(src), bool)
        valid[at[no_base[row]]] = False
        st.damage("vectors_without_base", int(n_v[no_base].sum()), w0 + int(vpos[no_base][0]))
    return src, np.minimum(x, 0xFFFF), p, valid


def finish(st: DecoderState) -> None:
    """End of stream: count a vector triplet cut short (``VECT_BASE_X [VECT_12 [VECT_12]]``) as damage."""
    types = [v >> 12 for v in st.last_words]
    for k in (3, 2, 1):
        if len(types) >= k and types[-k:] == [_VECT_BASE_X, _VECT_12, _VECT_12][:k]:
            st.damage("incomplete_group_words", k, st.words_seen - k)
            return


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
