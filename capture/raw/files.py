"""Whole-file API: :func:`read` a RAW file into arrays, :func:`write` arrays as a RAW file,
:func:`scan` / :func:`info` a file's counts and time range without keeping its events."""

from __future__ import annotations

import os
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from capture.events import EVENT_DTYPE, TRIGGER_DTYPE, concatenate
from capture.raw import evt2, evt3
from capture.raw.errors import RawDamageWarning, RawFormatError
from capture.raw.header import header_bytes, normalize_format
from capture.raw.stream import DEFAULT_CHUNK_BYTES, MAX_THREADS, PARALLEL_MIN_BYTES, WRAP_US, RawReader


@dataclass
class RawFile:
    """A decoded RAW file.

    Attributes
    ----------
    events : ndarray of EVENT_DTYPE, shape (N,)
        CD events in file order (t µs, 64-bit, the sensor's own clock unless time-shifted).
    triggers : ndarray of TRIGGER_DTYPE, shape (M,)
        External trigger events in file order.
    width, height : int
        Sensor geometry in pixels.
    format : str
        ``"EVT2"``, ``"EVT21"`` or ``"EVT3"``.
    header : dict
        Parsed header (see :func:`capture.raw.parse_header`).
    stats : dict
        Decoder counters (see :class:`capture.raw.StreamDecoder`).
    time_shift_us : int
        µs subtracted from every t (0 unless read with ``time_shift=True``).
    """

    events: np.ndarray
    triggers: np.ndarray
    width: int
    height: int
    format: str
    header: dict
    stats: dict = field(default_factory=dict)
    time_shift_us: int = 0


def read(path, *, time_shift: bool = False, strict: bool = False, format: str | None = None,
         width: int | None = None, height: int | None = None,
         chunk_bytes: int = PARALLEL_MIN_BYTES, threads: int | None = None) -> RawFile:
    """Read and decode a whole RAW file.

    Parameters
    ----------
    path : str or Path
        The RAW file (header + event words).
    time_shift : bool
        Subtract Metavision's default time shift (see :class:`capture.raw.StreamDecoder`).
    strict : bool
        Raise :class:`RawFormatError` on damage instead of warning.
    format, width, height : optional
        Override (or supply, for header-less files) the header's format and geometry.
    chunk_bytes : int
        Bytes decoded per batch. A file of fewer bytes than this and than
        :data:`~capture.raw.stream.PARALLEL_MIN_BYTES` is decoded in one batch, straight into
        the result (batches are joined, a copy, otherwise).
    threads : int, optional
        Parts of the file decoded at once (default: the machine's cores, at most 4); the
        result is the same for any number (see :class:`capture.raw.RawReader`).

    Raises
    ------
    RawFormatError
        Empty file, unknown or missing format, missing geometry; with ``strict``, any damage
        (message: file, byte offset, counts).
    FileNotFoundError
        No such file.

    Warns
    -----
    RawDamageWarning
        Damage was found (truncated word, words before any ADDR_Y, unknown words, events
        outside the sensor...); everything decodable was kept.
    """
    if threads is None:
        threads = min(os.cpu_count() or 1, MAX_THREADS)
    reader = RawReader(path, chunk_bytes=chunk_bytes, format=format, width=width, height=height,
                       time_shift=time_shift, threads=threads)
    if reader.width is None or reader.height is None:
        reader.close()
        raise RawFormatError(f"{path}: the header gives no sensor geometry; pass width= and height=")
    ev_parts, tr_parts = [], []
    for events, triggers in reader:
        ev_parts.append(events)
        tr_parts.append(triggers)
    message = reader.damage_message()
    if message:
        if strict:
            raise RawFormatError(message)
        warnings.warn(message, RawDamageWarning, stacklevel=2)
    return RawFile(
        events=concatenate([e for e in ev_parts if len(e)], EVENT_DTYPE),
        triggers=concatenate([t for t in tr_parts if len(t)], TRIGGER_DTYPE),
        width=int(reader.width), height=int(reader.height), format=reader.format,
        header=reader.header, stats=reader.decoder.stats, time_shift_us=reader.decoder.time_shift_us)


