"""EVT 3.0: decoder (a compiled word loop) and vectorised encoder for 16-bit little-endian words.

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

from capture.raw import _kernels
from capture.raw._common import (EMPTY_EVENTS, EMPTY_TRIGGERS, DecoderState, check_events, first_of_type, merge_order,
                                  time_high_words)
from capture.raw._kernels import run_kernel

TIME_HIGH_WRAP = 1 << 12
"""TIME_HIGH values per loop; one loop is 2^24 µs."""

_ADDR_Y, _ADDR_X, _VECT_BASE_X, _VECT_12, _VECT_8 = 0x0, 0x2, 0x3, 0x4, 0x5
_TIME_LOW, _TIME_HIGH, _EXT_TRIGGER = 0x6, 0x8, 0xA


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
    One compiled pass over the words (:func:`capture.raw._kernels.evt3`). Events are dropped
    and counted when no ADDR_Y came before them (damage), when they are another system's, or
    when outside the sensor (damage), in that order: each dropped event is counted once.
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
    return run_kernel(_kernels.evt3, (w,), st, w0, time_low_bits=12)


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
