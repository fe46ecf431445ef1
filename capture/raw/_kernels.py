"""Compiled word loops of the EVT decoders (Numba, no GIL held: parts of a file decode in parallel threads).

Each kernel walks the words once against the decoder state, writes the events and triggers
into the arrays it is given (stopping early when they might overflow), counts statistics into
an int64 array indexed as :data:`capture.raw._common.STAT_KEYS` and returns the stream index of
its first damaged word. The state array is read at entry and written at exit (see the ``S_*``
indices). Word layouts are documented in :mod:`capture.raw.evt3` and :mod:`capture.raw.evt2`;
:func:`run_kernel` is the way in.
"""

from __future__ import annotations

import functools

import numba
import numpy as np

from capture.events import EVENT_DTYPE, TRIGGER_DTYPE, as_void, concatenate
from capture.raw._common import STAT_KEYS, DecoderState

_K = {key: i for i, key in enumerate(STAT_KEYS)}
K_EVENTS, K_TRIGGERS = _K["events"], _K["triggers"]
K_WITHOUT_Y, K_WITHOUT_BASE, K_OTHER_SYSTEM = _K["events_without_y"], _K["vectors_without_base"], _K["events_other_system"]
K_OUT_OF_BOUNDS, K_TIME_BACKWARD, K_EVENTS_BACKWARD = (_K["events_out_of_bounds"], _K["time_backward"],
                                                       _K["events_time_backward"])
K_JUMPS, K_LOOPS, K_OTHERS, K_UNKNOWN = _K["time_jumps"], _K["time_loops"], _K["others"], _K["unknown_words"]

S_TH_RAW, S_LOOPS, S_HIGH, S_TL, S_T_MAX, S_Y, S_BASE_X, S_BASE_POL = range(8)
"""Indices into the state array: last TIME_HIGH payload, wrap-arounds, extended TIME_HIGH in
force, TIME_LOW (EVT3), latest event time (µs), ADDR_Y (EVT3), vector base x and polarity (EVT3)."""

NO_DAMAGE = np.iinfo(np.int64).max

_JIT = dict(nogil=True, cache=True, boundscheck=False)


@numba.njit(**_JIT)
def _put(ev, n, t, x, y, p):
    """Write event ``n``."""
    e = ev[n]
    e.t = t
    e.x = x
    e.y = y
    e.p = p


@numba.njit(**_JIT)
def _put_trigger(tr, m, t, channel, value):
    """Write trigger ``m``."""
    r = tr[m]
    r.t = t
    r.id = channel
    r.p = value


@numba.njit(**_JIT)
def _time_high(pay, th_raw, loops, half_wrap, stats, damage, word):
    """A TIME_HIGH word with payload ``pay`` after ``th_raw``: a step back by ``half_wrap`` or more is
    a wrap (one more loop), a smaller one damage. Returns ``(step, loops, damage)``."""
    step = pay - th_raw
    if step < -half_wrap:
        loops += 1
        stats[K_LOOPS] += 1
    elif step < 0:
        stats[K_TIME_BACKWARD] += 1
        damage = min(damage, word)
    if step > 1:
        stats[K_JUMPS] += 1
    return step, loops, damage


@numba.njit(**_JIT)
def _odd_event(ev, n, t, x, y, pol, t_max, damage, word, width, height, stats):
    """An event the fast path did not take (no row yet, another system's, outside the sensor or
    earlier than one before it): counted, and written unless dropped. Returns ``(n, t_max, damage)``."""
    if y >= 2048:
        if y == 0xFFFF:
            stats[K_WITHOUT_Y] += 1
            damage = min(damage, word)
        else:
            stats[K_OTHER_SYSTEM] += 1
        return n, t_max, damage
    if x >= width or y >= height:
        stats[K_OUT_OF_BOUNDS] += 1
        return n, t_max, min(damage, word)
    if t < t_max:
        stats[K_EVENTS_BACKWARD] += 1
        damage = min(damage, word)
    else:
        t_max = t
    _put(ev, n, t, x, y, pol)
    return n + 1, t_max, damage


