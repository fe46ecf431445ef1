"""Streaming decode: :class:`StreamDecoder` for live byte streams, :class:`RawReader` / :func:`iter_chunks` for files.

Decoding a stream in one call or in any chunking (down to single bytes, splits inside
words, vector triplets or OTHERS groups) gives identical arrays: the decoder carries the
incomplete word and the full time / address state from one call to the next.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from capture.raw import _kernels, evt2, evt3
from capture.raw._common import DAMAGE_KEYS, EMPTY_EVENTS, EMPTY_TRIGGERS, STAT_KEYS, DecoderState
from capture.raw.errors import RawFormatError
from capture.raw.header import MAX_HEADER_BYTES, normalize_format, parse_header

WORD_BYTES = {"EVT2": 4, "EVT21": 8, "EVT3": 2}
"""Bytes per stream word (EVT2.1: one 64-bit event)."""

WRAP_US = {"EVT2": 1 << 34, "EVT21": 1 << 34, "EVT3": 1 << 24}
"""Period of the format's wrapping time base in µs."""

DEFAULT_CHUNK_BYTES = 1 << 20
"""Bytes read per batch when streaming a file (1 MiB: a batch's output arrays stay small and reusable)."""


MAX_TIME_BASE_US = 1 << 62
"""Largest time base a header may give (µs; event times must stay within int64)."""


