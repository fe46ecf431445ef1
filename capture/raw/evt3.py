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

from capture.raw._common import (EMPTY_EVENTS, EMPTY_TRIGGERS, DecoderState, check_events, check_time_order,
                                  first_of_type,
                                  in_bounds, make_events, merge_order, time_high_words, triggers_from, xy_view)

TIME_HIGH_WRAP = 1 << 12
"""TIME_HIGH values per loop; one loop is 2^24 µs."""

_ADDR_Y, _ADDR_X, _VECT_BASE_X, _VECT_12, _VECT_8 = 0x0, 0x2, 0x3, 0x4, 0x5
_TIME_LOW, _TIME_HIGH, _EXT_TRIGGER = 0x6, 0x8, 0xA
_OTHER_TYPES = (0x7, 0xD, 0xE, 0xF)
_UNKNOWN_TYPES = (0x1, 0x9, 0xB, 0xC)


def _select_table() -> np.ndarray:
    """``table[m, k]``: index of the k-th set bit of the 12-bit mask ``m`` (uint8, 4096 x 12)."""
    bits = np.unpackbits(np.arange(4096, dtype="<u2").view(np.uint8).reshape(-1, 2), axis=1,
                         bitorder="little")[:, :12]
    table = np.zeros((4096, 12), np.uint8)
    rows, cols = np.nonzero(bits)
    n_set = bits.sum(1, dtype=np.int64)
    rank = np.arange(len(rows)) - np.repeat(np.cumsum(n_set) - n_set, n_set)
    table[rows, rank] = cols
    return table


_SET_BIT = _select_table()


def _running(mask: np.ndarray) -> np.ndarray:
    """Inclusive running count of ``mask`` (int32 when it fits: much faster than int64)."""
    return np.cumsum(mask, dtype=np.int32 if len(mask) < (1 << 31) else np.int64)


def _lookup(table: np.ndarray, run: np.ndarray, n_queries: int):
    """``f(k)`` = value of ``table`` in force after state word ``k`` (``run`` indexes ``table``).

    Materialises the per-state-word values when there are more queries than state words,
    otherwise composes the two lookups per query.
    """
    if n_queries >= len(run):
        per_state = table.take(run)
        return per_state.take
    return lambda k: table.take(run.take(k))


def _running0(mask: np.ndarray) -> np.ndarray:
    """Running count of ``mask`` with a leading 0: index into a table whose entry 0 is the prior state."""
    out = np.empty(len(mask) + 1, np.int32 if len(mask) < (1 << 31) else np.int64)
    out[0] = 0
    np.cumsum(mask, out=out[1:])
    return out


