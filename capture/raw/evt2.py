"""EVT 2.0 (32-bit words) and EVT 2.1 (64-bit vectorised words): decoders (a compiled word loop), EVT2 encoder.

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

from capture.raw import _kernels
from capture.raw._common import (EMPTY_EVENTS, EMPTY_TRIGGERS, DecoderState, check_events, first_of_type, merge_order,
                                  time_high_words)
from capture.raw._kernels import run_kernel

TIME_HIGH_WRAP = 1 << 28
"""TIME_HIGH values per loop; one loop is 2^34 µs."""

_TIME_HIGH, _EXT_TRIGGER = 0x8, 0xA


def _decode(head: np.ndarray, mask: np.ndarray | None, st: DecoderState) -> tuple[np.ndarray, np.ndarray]:
    """Shared EVT2 / EVT2.1 decoder: ``head`` are the u32 headers, ``mask`` the EVT2.1 masks.

    One compiled pass over the words (:func:`capture.raw._kernels.evt2`). The time order is
    checked per CD word, before events outside the sensor are dropped (damage).
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
    return run_kernel(_kernels.evt2, (head, mask), st, w0, time_low_bits=6)


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