@numba.njit(**_JIT)
def evt3(words, start, w0, width, height, state, stats, ev, tr):
    """Decode EVT3 ``words`` (uint16) from index ``start`` on (stream word ``w0`` is ``words[0]``).

    ``width`` / ``height`` of 0 mean unknown (no bounds check). ``ev`` / ``tr`` are EVENT_DTYPE /
    TRIGGER_DTYPE arrays to write into (records: faster than column views). Returns
    ``(stop, events, triggers, first_damage)``: the loop stops before word ``stop`` when the
    outputs might not hold its events; ``first_damage`` is the stream index of the first damaged
    word (``NO_DAMAGE`` if none).
    """
    th_raw = state[S_TH_RAW]
    loops = state[S_LOOPS]
    high = state[S_HIGH]
    tl = state[S_TL]
    t_max = state[S_T_MAX]
    y = state[S_Y]
    base_x = state[S_BASE_X]
    base_pol = state[S_BASE_POL]
    if width <= 0 or height <= 0:
        width = height = 1 << 16
    y_ok = y < min(height, 2048)
    damage = NO_DAMAGE
    t = (high << 12) | tl
    n = 0
    m = 0
    stop = len(words)
    for i in range(start, len(words)):
        w = np.int64(words[i])
        typ = w >> 12
        pay = w & 0xFFF
        if typ == 0x2:
            if n + 12 > len(ev):
                stop = i
                break
            x = pay & 0x7FF
            if y_ok and x < width and t >= t_max:
                _put(ev, n, t, x, y, pay >> 11)
                n += 1
                t_max = t
            else:
                n, t_max, damage = _odd_event(ev, n, t, x, y, pay >> 11, t_max, damage, w0 + i, width, height, stats)
        elif typ == 0x0:
            y = pay
            y_ok = y < min(height, 2048)
        elif typ == 0x6:
            tl = pay
            t = (high << 12) | tl
        elif typ == 0x4 or typ == 0x5:
            if n + 12 > len(ev):
                stop = i
                break
            bits = pay if typ == 0x4 else pay & 0xFF
            if base_x < 0:
                while bits:
                    stats[K_WITHOUT_BASE] += bits & 1
                    damage = min(damage, w0 + i)
                    bits >>= 1
                continue
            x0 = min(base_x, 0xFFF0)
            base_x += 12 if typ == 0x4 else 8
            fast = y_ok and x0 + 12 <= width and t >= t_max
            k = 0
            while bits:
                if bits & 1:
                    if fast:
                        _put(ev, n, t, x0 + k, y, base_pol)
                        n += 1
                        t_max = t
                    else:
                        n, t_max, damage = _odd_event(ev, n, t, x0 + k, y, base_pol, t_max, damage, w0 + i,
                                                      width, height, stats)
                bits >>= 1
                k += 1
        elif typ == 0x8:
            step, loops, damage = _time_high(pay, th_raw, loops, 2048, stats, damage, w0 + i)
            if step != 0:
                tl = 0
            th_raw = pay
            high = pay + (loops << 12)
            t = (high << 12) | tl
        elif typ == 0x3:
            base_x = pay & 0x7FF
            base_pol = pay >> 11
        elif typ == 0xA:
            if m == len(tr):
                stop = i
                break
            _put_trigger(tr, m, t, (pay >> 8) & 0xF, pay & 1)
            m += 1
        elif typ == 0x7 or typ >= 0xD:
            stats[K_OTHERS] += 1
        else:
            stats[K_UNKNOWN] += 1
            damage = min(damage, w0 + i)
    state[S_TH_RAW] = th_raw
    state[S_LOOPS] = loops
    state[S_HIGH] = high
    state[S_TL] = tl
    state[S_T_MAX] = t_max
    state[S_Y] = y
    state[S_BASE_X] = base_x
    state[S_BASE_POL] = base_pol
    return stop, n, m, damage


@numba.njit(**_JIT)
def _odd_cd(ev, n, t, x, y, pol, t_max, damage, word, width, height, stats):
    """An EVT2 CD word the fast path did not take (earlier than one before it, or outside the
    sensor): time order first, then bounds. Returns ``(n, t_max, damage)``."""
    if t < t_max:
        stats[K_EVENTS_BACKWARD] += 1
        damage = min(damage, word)
    else:
        t_max = t
    if x >= width or y >= height:
        stats[K_OUT_OF_BOUNDS] += 1
        return n, t_max, min(damage, word)
    _put(ev, n, t, x, y, pol)
    return n + 1, t_max, damage


@numba.njit(**_JIT)
def evt2(head, mask, start, w0, width, height, state, stats, ev, tr):
    """Decode EVT 2.0 headers (``mask`` None) or EVT 2.1 events (headers + validity masks).

    Like :func:`evt3`; the time order is checked per CD word, before the bounds (as one word
    stands for all its events).
    """
    th_raw = state[S_TH_RAW]
    loops = state[S_LOOPS]
    high = state[S_HIGH]
    t_max = state[S_T_MAX]
    if width <= 0 or height <= 0:
        width = height = 1 << 16
    damage = NO_DAMAGE
    n = 0
    m = 0
    stop = len(head)
    for i in range(start, len(head)):
        w = np.int64(head[i])
        typ = w >> 28
        if typ <= 1:
            t = (high << 6) | ((w >> 22) & 0x3F)
            x0 = (w >> 11) & 0x7FF
            y = w & 0x7FF
            if mask is None:
                if n == len(ev):
                    stop = i
                    break
                if t >= t_max and x0 < width and y < height:
                    _put(ev, n, t, x0, y, typ)
                    n += 1
                    t_max = t
                else:
                    n, t_max, damage = _odd_cd(ev, n, t, x0, y, typ, t_max, damage, w0 + i, width, height, stats)
                continue
            if n + 32 > len(ev):
                stop = i
                break
            if t < t_max:
                stats[K_EVENTS_BACKWARD] += 1
                damage = min(damage, w0 + i)
            else:
                t_max = t
            bits = np.int64(mask[i])
            k = 0
            while bits:
                if bits & 1:
                    if x0 + k < width and y < height:
                        _put(ev, n, t, x0 + k, y, typ)
                        n += 1
                    else:
                        stats[K_OUT_OF_BOUNDS] += 1
                        damage = min(damage, w0 + i)
                bits >>= 1
                k += 1
        elif typ == 0x8:
            pay = w & 0x0FFFFFFF
            step, loops, damage = _time_high(pay, th_raw, loops, 1 << 27, stats, damage, w0 + i)
            th_raw = pay
            high = pay + (loops << 28)
        elif typ == 0xA:
            if m == len(tr):
                stop = i
                break
            _put_trigger(tr, m, (high << 6) | ((w >> 22) & 0x3F), (w >> 8) & 0x1F, w & 1)
            m += 1
        elif typ >= 0xD:
            stats[K_OTHERS] += 1
        else:
            stats[K_UNKNOWN] += 1
            damage = min(damage, w0 + i)
    state[S_TH_RAW] = th_raw
    state[S_LOOPS] = loops
    state[S_HIGH] = high
    state[S_T_MAX] = t_max
    return stop, n, m, damage