def _time_lookup(styp, spay, st: DecoderState, w0: int, spos):
    """Time (µs) in force after each state word, from its TIME_LOW / TIME_HIGH words.

    ``styp`` / ``spay`` are the types / payloads of the batch's state words (positions
    ``spos``). Returns ``make(n_queries)`` giving ``f(k)`` = time after state word ``k - 1``
    (``k = 0``: the time before the batch), built for ``n_queries`` lookups (see
    :func:`_lookup`). Updates the time part of ``st`` and its statistics.
    """
    is_th = styp == _TIME_HIGH
    setter = styp == _TIME_LOW                  # words that set time_low (+ changed TIME_HIGH)
    thsel = np.flatnonzero(is_th)
    high_table = np.empty(len(thsel) + 1, np.int64)
    high_table[0] = st.t_us >> 12
    if len(thsel):
        thv = spay.take(thsel).astype(np.int64)
        step = np.diff(thv, prepend=st.th_raw)
        wrap = step < -(TIME_HIGH_WRAP // 2)
        loops = st.loops + np.cumsum(wrap)
        np.add(thv, loops * TIME_HIGH_WRAP, out=high_table[1:])
        back = (step < 0) & ~wrap
        if back.any():
            st.damage("time_backward", np.count_nonzero(back), w0 + int(spos[thsel[np.argmax(back)]]))
        st.stats["time_jumps"] += int(np.count_nonzero(step > 1))
        st.stats["time_loops"] += int(loops[-1] - st.loops)
        st.th_raw, st.loops = int(thv[-1]), int(loops[-1])
        # TIME_LOW resets to 0 when TIME_HIGH changes; a repeated TIME_HIGH keeps it.
        setter[thsel[step != 0]] = True
    low_sel = np.flatnonzero(setter)
    low_table = np.empty(len(low_sel) + 1, np.int64)
    low_table[0] = st.tl
    low_table[1:] = spay.take(low_sel)
    low_table[1:][is_th.take(low_sel)] = 0
    st.tl = int(low_table[-1])
    st.t_us = (int(high_table[-1]) << 12) | st.tl
    h_run = _running0(is_th)
    l_run = _running0(setter)

    def make(n_queries: int):
        if n_queries < len(h_run):
            return lambda k: (high_table.take(h_run.take(k)) << 12) | low_table.take(l_run.take(k))
        t_state = high_table.take(h_run)
        t_state <<= 12
        t_state |= low_table.take(l_run)
        return t_state.take
    return make


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
    The words that change decoder state (TIME_LOW/HIGH, ADDR_Y, VECT_BASE_X and the vector
    words) are pulled out into a small "state table" where time, y and vector base are
    forward-filled with running counts; every ADDR_X word then reads its state with one
    index (its count of state words before it), and vector words expand through a
    k-th-set-bit lookup table.
    """
    w = words
    w0 = st.words_seen
    st.words_seen += len(w)
    st.stats["words"] += len(w)
    if len(w):
        st.last_words = (st.last_words + tuple(int(v) for v in w[-3:]))[-3:]
    if not st.started:
        skip = first_of_type(w, 12, _TIME_HIGH)
        if skip < 0:
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
    is_x = typ == _ADDR_X
    is_vec = (typ >> 1) == (_VECT_12 >> 1)          # VECT_12 or VECT_8
    is_state = (typ == _ADDR_Y) | (typ == _TIME_LOW) | (typ == _TIME_HIGH) | (typ == _VECT_BASE_X) | is_vec
    is_tr = typ == _EXT_TRIGGER
    n_x, n_vec, n_state, n_tr = (int(np.count_nonzero(m)) for m in (is_x, is_vec, is_state, is_tr))
    n_rest = len(w) - n_x - n_state - n_tr         # OTHERS / CONTINUED / IMU / unknown words
    if n_rest:
        n_other = int(np.count_nonzero((typ == 0x7) | (typ >= 0xD)))
        st.stats["others"] += n_other
        n_unknown = n_rest - n_other
        if n_unknown:
            st.damage("unknown_words", n_unknown, w0 + int(np.argmax(np.isin(typ, _UNKNOWN_TYPES))))

    # State table: time, y and vector base in force after each state word.
    spos = np.flatnonzero(is_state)
    styp = typ.take(spos)
    spay = pay.take(spos)
    make_time_at = _time_lookup(styp, spay, st, w0, spos)
    s_is_y = styp == _ADDR_Y
    y_sel = np.flatnonzero(s_is_y)
    y_table = np.empty(len(y_sel) + 1, np.uint16)
    y_table[0] = st.y
    y_table[1:] = spay.take(y_sel)
    y_run = _running0(s_is_y)
    st.y = int(y_table[-1])

    only_x_and_state = n_tr + n_rest == 0
    if only_x_and_state:
        def state_index(pos):                        # state words before each ADDR_X word
            return pos - np.arange(len(pos))         # (every word before is a state word or ADDR_X)
    else:
        cs = _running(is_state)

        def state_index(pos):
            return cs.take(pos)

    triggers = EMPTY_TRIGGERS
    if n_tr:
        tr = np.flatnonzero(is_tr)
        tp = pay.take(tr)
        triggers = triggers_from(make_time_at(len(tr))(cs.take(tr)), (tp >> 8) & 0xF, tp & 1)
        st.stats["triggers"] += len(triggers)

    vsel = np.flatnonzero((styp >> 1) == (_VECT_12 >> 1)) if n_vec else None
    if n_vec:
        v_base, v_pol, v_mask, v_count = _vector_words(styp, spay, vsel, st, w0, spos)
    else:
        vb = np.flatnonzero(styp == _VECT_BASE_X)
        if len(vb):
            last = int(spay[vb[-1]])
            st.base_x, st.base_pol = last & 0x7FF, last >> 11
    n_events = n_x + (int(v_count.sum()) if n_vec else 0)
    if n_events == 0:
        return EMPTY_EVENTS, triggers
    t_at = make_time_at(n_events)
    y_at = _lookup(y_table, y_run, n_events)

    xpos = np.flatnonzero(is_x)
    kx = state_index(xpos)
    px = pay.take(xpos)
    if n_vec == 0:
        t = t_at(kx)
        y = y_at(kx)
        x = px & 0x7FF
        p = px >> 11

        def locate(i):
            return w0 + int(xpos[i])
    else:
        # Insert each vector word's events among the ADDR_X events: ADDR_X words before
        # vector word j = its position minus the state words before it (and other words).
        vpos = spos.take(vsel)
        x_before_v = vpos - vsel if only_x_and_state else np.searchsorted(xpos, vpos)
        v_first = np.cumsum(v_count) - v_count
        total = n_x + int(v_count.sum())
        row = np.repeat(np.arange(len(vsel)), v_count)
        at_v = (x_before_v + v_first).take(row) + (np.arange(len(row)) - v_first.take(row))
        is_v_event = np.zeros(total, bool)
        is_v_event[at_v] = True
        at_x = np.flatnonzero(~is_v_event)
        k = np.empty(total, kx.dtype)
        k[at_x] = kx
        k[at_v] = vsel.take(row) + 1
        t = t_at(k)
        y = y_at(k)
        x = np.empty(total, np.uint16)
        x[at_x] = px & 0x7FF
        rank = np.arange(len(row)) - v_first.take(row)
        x[at_v] = v_base.take(row) + _SET_BIT[v_mask.take(row), rank]
        p = np.empty(total, np.uint16)
        p[at_x] = px >> 11
        p[at_v] = v_pol.take(row)

        def locate(i):
            j = np.searchsorted(at_v, i)
            return w0 + int(vpos[row[j]] if j < len(at_v) and at_v[j] == i else xpos[np.searchsorted(at_x, i)])
    keep = None
    if int(y.max()) >= 2048:                     # no ADDR_Y yet (0xFFFF) or another system's
        keep = y < 2048
        none = y == 0xFFFF
        if none.any():
            st.damage("events_without_y", np.count_nonzero(none), locate(int(np.argmax(none))))
        st.stats["events_other_system"] += int(len(y) - np.count_nonzero(keep) - np.count_nonzero(none))
    bounds = in_bounds(x, y if keep is None else np.where(keep, y, 0), st, locate)
    if bounds is not None:
        keep = bounds if keep is None else keep & bounds
    if keep is not None:
        t, x, y, p = (a.compress(keep) for a in (t, x, y, p))
        located = locate
        locate = lambda i: located(int(np.flatnonzero(keep)[i]))  # noqa: E731 (index among the kept)
    check_time_order(t, st, locate)
    ev = make_events(len(t))
    ev["t"] = t
    xy = y.astype(np.uint32)
    xy <<= 16
    xy |= x
    xy_view(ev)[:] = xy                          # x and y in one strided write
    ev["p"] = p
    st.stats["events"] += len(ev)
    return ev, triggers


def _vector_words(styp, spay, vsel, st: DecoderState, w0: int, spos):
    """Base x, polarity, 12-bit mask and event count of every vector word (``vsel`` in the state table).

    A vector word's base is its VECT_BASE_X plus the widths (12 / 8) of the vector words
    between them; words with no VECT_BASE_X yet in the stream get no events (damage).
    """
    is12 = styp.take(vsel) == _VECT_12
    widths = np.where(is12, 12, 8)
    cw_excl = np.cumsum(widths) - widths
    total = int(cw_excl[-1] + widths[-1])
    mask = spay.take(vsel)
    mask[~is12] &= 0xFF
    s_is_vb = styp == _VECT_BASE_X
    vb_sel = np.flatnonzero(s_is_vb)
    if len(vb_sel):
        vbpay = spay.take(vb_sel)
        jb = _running(s_is_vb).take(vsel) - 1         # last VECT_BASE_X before each vector word
        start_cw = np.append(cw_excl, total).take(np.searchsorted(vsel, vb_sel))
        has = jb >= 0
        jbc = np.maximum(jb, 0)
        vb = vbpay.take(jbc)
        base = np.where(has, (vb & 0x7FF).astype(np.int64) + cw_excl - start_cw.take(jbc), st.base_x + cw_excl)
        pol = np.where(has, vb >> 11, st.base_pol)
        no_base = ~has & (st.base_x < 0)
        st.base_x = int(vbpay[-1] & 0x7FF) + total - int(start_cw[-1])
        st.base_pol = int(vbpay[-1] >> 11)
    else:
        base = st.base_x + cw_excl
        pol = np.full(len(vsel), st.base_pol)
        no_base = np.full(len(vsel), st.base_x < 0)
        if st.base_x >= 0:
            st.base_x += total
    if no_base.any():
        st.damage("vectors_without_base", int(np.bitwise_count(mask[no_base]).sum()),
                  w0 + int(spos[vsel[np.argmax(no_base)]]))
        mask[no_base] = 0
    count = np.bitwise_count(mask).astype(np.int64)
    return np.minimum(base, 0xFFF0).astype(np.uint16), pol.astype(np.uint16), mask, count


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