def encode(events: np.ndarray, triggers: np.ndarray | None = None, *, format: str = "EVT3",
           width: int, height: int) -> bytes:
    """Event words (no header) for ``events`` / ``triggers`` in EVT3 or EVT2, little-endian.

    The words carry t modulo the format's wrap period (2^24 µs EVT3, 2^34 µs EVT2); decode
    with ``StreamDecoder(format, time_base_us=t0 // period * period)`` to get t back in full
    (:func:`write` stores that value in the header).
    """
    fmt = normalize_format(format)
    if fmt == "EVT3":
        return evt3.encode(events, triggers, width=width, height=height).astype("<u2").tobytes()
    if fmt == "EVT2":
        return evt2.encode(events, triggers, width=width, height=height).astype("<u4").tobytes()
    raise ValueError(f"writing {fmt} is not supported (EVT3 or EVT2)")


def write(path, events: np.ndarray, triggers: np.ndarray | None = None, *, format: str = "EVT3",
          width: int, height: int, **header_fields) -> int:
    """Write events (and triggers) as a RAW file with a modern header.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten). Written to ``path.tmp`` first, then renamed.
    events : ndarray of EVENT_DTYPE
        t non-decreasing, inside the geometry.
    triggers : ndarray of TRIGGER_DTYPE, optional
    format : str
        ``"EVT3"`` (compact, vectorised) or ``"EVT2"``.
    width, height : int
        Sensor geometry in pixels.
    **header_fields
        Extra header fields (``serial_number=...``, ``plugin_name=...``). ``time_base_us`` is
        added when the first t is past the format's first wrap period.

    Returns
    -------
    int
        Bytes written.
    """
    fmt = normalize_format(format)
    t0 = min([int(a["t"][0]) for a in (events, triggers) if a is not None and len(a)], default=0)
    time_base_us = t0 // WRAP_US[fmt] * WRAP_US[fmt]
    if time_base_us:
        header_fields["time_base_us"] = time_base_us
    data = header_bytes(fmt, width=width, height=height, **header_fields) + \
        encode(events, triggers, format=fmt, width=width, height=height)
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)
    return len(data)


def scan(reader: RawReader, on_batch=None, progress: bool = False) -> dict:
    """Decode every batch of ``reader``; ``on_batch(events, triggers)`` sees each one.

    Returns
    -------
    dict
        ``events``, ``events_on``, ``triggers`` (counts), ``t_first_us``, ``t_last_us``,
        ``duration_us`` (µs; None / 0 without events) and ``rate_ev_s`` (mean event rate, ev/s).
    """
    n_ev = n_tr = n_on = 0
    t_first = t_last = None
    bar = tqdm(total=reader.size_bytes, unit="B", unit_scale=True, disable=not progress,
               desc="decoding", file=sys.stderr)
    done = 0
    for events, triggers in reader:
        if len(events):
            n_ev += len(events)
            n_on += int(np.count_nonzero(events["p"]))
            t_first = int(events["t"][0]) if t_first is None else t_first
            t_last = int(events["t"][-1])
        n_tr += len(triggers)
        if on_batch is not None:
            on_batch(events, triggers)
        now = reader.decoder.bytes_in + reader.header_size
        bar.update(now - done)
        done = now
    bar.close()
    duration_us = (t_last - t_first) if t_first is not None else 0
    return {"events": n_ev, "events_on": n_on, "triggers": n_tr, "t_first_us": t_first, "t_last_us": t_last,
            "duration_us": duration_us,
            "rate_ev_s": n_ev / (duration_us * 1e-6) if duration_us > 0 else None}


def info(path, *, chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> dict:
    """Header, format, geometry (px), counts, duration (µs) and mean event rate (ev/s) of a RAW file."""
    reader = RawReader(path, chunk_bytes=chunk_bytes)
    summary = scan(reader)
    return {"file": str(path), "format": reader.format, "width": reader.width, "height": reader.height,
            "header_style": reader.header["style"], "header": reader.header["fields"],
            "header_bytes": reader.header_size, "size_bytes": reader.size_bytes, **summary,
            "damage": reader.damage_message(), "stats": reader.decoder.stats}