def run_kernel(kernel, words: tuple, st: DecoderState, w0: int, time_low_bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Run a compiled word loop (:func:`evt3`, :func:`evt2`) on ``words`` (its word arrays; the
    first word is stream word ``w0``) against ``st`` (updated in place); returns ``(events, triggers)``.

    ``time_low_bits`` is the width of the time below TIME_HIGH (12 in EVT3, 6 in EVT2). The
    outputs hold as many events as words (and a few triggers) at first; when the loop stops
    for room, it resumes into arrays sized by the events per word seen so far.
    """
    words = tuple(None if w is None else _read_only(w) for w in words)  # one compiled version for all
    state = np.array([st.th_raw, st.loops, st.t_us >> time_low_bits, st.tl, st.t_max, st.y, st.base_x,
                      st.base_pol], np.int64)
    stats = np.zeros(len(STAT_KEYS), np.int64)
    width, height = (st.width, st.height) if st.width is not None and st.height is not None else (0, 0)
    n_words = len(words[0])
    events, triggers = [], []
    first_damage = NO_DAMAGE
    start, room_events, room_triggers = 0, n_words + 32, 64
    while True:
        ev = np.empty(room_events, EVENT_DTYPE)
        tr = np.empty(room_triggers, TRIGGER_DTYPE)
        stop, n, m, damage = kernel(*words, start, w0, width, height, state, stats, ev, tr)
        first_damage = min(first_damage, damage)
        events.append(_trimmed(ev, n))
        triggers.append(_trimmed(tr, m))
        if stop == n_words:
            break
        left = n_words - stop
        per_word = sum(map(len, events)) / max(stop, 1)
        room_events = int(left * max(per_word, 1.0) * 1.25) + 32
        room_triggers = left if m == room_triggers else 64
        start = stop
    st.th_raw, st.loops, high, st.tl, st.t_max, st.y, st.base_x, st.base_pol = (int(v) for v in state)
    st.t_us = (high << time_low_bits) | st.tl
    events, triggers = concatenate(events, EVENT_DTYPE), concatenate(triggers, TRIGGER_DTYPE)
    stats[K_EVENTS], stats[K_TRIGGERS] = len(events), len(triggers)
    for key, count in zip(STAT_KEYS, stats.tolist()):
        st.stats[key] += count
    if first_damage != NO_DAMAGE:
        st.first_damage_word = first_damage if st.first_damage_word is None else min(first_damage,
                                                                                       st.first_damage_word)
    return events, triggers


def _trimmed(records: np.ndarray, n: int) -> np.ndarray:
    """The first ``n`` records (a copy when half the array would be left unused: a view keeps it all;
    copied as raw bytes, 17x faster than NumPy's copy of packed records)."""
    return as_void(records[:n]).copy().view(records.dtype) if n < len(records) // 2 else records[:n]


def _read_only(words: np.ndarray) -> np.ndarray:
    """A read-only view (words from ``bytes`` are read-only, from a reused buffer writable: Numba
    would compile the loop once for each)."""
    view = words.view()
    view.flags.writeable = False
    return view


@functools.cache
def load(format: str) -> None:
    """Load the word loop of ``format`` (``"EVT2"``, ``"EVT21"``, ``"EVT3"``) now, not at the first
    batch: from the cache (about 0.5 s once per process) or, the first time, compiled (seconds).
    Once per format and process (a second thread asking meanwhile waits on Numba's lock)."""
    empty = np.zeros(0, np.uint32)
    if format == "EVT3":
        run_kernel(evt3, (np.zeros(0, np.uint16),), DecoderState(), 0, time_low_bits=12)
    else:
        run_kernel(evt2, (empty, None if format == "EVT2" else empty), DecoderState(), 0, time_low_bits=6)