class StreamDecoder:
    """Stateful decoder for a RAW byte stream (no header) of one format.

    Parameters
    ----------
    format : str
        ``"EVT2"``, ``"EVT21"`` or ``"EVT3"`` (usual spellings accepted).
    endianness : str
        EVT2.1 only: ``"little"`` (standard) or ``"legacy"`` (halves swapped, EVK IMX636).
    time_shift : bool
        Reproduce Metavision's default time shifting: subtract ``first_time_high << 6``
        (EVT2/2.1) or ``(first_time_high - 1) << 12`` (EVT3, if positive) from every t
        (plus ``time_base_us``).
        Default: the sensor's own timestamps.
    width, height : int, optional
        Sensor geometry; events outside it are dropped and counted as damage.
    time_base_us : int
        µs the stream's clock had already looped through before its first TIME_HIGH: a
        multiple of the wrap period (2^24 µs EVT3, 2^34 µs EVT2/2.1). Files written by
        :func:`capture.raw.write` store it in the header field ``time_base_us``.

    Attributes
    ----------
    stats : dict
        Counters (words, events, triggers, skipped and damaged items, time loops/jumps,
        ``trailing_bytes`` after :meth:`finish`) and ``first_damage_byte`` (stream offset
        of the first damaged word, or None).
    """

    def __init__(self, format: str, *, endianness: str = "little", time_shift: bool = False,
                 width: int | None = None, height: int | None = None, time_base_us: int = 0):
        self.format = normalize_format(format)
        if endianness not in ("little", "legacy"):
            raise ValueError(f"endianness must be 'little' or 'legacy', got {endianness!r}")
        self.endianness = endianness
        self.time_shift = bool(time_shift)
        self.word_bytes = WORD_BYTES[self.format]
        wrap_us = WRAP_US[self.format]
        if not 0 <= time_base_us < MAX_TIME_BASE_US:
            raise RawFormatError(f"time_base_us={time_base_us} is outside 0..2^62 us")
        if time_base_us % wrap_us:
            raise RawFormatError(f"time_base_us={time_base_us} is not a multiple of the {self.format} "
                                 f"wrap period {wrap_us} us")
        self._state = DecoderState(width=width, height=height, loops=time_base_us // wrap_us)
        _kernels.load(self.format)  # here, not in the first batch (a live stream would wait for it)
        self._time_base_us = int(time_base_us)
        self._tail = b""
        self.bytes_in = 0

    @property
    def stats(self) -> dict:
        st = self._state
        out = dict(st.stats)
        out["first_damage_byte"] = (None if st.first_damage_word is None
                                    else st.first_damage_word * self.word_bytes)
        return out

    @property
    def damaged(self) -> bool:
        """True if any damage counter is non-zero."""
        return any(self._state.stats[k] for k in DAMAGE_KEYS)

    @property
    def time_shift_us(self) -> int:
        """The µs subtracted from every t (0 unless ``time_shift`` and a TIME_HIGH was seen)."""
        first = self._state.first_th
        if not self.time_shift or first is None:
            return 0
        if self.format == "EVT3":
            return self._time_base_us + (max(first - 1, 0) << 12)
        return self._time_base_us + (first << 6)

    def decode(self, data) -> tuple[np.ndarray, np.ndarray]:
        """Decode the next bytes of the stream.

        Parameters
        ----------
        data : bytes, bytearray, memoryview or uint8 ndarray
            Any number of bytes (incomplete words are kept for the next call).

        Returns
        -------
        events : ndarray of EVENT_DTYPE
        triggers : ndarray of TRIGGER_DTYPE
        """
        data = memoryview(data).cast("B") if not isinstance(data, bytes) else data
        self.bytes_in += len(data)
        if self._tail:
            data = self._tail + bytes(data)
        n_words = len(data) // self.word_bytes
        cut = n_words * self.word_bytes
        self._tail = bytes(data[cut:])
        if n_words == 0:
            return EMPTY_EVENTS, EMPTY_TRIGGERS
        if self.format == "EVT3":
            words = np.frombuffer(data, "<u2", n_words)
        elif self.format == "EVT2":
            words = np.frombuffer(data, "<u4", n_words)
        else:
            words = np.frombuffer(data, "<u4", 2 * n_words).reshape(-1, 2)
        events, triggers = self._decode_batch(words)
        shift = self.time_shift_us
        if shift and len(events):
            events["t"] -= shift
        if shift and len(triggers):
            triggers["t"] -= shift
        return events, triggers

    def _decode_batch(self, words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.format == "EVT3":
            return evt3.decode_words(words, self._state)
        if self.format == "EVT2":
            return evt2.decode_words(words, self._state)
        return evt2.decode_words_21(words, self._state, endianness=self.endianness)

    def speculative(self, preceding, offset_bytes: int) -> StreamDecoder:
        """A decoder for the bytes from stream offset ``offset_bytes`` on (word-aligned), its state
        guessed by decoding ``preceding`` (the bytes just before it, a few thousand words) from
        scratch; its counters start at zero there. :meth:`follows` says whether the guess was
        right. (Used to decode parts of a file at once: :class:`RawReader`.)"""
        st = self._state
        guess = StreamDecoder(self.format, endianness=self.endianness, width=st.width, height=st.height,
                              time_base_us=self._time_base_us)
        guess.decode(preceding)
        g = guess._state
        g.stats = dict.fromkeys(STAT_KEYS, 0)
        g.first_damage_word = None
        g.words_seen = offset_bytes // self.word_bytes
        guess.bytes_in = offset_bytes
        guess._guessed = _decoding_state(g)
        return guess

    def follows(self, earlier: StreamDecoder) -> int | None:
        """Whole wrap periods to add to this (speculative) decoder's times when its guessed start
        state is the state ``earlier`` ended in, else None (the guess was wrong)."""
        mine, theirs = self._guessed, _decoding_state(earlier._state)
        loops = theirs[0] - mine[0]
        shift = loops * WRAP_US[self.format]
        if theirs[1] - mine[1] != shift or theirs[2] - mine[2] != shift or theirs[3:] != mine[3:] or earlier._tail:
            return None
        return loops

    def absorb(self, later: StreamDecoder, loops: int) -> None:
        """Continue as ``later`` (the decoder of the bytes that follow this one's, whose times
        are ``loops`` wrap periods behind): its end state and counters are taken over."""
        st, other = self._state, later._state
        for key, value in other.stats.items():
            st.stats[key] += value
        if other.first_damage_word is not None and st.first_damage_word is None:
            st.first_damage_word = other.first_damage_word
        shift = loops * WRAP_US[self.format]
        if st.first_th is None:  # the stream's first TIME_HIGH was in the later part (time shift)
            st.first_th = other.first_th
        st.loops, st.t_us, st.t_max = other.loops + loops, other.t_us + shift, other.t_max + shift
        st.started, st.th_raw, st.tl, st.y, st.base_x, st.base_pol = (
            other.started, other.th_raw, other.tl, other.y, other.base_x, other.base_pol)
        st.words_seen, st.last_words = other.words_seen, other.last_words
        self.bytes_in = later.bytes_in
        self._tail = later._tail

    def finish(self) -> None:
        """End of stream: count an incomplete last word (and EVT3 vector triplet) as damage."""
        if self.format == "EVT3":
            evt3.finish(self._state)
        if self._tail:
            self._state.damage("trailing_bytes", len(self._tail), self._state.words_seen)
            self._tail = b""


def _decoding_state(st: DecoderState) -> tuple:
    """What decoding the next word depends on: loops, the times (µs), then the rest."""
    return (st.loops, st.t_us, st.t_max, st.started, st.th_raw, st.tl, st.y, st.base_x, st.base_pol)


PARALLEL_MIN_BYTES = 4 << 20
"""Files with fewer bytes of words are decoded in one thread (the parts would be too small)."""

PART_BYTES = 8 << 20
"""Bytes of words one thread decodes before the parts of a window are joined."""

MAX_THREADS = 4
"""Most threads :func:`capture.raw.read` uses by default (one per core)."""

GUESS_WORDS = 1 << 14
"""Words before a part decoded to guess the decoder state at its start (4x more while that
does not reach a time word, and an EVT3 row word, up to 4 Mi words)."""


class RawReader:
    """Header plus bounded-memory batches of a RAW file, open file object or byte iterator.

    Parameters
    ----------
    source : str, Path, binary file object, or iterable of bytes
        A path or binary stream starts with a RAW header unless ``format`` is given
        (then it must start directly with event words).
    chunk_bytes : int
        Bytes read per batch (files and file objects).
    format : str, optional
        Decode as this format, without reading a header.
    width, height : int, optional
        Geometry (overrides the header's).
    time_shift : bool
        See :class:`StreamDecoder`.
    threads : int
        Parts of a file (of 4 MiB and more) decoded at once; the batches are the same for any
        number (see :meth:`_parallel_batches`). One by default: a streaming consumer (a store
        being written, as in :func:`capture.ingest.convert_raw`) does best with the other cores
        (measured: ingest 20 Mev/s with two decoding threads, 22 with one).

    Attributes
    ----------
    header : dict
        As returned by :func:`capture.raw.parse_header` (``{}``-like when ``format`` was given).
    header_size : int
        Bytes of header before the words.
    decoder : StreamDecoder
        Holds ``stats`` after (and during) iteration.
    size_bytes : int or None
        Total size of a file source (for progress bars).
    """

    def __init__(self, source, *, chunk_bytes: int = DEFAULT_CHUNK_BYTES, format: str | None = None,
                 width: int | None = None, height: int | None = None, time_shift: bool = False,
                 threads: int = 1):
        if chunk_bytes < 1:
            raise ValueError(f"chunk_bytes must be >= 1, got {chunk_bytes}")
        self.chunk_bytes = int(chunk_bytes)
        self.threads = max(1, int(threads))
        self.name = str(source) if isinstance(source, (str, os.PathLike)) else getattr(source, "name", "<stream>")
        self.size_bytes = None
        self._close = None
        if isinstance(source, (str, os.PathLike)):
            path = Path(source)
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no such RAW file")
            self.size_bytes = path.stat().st_size
            source = self._close = open(path, "rb")
        self._file = None
        if hasattr(source, "readinto") and getattr(source, "seekable", lambda: False)():
            self._file = source                # read straight into an aligned, reused buffer
            self._start = source.tell()
            self._chunks = iter(())
        elif hasattr(source, "read"):
            self._chunks = iter(lambda: source.read(self.chunk_bytes), b"")
        elif isinstance(source, (bytes, bytearray, memoryview)):
            raise TypeError("pass bytes as [data] (an iterable of chunks) or wrap them in io.BytesIO")
        else:
            self._chunks = iter(source)
        self._first = b""
        if format is not None:
            fmt = normalize_format(format, source=self.name)
            self.header = {"format": fmt, "width": width, "height": height, "endianness": "little",
                           "style": "none", "fields": {}}
            self.header_size = 0
        else:
            self._read_header()
            fmt = self.header["format"]
            if fmt is None:
                self.close()
                raise RawFormatError(f"{self.name}: byte {self.header_size}: the header does not name "
                                     "the event format; pass format='EVT2'|'EVT21'|'EVT3'")
        if width is not None and height is not None:
            self.header["width"], self.header["height"] = int(width), int(height)
        self.format = fmt
        self.width, self.height = self.header["width"], self.header["height"]
        try:
            time_base_us = int(self.header["fields"].get("time_base_us", 0))
        except ValueError:
            raise RawFormatError(f"{self.name}: header field time_base_us is not an integer") from None
        if not 0 <= time_base_us < MAX_TIME_BASE_US:
            raise RawFormatError(f"{self.name}: header field time_base_us={time_base_us} is outside 0..2^62 us")
        self.decoder = StreamDecoder(fmt, endianness=self.header["endianness"], time_shift=time_shift,
                                     width=self.width, height=self.height, time_base_us=time_base_us)

    def _read_header(self) -> None:
        if self._file is not None:
            buf = self._file.read(MAX_HEADER_BYTES + 1)
        else:
            buf = b""
            for chunk in self._chunks:
                buf += bytes(chunk)
                if len(buf) > MAX_HEADER_BYTES or _header_complete(buf):
                    break
        if not buf:
            self.close()
            raise RawFormatError(f"{self.name}: empty file (0 bytes)")
        self.header, self.header_size = parse_header(buf, source=self.name)
        if self._file is not None:
            self._file.seek(self._start + self.header_size)
        else:
            self._first = memoryview(buf)[self.header_size:]

    def _file_chunks(self) -> Iterator[np.ndarray]:
        """Chunks of a seekable file read into one reused buffer (no per-chunk allocation)."""
        if self._file is None:
            return
        left = None if self.size_bytes is None else self.size_bytes - self.header_size
        buf = np.empty(max(1, self.chunk_bytes if left is None else min(self.chunk_bytes, left)), np.uint8)
        while True:
            n = self._file.readinto(buf)
            if not n:
                return
            yield buf[:n]

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Yield ``(events, triggers)`` per batch (either may be empty), then finish the decoder."""
        try:
            if len(self._first):
                yield self.decoder.decode(self._first)
                self._first = b""
            words = None if self.size_bytes is None else self.size_bytes - self.header_size
            if self._file is not None and self.threads > 1 and words is not None and words >= PARALLEL_MIN_BYTES:
                yield from self._parallel_batches()
            else:
                for chunk in self._file_chunks():
                    yield self.decoder.decode(chunk)
            for chunk in self._chunks:
                yield self.decoder.decode(chunk)
            self.decoder.finish()
        finally:
            self.close()

    def _parallel_batches(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """The file's batches, decoded ``threads`` parts at a time (windows of :data:`PART_BYTES`
        per part; memory stays bounded).

        Each part after the first in a window starts from a guessed decoder state
        (:meth:`StreamDecoder.speculative`). When the part before it ends in that state (up to
        whole wrap periods, added to the part's times) the part is kept; otherwise the rest of
        the window is decoded again from the true state. Batches, counters and warnings are
        those of one thread.
        """
        fd = self._file.fileno()
        wb = self.decoder.word_bytes
        pos, stop = self._file.tell(), self.size_bytes
        window = self.threads * PART_BYTES
        with ThreadPoolExecutor(self.threads - 1, thread_name_prefix="raw-decode") as pool:
            while pos < stop:
                end = stop if stop - pos < 2 * window else pos + window
                yield from self._decode_window(fd, pool, pos, end, wb)
                pos = end

    def _guess(self, fd: int, cut: int, wb: int) -> StreamDecoder:
        """A speculative decoder for the bytes from ``cut`` on, from the words before it: 4x more
        of them while the guess knows no time yet (or, in EVT3, no row)."""
        for words_back in (GUESS_WORDS << k for k in range(0, 9, 2)):
            guess_from = max(self.header_size, cut - words_back * wb)
            guess = self.decoder.speculative(os.pread(fd, cut - guess_from, guess_from), cut - self.header_size)
            st = guess._state
            if st.started and (st.y != 0xFFFF or self.format != "EVT3") or guess_from == self.header_size:
                break
        return guess

    def _decode_window(self, fd: int, pool: ThreadPoolExecutor, start: int, stop: int, wb: int) -> list:
        n_words = (stop - start) // wb
        cuts = [start + (n_words * k // self.threads) * wb for k in range(self.threads)] + [stop]
        decoders = [self.decoder] + [self._guess(fd, cut, wb) for cut in cuts[1:-1]]
        later = [pool.submit(_decode_span, fd, d, a, b, self.chunk_bytes)
                 for d, a, b in zip(decoders[1:], cuts[1:-1], cuts[2:])]
        batches = _decode_span(fd, self.decoder, cuts[0], cuts[1], self.chunk_bytes)
        parts = [f.result() for f in later]
        for k, part in enumerate(parts, 1):
            loops = decoders[k].follows(self.decoder)
            if loops is None:  # a wrong guess: the rest of the window in one thread, from the truth
                batches += list(_iter_span(fd, self.decoder, cuts[k], stop, self.chunk_bytes))
                break
            self.decoder.absorb(decoders[k], loops)
            _shift(part, loops * WRAP_US[self.format] - self.decoder.time_shift_us)
            batches += part
        return batches

    def close(self) -> None:
        if self._close is not None:
            self._close.close()
            self._close = None

    def damage_message(self) -> str | None:
        """One line naming the file, the first damaged byte and the counts, or None if undamaged."""
        if not self.decoder.damaged:
            return None
        stats = self.decoder.stats
        counts = ", ".join(f"{k}={stats[k]}" for k in DAMAGE_KEYS if stats[k])
        where = stats["first_damage_byte"]
        where = "?" if where is None else where + self.header_size
        return f"{self.name}: damaged {self.format} data from byte {where}: {counts}"


def _iter_span(fd: int, decoder: StreamDecoder, start: int, stop: int, chunk_bytes: int):
    """Decoded batches of the file's bytes ``start .. stop`` (read with ``pread``: threads may share ``fd``)."""
    buf = np.empty(max(1, min(chunk_bytes, stop - start)), np.uint8)
    pos = start
    while pos < stop:
        n = os.preadv(fd, [memoryview(buf)[:min(len(buf), stop - pos)]], pos)
        if not n:
            return
        pos += n
        yield decoder.decode(buf[:n])


def _decode_span(fd: int, decoder: StreamDecoder, start: int, stop: int, chunk_bytes: int) -> list:
    return list(_iter_span(fd, decoder, start, stop, chunk_bytes))


def _shift(batches, shift_us: int) -> None:
    """Add ``shift_us`` to the times of a part's ``(events, triggers)`` batches."""
    if shift_us:
        for pair in batches:
            for a in pair:
                if len(a):
                    a["t"] += shift_us


def _header_complete(buf: bytes) -> bool:
    """True once ``buf`` holds the whole header (``% end`` or a byte after the last ``%`` line)."""
    pos = 0
    while buf[pos:pos + 1] == b"%":
        nl = buf.find(b"\n", pos)
        if nl < 0:
            return False
        if buf[pos:nl + 1].strip() == b"% end":
            return True
        pos = nl + 1
    return pos < len(buf)


def iter_chunks(source, *, chunk_bytes: int = DEFAULT_CHUNK_BYTES, format: str | None = None,
                width: int | None = None, height: int | None = None,
                time_shift: bool = False, threads: int = 1) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Decode a RAW file (path or binary file object) or a byte iterator in bounded memory.

    Yields ``(events, triggers)`` batches (EVENT_DTYPE, TRIGGER_DTYPE) in stream order;
    concatenated, they equal :func:`capture.raw.read` of the same file. Parameters as in
    :class:`RawReader`; use ``RawReader`` directly to see the header and damage counters.
    """
    return iter(RawReader(source, chunk_bytes=chunk_bytes, format=format, width=width,
                          height=height, time_shift=time_shift, threads=threads))
