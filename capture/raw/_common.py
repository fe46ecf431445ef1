"""Shared pieces of the word decoders and encoders: decoder state, damage accounting, stream order."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from capture.events import EVENT_DTYPE, TRIGGER_DTYPE

STAT_KEYS = (
    "words",                     # complete words decoded
    "events",                    # CD events emitted
    "triggers",                  # trigger events emitted
    "words_before_time_high",    # words skipped before the first TIME_HIGH (not damage)
    "events_without_y",          # EVT3 ADDR_X / vector before any ADDR_Y in the stream (damage)
    "vectors_without_base",      # EVT3 VECT_12 / VECT_8 before any VECT_BASE_X (damage)
    "events_other_system",       # EVT3 ADDR_Y system-type bit set: another camera's events, dropped
    "events_out_of_bounds",      # x >= width or y >= height: dropped (damage)
    "time_backward",             # TIME_HIGH steps backwards that are not a wrap (jitter/damage)
    "events_time_backward",      # CD events earlier than an event before them (e.g. a damaged TIME_LOW word)
    "time_jumps",                # TIME_HIGH forward steps larger than one unit (gap or loss)
    "time_loops",                # TIME_HIGH wrap-arounds counted into the 64-bit time
    "others",                    # OTHERS / CONTINUED / IMU words (no CD events)
    "unknown_words",             # words of an undefined type (ignored)
    "trailing_bytes",            # bytes of an incomplete word at the end of the stream (damage)
    "incomplete_group_words",    # EVT3: words of a vector triplet cut off by the end of the stream
)
DAMAGE_KEYS = ("events_without_y", "vectors_without_base", "events_out_of_bounds",
               "time_backward", "events_time_backward", "unknown_words", "trailing_bytes", "incomplete_group_words")
"""Counters that indicate damaged or foreign input."""


@dataclass
class DecoderState:
    """Everything a word decoder carries from one batch of words to the next.

    Times are in the format's TIME_HIGH units (``th``) and µs (``t_us``).
    """

    width: int | None = None
    height: int | None = None
    started: bool = False          # a TIME_HIGH has been seen
    th_raw: int = 0                # last TIME_HIGH payload as sent (wrapping)
    loops: int = 0                 # wrap-arounds so far
    t_us: int = 0                  # current time (64-bit, not shifted)
    t_max: int = -(1 << 62)        # latest CD event time emitted so far (µs, not shifted)
    tl: int = 0                    # EVT3: last TIME_LOW payload
    y: int = 0xFFFF                # EVT3: last ADDR_Y payload incl. system bit (0xFFFF: none yet)
    base_x: int = -1               # EVT3: next vector base x (-1: no VECT_BASE_X yet)
    base_pol: int = 0              # EVT3: vector polarity
    first_th: int | None = None    # first TIME_HIGH payload (for Metavision's time shift)
    words_seen: int = 0            # words consumed so far (for damage offsets)
    last_words: tuple = ()         # EVT3: the stream's last (up to 3) words, to spot a cut-off triplet
    first_damage_word: int | None = None
    stats: dict = field(default_factory=lambda: dict.fromkeys(STAT_KEYS, 0))

    def damage(self, key: str, count: int, word_index: int) -> None:
        """Count ``count`` damaged items of kind ``key``; remember the first damaged word."""
        if count:
            self.stats[key] += int(count)
            if self.first_damage_word is None or word_index < self.first_damage_word:
                self.first_damage_word = int(word_index)


def first_of_type(words: np.ndarray, shift: int, word_type: int) -> int:
    """Index of the first word with ``word >> shift == word_type`` (-1 if none); looks at a short prefix first."""
    for stop in (64, len(words)):
        hits = np.flatnonzero((words[:stop] >> shift) == word_type)
        if len(hits):
            return int(hits[0])
        if stop >= len(words):
            break
    return -1


EMPTY_EVENTS = np.zeros(0, dtype=EVENT_DTYPE)
EMPTY_TRIGGERS = np.zeros(0, dtype=TRIGGER_DTYPE)


def check_events(events: np.ndarray, triggers: np.ndarray | None, width: int, height: int,
                 max_channel: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate arrays handed to an encoder; returns them as EVENT_DTYPE / TRIGGER_DTYPE."""
    events = np.asarray(events)
    if events.dtype != EVENT_DTYPE:
        raise TypeError(f"events must have EVENT_DTYPE, got {events.dtype}")
    triggers = EMPTY_TRIGGERS if triggers is None else np.asarray(triggers)
    if triggers.dtype != TRIGGER_DTYPE:
        raise TypeError(f"triggers must have TRIGGER_DTYPE, got {triggers.dtype}")
    if not (0 < width <= 2048 and 0 < height <= 2048):
        raise ValueError(f"geometry {width}x{height} is outside 1..2048 pixels")
    for name, arr in (("events", events), ("triggers", triggers)):
        t = arr["t"]
        if len(t) and (t[0] < 0 or np.any(t[1:] < t[:-1])):
            raise ValueError(f"{name}: t must be >= 0 and non-decreasing")
        if len(arr) and not np.isin(arr["p"], (0, 1)).all():
            raise ValueError(f"{name}: p must be 0 or 1")
    if len(events) and (events["x"].max() >= width or events["y"].max() >= height):
        raise ValueError(f"events: x must be < width={width} and y < height={height}")
    if len(triggers) and triggers["id"].max() > max_channel:
        raise ValueError(f"triggers: channel id must be <= {max_channel} in this format")
    return events, triggers


def merge_order(t_events: np.ndarray, t_triggers: np.ndarray) -> np.ndarray:
    """Stream order of events then triggers by time; at equal t, events come first.

    Returns indices into ``concatenate((events, triggers))``.
    """
    return np.argsort(np.concatenate((t_events, t_triggers)), kind="stable")


def time_high_words(high: np.ndarray, stride: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TIME_HIGH words each item needs so that no step between two of them exceeds ``stride``.

    Parameters
    ----------
    high : ndarray of int64, shape (N,)
        Extended (unwrapped) TIME_HIGH value of each item in stream order.
    stride : int
        Largest step a decoder reads without mistaking it for a wrap (a quarter of the range).

    Returns
    -------
    count : ndarray of int64, shape (N,)
        TIME_HIGH words before each item (0 when its TIME_HIGH is already current).
    item : ndarray of int64
        For every TIME_HIGH word, the item it precedes.
    value : ndarray of int64
        For every TIME_HIGH word, its extended value (wrap it with the format's mask).
    """
    gap = np.diff(high, prepend=high[:1] - 1) if len(high) else high
    count = np.where(gap > 0, (gap + stride - 1) // stride, 0)
    if len(count):
        count[0] = 1
    item = np.repeat(np.arange(len(high)), count)
    first = np.cumsum(count) - count
    rank = np.arange(len(item)) - np.repeat(first, count)
    prev = np.repeat(high - gap, count)
    value = np.minimum(prev + stride * (rank + 1), np.repeat(high, count))
    return count, item, value


