"""Crash-safe session store: one Zarr v3 group per recorded session.

Layout (names are fixed; other tools rely on them)::

    SESSION_DIR/                    root group, attrs: kind, schema_version, sensor, ...
        events/{t,x,y,p}            CD events as 1-D columns (t µs int64, x/y uint16, p int8)
        index/ms_to_idx             first event index with t >= (t0_ms + k) * 1000
        triggers/{t,id,p}           external trigger events
        frames/{t_us}               frame timestamps on the event clock (+ optional image)
        track/{t_us,cx,cy,r,vx,vy,score,flight,sigma_px}  capture.events.TRACK_COLUMNS
        spin/{t_start_us,t_end_us,axis,omega_rad_s,...}   capture.events.SPIN_COLUMNS

Every table is a group of arrays sharing their first axis plus an attribute
``n_committed``. A writer resizes, writes the data and only then raises
``n_committed``; readers never look past it. A writer killed mid-append
therefore leaves a store whose committed prefix is intact (Zarr's local store
writes each file atomically). Metadata is consolidated when a session is closed.

Nothing is lost silently:

- every chunk carries a CRC-32C checksum (Zarr's ``crc32c`` codec; stores written before
  it was added still open), and :func:`open_session` checks that every committed chunk is
  there, so a damaged store is reported with the damaged column and row range
  (:class:`SessionError`) instead of being read as zeros;
- a write that fails (disk full) keeps the events in memory, committed by a later write or
  at :meth:`SessionWriter.close`; if they still cannot be written, the closed store says so
  in ``events.attrs["lost"]`` (``[index, t_us, events, reason]``: the events from store index
  ``index`` on, first time ``t_us``, are not in the store) and ``close`` raises
  :class:`SessionWriteError`. A small reserve file (``.reserve``) is given up then, so
  that the store can still be closed on a full disk;
- events whose times go backwards (a corrupted time word on the link) are left out of the
  store, counted and placed in ``events.attrs["out_of_order"]`` (``[index, t_us, events]``
  per damaged run: before store index ``index``, after time ``t_us``; the RAW file keeps
  their bytes) and ``events.attrs["n_out_of_order"]``;
- the root ``zarr.json`` is written last when a session is created, with all its
  attributes at once: a kill before it leaves a directory that :func:`open_session` names as
  an unfinished creation and that :func:`create_session` reuses.
"""

from __future__ import annotations

import collections
import contextlib
import datetime as _dt
import errno
import itertools
import json
import os
import time
import uuid
import weakref
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from importlib import metadata
from pathlib import Path

import warnings

try:  # the one-writer lock (flock); without it (Windows) writers are not kept apart
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None

import google_crc32c
import numcodecs
import numpy as np
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec
from zarr.codecs.numcodecs import Delta

from capture.events import (EVENT_DTYPE, SPIN_COLUMNS, TRACK_COLUMNS, TRACK_OPTIONAL, TRIGGER_DTYPE, concatenate,
                            empty_table, in_order_mask, missing_value, spin_table, time_slice)

# We knowingly use two Zarr extensions (the numcodecs Delta filter, consolidated metadata).
warnings.filterwarnings("ignore", message="Numcodecs codecs are not in", category=UserWarning)
warnings.filterwarnings("ignore", message="Consolidated metadata is currently not", category=UserWarning)
# A session directory also holds non-Zarr files (the RAW byte stream, the GoPro video).
warnings.filterwarnings("ignore", message="Object at .* is not recognized as a component", category=UserWarning)

# Every chunk is written, also an all-zero one (Zarr skips those by default): a missing chunk is
# then damage, never "zeros", and open_session can say so.
zarr.config.set({"array.write_empty_chunks": True})

SCHEMA_VERSION = 1
SESSION_KIND = "courtside-spin session"
EVENT_CHUNK = 1 << 20
"""Events per chunk of each ``events/*`` array."""
TABLE_CHUNK = 1 << 16
"""Rows per chunk of the smaller tables."""

_EVENT_COLUMNS = {"t": ("<i8", ()), "x": ("<u2", ()), "y": ("<u2", ()), "p": ("i1", ())}
_TRIGGER_COLUMNS = {"t": ("<i8", ()), "id": ("u1", ()), "p": ("i1", ())}
_INDEX_COLUMNS = {"ms_to_idx": ("<i8", ())}
EVENT_GROW_CHUNKS = 16
"""The event arrays are resized 16 chunks at a time while recording (to the committed rows at close)."""


RESERVE_NAME = ".reserve"
"""Space set aside in a session being recorded, given up to close the store on a full disk."""
RESERVE_BYTES = 1 << 20
MAX_HELD_EVENTS = 1 << 24
"""Events kept in memory after a write error (for a retry at close); more are counted as lost."""
MAX_DAMAGE_ENTRIES = 1000
"""Out-of-order runs placed individually in the store (all are counted)."""


class SessionError(Exception):
    """A path is not a usable session (missing, not a session, newer schema, damaged, ...)."""


class SessionWriteError(OSError):
    """The store could not be written (disk full, I/O error); the message says what is kept."""


def software_version() -> str:
    """The installed package's version ("unknown" when it is run from a bare checkout)."""
    try:
        return metadata.version("courtside-spin")
    except metadata.PackageNotFoundError:
        return "unknown"


EVENT_COMPRESSION = {"t": ("lz4", 5), "x": ("lz4", 5), "y": ("lz4", 5), "p": ("lz4", 5)}
"""Blosc compressor and level per column (bit-shuffled); any other column: zstd level 1.
``bench/store_bench.py`` measures the alternatives: lz4 writes 23 % faster than zstd level 1
for 12 % more disk (2.11 against 1.89 bytes per event on a court-like stream)."""


def _codecs(name: str, dtype: str):
    cname, clevel = EVENT_COMPRESSION.get(name, ("zstd", 1))
    compressors = [BloscCodec(cname=cname, clevel=clevel, shuffle="bitshuffle"), Crc32cCodec()]
    filters = [Delta(dtype=dtype)] if name in ("t", "t_us") else None
    return filters, compressors


class _ChunkCodec:
    """Encodes and decodes whole chunks of one array exactly as its Zarr codecs would (delta,
    little-endian bytes, Blosc, CRC-32C), in the calling thread: about three times faster than
    Zarr's own write path, and reading twice as fast, where its copies and event-loop hops cost
    more than the compression. The chunks are Zarr's own: Zarr reads them (and checks their
    checksums) as it reads its own."""

    _SHUFFLE = {"noshuffle": 0, "shuffle": 1, "bitshuffle": 2}

    def __init__(self, arr: zarr.Array):
        blosc = arr.compressors[0]
        self.delta = numcodecs.Delta(dtype=arr.dtype.str) if arr.filters else None
        self.blosc = numcodecs.Blosc(cname=blosc.cname.value, clevel=blosc.clevel,
                                     shuffle=self._SHUFFLE[blosc.shuffle.value])
        self.dir = Path(arr.store_path.store.root) / arr.store_path.path
        self.key = arr.metadata.chunk_key_encoding.encode_chunk_key
        self.tail = (0,) * (arr.ndim - 1)
        self.rows = arr.chunks[0]
        self.dtype = arr.dtype

    @staticmethod
    def fits(arr: zarr.Array) -> bool:
        """True if ``arr``'s codecs are ones this class writes: an optional Delta filter, then
        Blosc (its own type size and block size) and CRC-32C; other arrays are left to Zarr."""
        filters = arr.filters
        blosc, *rest = arr.compressors or (None,)
        return (isinstance(arr.store_path.store, zarr.storage.LocalStore) and arr.dtype.str[0] in "<|"
                and (not filters or (len(filters) == 1 and isinstance(filters[0], Delta)
                                     and filters[0].codec_config.get("dtype") == arr.dtype.str
                                     and filters[0].codec_config.get("astype", arr.dtype.str) == arr.dtype.str))
                and isinstance(blosc, BloscCodec) and blosc.blocksize == 0
                and blosc.typesize == arr.dtype.itemsize
                and len(rest) == 1 and isinstance(rest[0], Crc32cCodec))

    def put(self, index: int, block: np.ndarray) -> None:
        """Write chunk ``index`` (``block``: the whole chunk, padded) atomically, like Zarr's store."""
        data = np.ascontiguousarray(block)
        if self.delta is not None:
            data = self.delta.encode(data)
        packed = self.blosc.encode(data)
        path = self.dir / self.key((index, *self.tail))
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{uuid.uuid4().hex}.partial")
        try:
            with open(tmp, "wb") as f:
                f.write(packed)
                f.write(google_crc32c.value(packed).to_bytes(4, "little"))
            tmp.replace(path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise

    def get(self, index: int, out: np.ndarray | None = None) -> np.ndarray:
        """Chunk ``index`` decoded (the whole chunk, padding included) into ``out`` (contiguous,
        of the chunk's length) or a new array; a checksum that does not match raises ValueError."""
        raw = (self.dir / self.key((index, *self.tail))).read_bytes()
        packed, stored = raw[:-4], int.from_bytes(raw[-4:], "little")
        if len(raw) < 4 or google_crc32c.value(packed) != stored:
            raise ValueError("stored and computed CRC-32C checksums do not match")
        out = np.empty(self.rows, self.dtype) if out is None else out
        self.blosc.decode(packed, out=out)
        if self.delta is not None:  # numcodecs' Delta decode, in place (its own decode copies)
            np.cumsum(out, out=out)
        return out

    def read(self, i0: int, i1: int) -> np.ndarray:
        """Rows ``i0:i1`` (``0 <= i0``; 1-D arrays), chunks wholly inside decoded in place; a chunk that
        cannot be read raises :class:`_BadChunk` (its cause the error)."""
        out = np.empty(max(0, i1 - i0), self.dtype)
        for c in range(i0 // self.rows, -(-i1 // self.rows)) if i1 > i0 else ():
            lo, hi = max(i0, c * self.rows), min(i1, (c + 1) * self.rows)
            try:
                if hi - lo == self.rows:
                    self.get(c, out[lo - i0:hi - i0])
                else:
                    out[lo - i0:hi - i0] = self.get(c)[lo - c * self.rows:hi - c * self.rows]
            except Exception as exc:
                raise _BadChunk(c) from exc
        return out


class _BadChunk(Exception):
    """Chunk ``index`` of a column could not be read (:meth:`_ChunkCodec.read`)."""

    def __init__(self, index: int):
        super().__init__(index)
        self.index = index


def _columns_of(rows, fields: Mapping, optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Columns from a mapping, an object with attributes, or a structured array; the ``optional``
    ones may be missing (then :func:`capture.events.missing_value` on every row)."""
    out = {}
    for name in fields:
        if isinstance(rows, np.ndarray) and rows.dtype.names:
            value = rows[name] if name in rows.dtype.names or name not in optional else None
        elif isinstance(rows, Mapping):
            value = rows[name] if name in rows or name not in optional else None
        else:
            value = getattr(rows, name) if hasattr(rows, name) or name not in optional else None
        if value is not None:
            out[name] = np.asarray(value)
    lengths = {len(v) for v in out.values()}
    if len(lengths) > 1:
        raise ValueError(f"columns have different lengths: { {k: len(v) for k, v in out.items()} }")
    n = lengths.pop() if lengths else 0
    for name in fields:
        if name not in out:
            out[name] = np.full(n, missing_value(name, fields[name][0]), fields[name][0])
    return {name: out[name] for name in fields}


_COLUMN_WRITERS = ThreadPoolExecutor(min(4, os.cpu_count() or 1), thread_name_prefix="session-columns")
"""Columns are encoded side by side, one thread per core at most: more threads only contend for the
GIL between codec calls (measured on 2 cores: 39-42 Mev/s stored with two, 29-36 with four)."""


def _table_group(parent: zarr.Group, name: str) -> zarr.Group:
    """A table's group; a new one is created with ``n_committed = 0`` in its first metadata write."""
    if name in parent:
        return parent[name]
    return parent.create_group(name, attributes={"n_committed": 0})


_ABSENT = object()


class _Table:
    """Writer side of one table: arrays sharing the first axis plus ``n_committed``.

    Chunks are encoded here (:class:`_ChunkCodec`) when the arrays have this version's
    codecs; the rows of the last, partly filled chunk are kept so that the next append
    re-encodes that chunk whole without reading it back. Arrays of older stores are written
    through Zarr.
    """

    def __init__(self, group: zarr.Group, columns: Mapping[str, tuple[str, tuple]], chunk: int,
                 grow_chunks: int = 0):
        self.group = group
        self.columns = dict(columns)
        self._grow_rows = grow_chunks * chunk  # 0: arrays sized to the committed rows at each append
        self.arrays = {}
        created = []
        for name, (dtype, tail) in self.columns.items():
            if name in group:
                self.arrays[name] = group[name]
            else:
                filters, compressors = _codecs(name, dtype)
                self.arrays[name] = group.create_array(
                    name, shape=(0, *tail), chunks=(chunk, *tail), dtype=dtype,
                    filters=filters, compressors=compressors, fill_value=missing_value(name, dtype))
                created.append(name)
        if "n_committed" not in group.attrs:  # a table made by an older version
            group.attrs["n_committed"] = 0
        self.n = int(group.attrs["n_committed"])
        self._encoders = {name: _ChunkCodec(arr) for name, arr in self.arrays.items() if _ChunkCodec.fits(arr)}
        self._partial: dict[str, np.ndarray] = {}  # column -> committed rows of its last, partly filled chunk
        self._keep_rows = 0  # rows a failed commit may have counted on disk: never trimmed away
        if self.n:  # a column an older version did not write: its committed rows hold "not measured"
            for name in created:
                self._fill_missing(name)

    def _fill_missing(self, name: str) -> None:
        """Write :func:`capture.events.missing_value` into the committed rows of column ``name``, new in a
        table that already has rows (written by an older version), chunk by chunk as appends write them."""
        arr = self.arrays[name]
        arr.resize((self.n, *arr.shape[1:]))
        fill = np.full((self.n, *arr.shape[1:]), missing_value(name, arr.dtype), arr.dtype)
        if name not in self._encoders:
            arr[:] = fill
            return
        n, self.n = self.n, 0  # encoded from row 0
        try:
            self._partial[name] = self._write_chunks(name, arr, fill)
        finally:
            self.n = n

    def append(self, cols: Mapping[str, np.ndarray], **attrs) -> None:
        """Write rows, then commit them (and ``attrs``) in one metadata write. On an OSError
        nothing is committed: the space of the rows written so far is given back, unless the
        commit itself failed and may have reached the disk (then the rows stay, see :meth:`trim`)."""
        m = len(next(iter(cols.values())))
        if m == 0 and not attrs:
            return
        n_new = self.n + m
        partial = {}

        def write(name: str) -> None:
            arr = self.arrays[name]
            if arr.shape[0] < n_new or not self._grow_rows:
                arr.resize((self._capacity(n_new), *arr.shape[1:]))
            values = np.asarray(cols[name], dtype=arr.dtype)
            if name in self._encoders:
                partial[name] = self._write_chunks(name, arr, values)
            else:
                arr[self.n:n_new] = values

        try:
            if m:  # the columns are encoded and written side by side (the codecs release the GIL)
                futures = [_COLUMN_WRITERS.submit(write, name) for name in self.arrays]
                for f in futures:  # all done before a failure is raised (and rolled back)
                    f.exception()
                for f in futures:
                    f.result()
        except OSError:
            self._roll_back()
            raise
        before = {k: self.group.attrs.get(k, _ABSENT) for k in attrs}
        try:
            self.group.attrs.update({"n_committed": n_new, **attrs})
        except OSError:
            # the new count may have reached the disk all the same: put the old one (and the old
            # attributes) back, and where even that fails never leave fewer rows than the disk
            # may say are committed
            try:
                self.group.attrs.update({"n_committed": self.n,
                                         **{k: v for k, v in before.items() if v is not _ABSENT}})
                for k in (k for k, v in before.items() if v is _ABSENT):
                    self.group.attrs.pop(k, None)
            except OSError:
                self._keep_rows = max(self._keep_rows, n_new)
            else:
                self._roll_back()
            raise
        self.n = n_new
        self._partial.update(partial)

    def _capacity(self, n_rows: int) -> int:
        """Rows to size the arrays for ``n_rows``: grown ``grow_chunks`` chunks at a time, as each
        resize is a metadata write (readers never look past ``n_committed``; :meth:`trim` ends it)."""
        step = self._grow_rows
        return -(-n_rows // step) * step if step else n_rows

    def trim(self) -> None:
        """Size the arrays to the committed rows (or to the rows of a commit that failed in a
        way that may have reached the disk)."""
        rows = max(self.n, self._keep_rows)
        for arr in self.arrays.values():
            if arr.shape[0] != rows:
                arr.resize((rows, *arr.shape[1:]))

    def _write_chunks(self, name: str, arr: zarr.Array, values: np.ndarray) -> np.ndarray:
        """Encode and write the chunks that rows ``n .. n + len(values)`` touch; returns the rows
        of the new last chunk when it is partly filled (for the next append)."""
        rows = arr.chunks[0]
        first = self.n // rows
        head = self._partial.get(name)
        if head is None or len(head) != self.n - first * rows:  # not kept (a table opened again)
            head = arr[first * rows:self.n]
        data = np.concatenate((head, values)) if len(head) else values
        for c in range(-(-len(data) // rows)):
            piece = data[c * rows:(c + 1) * rows]
            if len(piece) < rows:  # the last chunk, partly filled: padded with the fill value
                piece = np.concatenate((piece, np.zeros((rows - len(piece), *arr.shape[1:]), arr.dtype)))
            self._encoders[name].put(first + c, piece)
        return data[len(data) // rows * rows:].copy()

    def mark(self, **attrs) -> None:
        """Write attributes with the committed row count (a failed commit may have left another
        count in the group's cached metadata)."""
        self.group.attrs.update({"n_committed": self.n, **attrs})

    def _roll_back(self) -> None:
        """Drop the chunks past the committed rows (best effort: the disk may be full)."""
        with contextlib.suppress(OSError):
            self.trim()

    def replace(self, cols: Mapping[str, np.ndarray]) -> None:
        self.group.attrs["n_committed"] = 0
        self.n = self._keep_rows = 0
        self._partial = {}
        for arr in self.arrays.values():
            arr.resize((0, *arr.shape[1:]))
        self.append(cols)


REPAIR_TAIL = 1 << 16
"""Events of the last uncommitted batch that take part in repairing a batch whose times go back."""


class SessionWriter:
    """The one writer of a session. Use :func:`create_session` or :func:`update_session`.

    Events are buffered and written in whole chunks of :data:`EVENT_CHUNK`; the
    buffer is also flushed (committed) at least every ``flush_interval_s``
    seconds of wall time, so a crash loses at most that much.

    A failed write raises :class:`SessionWriteError` once; from then on events and
    triggers are held in memory (up to :data:`MAX_HELD_EVENTS`) and written, or recorded
    as lost, by :meth:`close`.
    """

    def __init__(self, root: zarr.Group, path: Path, flush_interval_s: float = 1.0,
                 reserve: Path | None = None, lock: int | None = None):
        self.root = root
        self.path = path
        self._unlock = weakref.finalize(self, _unlock, lock)  # at close, or when dropped unclosed
        self.flush_interval_s = flush_interval_s
        self._reserve = reserve
        self._events = _Table(_table_group(root, "events"), _EVENT_COLUMNS, EVENT_CHUNK, grow_chunks=EVENT_GROW_CHUNKS)
        self._triggers = _Table(_table_group(root, "triggers"), _TRIGGER_COLUMNS, TABLE_CHUNK)
        self._index = _Table(_table_group(root, "index"), _INDEX_COLUMNS, TABLE_CHUNK, grow_chunks=1)
        self._t0_ms = self._index.group.attrs.get("t0_ms")
        self._pending_index: list[np.ndarray] = []  # ms-index entries not written yet
        self._n_pending_index = 0
        self._index_committed()
        self._buffer: list[np.ndarray] = []
        self._buffered = 0
        self._pending_triggers: list[np.ndarray] = []
        self._last_flush = self._events_committed_at = time.monotonic()
        self._committed_last_t = None
        if self._events.n:
            self._committed_last_t = int(self._events.arrays["t"][self._events.n - 1])
        self._last_t = self._committed_last_t
        attrs = self._events.group.attrs
        self._damage = list(attrs.get("out_of_order", []))
        self.n_out_of_order = int(attrs.get("n_out_of_order", 0))
        self.write_error: OSError | None = None
        self._not_held = 0  # events received after a write error beyond MAX_HELD_EVENTS
        self.closed = False

    # -- events -----------------------------------------------------------------------------
    @property
    def n_events(self) -> int:
        """Events committed plus events buffered."""
        return self._events.n + self._buffered

    def append_events(self, events: np.ndarray) -> None:
        """Queue a batch of EVENT_DTYPE events (times non-decreasing, also across batches).

        Events whose times go back (a corrupted time word) are left out of the store and
        recorded as damage (:attr:`n_out_of_order`, ``events.attrs["out_of_order"]``).

        Raises
        ------
        SessionWriteError
            The first time a write fails (the events stay held for :meth:`close`).
        """
        events = np.asarray(events)
        if events.dtype != EVENT_DTYPE:
            raise TypeError(f"events must have EVENT_DTYPE, got {events.dtype}")
        if len(events):
            t = events["t"]
            if (self._last_t is not None and t[0] < self._last_t) or np.any(t[1:] < t[:-1]):
                events = self._repair(events)
        if len(events):
            if self.write_error is not None and self._buffered + len(events) > MAX_HELD_EVENTS:
                self._not_held += len(events)
                return
            self._last_t = int(events["t"][-1])
            self._buffer.append(events)
            self._buffered += len(events)
        if self.write_error is not None:
            return
        aligned = (self._events.n + self._buffered) // EVENT_CHUNK * EVENT_CHUNK
        if aligned > self._events.n:
            self._guarded(self._write_events, aligned - self._events.n)
        self.flush_if_due()

    def _repair(self, events: np.ndarray) -> np.ndarray:
        """The batch, joined to the tail of the last uncommitted one, with the events out of
        time order left out (and recorded)."""
        prev = self._buffer.pop() if self._buffer else events[:0]
        self._buffered -= len(prev)
        kept_prev = prev[:max(0, len(prev) - REPAIR_TAIL)]
        if len(kept_prev):
            self._buffer.append(kept_prev)
            self._buffered += len(kept_prev)
        floor = int(self._buffer[-1]["t"][-1]) if self._buffer else self._committed_last_t
        seg = concatenate([prev[len(kept_prev):], events])
        keep = in_order_mask(seg["t"], floor)
        dropped = np.flatnonzero(~keep)
        if len(dropped):
            base = self._events.n + self._buffered  # store index of seg[0]
            starts = dropped[np.flatnonzero(np.diff(dropped, prepend=-2) != 1)]
            sizes = np.diff(np.append(np.flatnonzero(np.diff(dropped, prepend=-2) != 1), len(dropped)))
            kept_before = np.cumsum(keep) - keep
            t_kept = seg["t"][keep]
            for s, k in zip(starts.tolist(), sizes.tolist()):
                j = int(kept_before[s])
                t_at = int(t_kept[j - 1]) if j else (floor if floor is not None else -1)
                if len(self._damage) < MAX_DAMAGE_ENTRIES:
                    self._damage.append([base + j, t_at, k])
            self.n_out_of_order += len(dropped)
        return seg[keep]

    def _guarded(self, write, *args) -> None:
        """Run a store write; on the first OSError hold everything and say so."""
        try:
            write(*args)
        except OSError as exc:
            self.write_error = exc
            raise SessionWriteError(f"{self.path}: session store write failed ({exc}); "
                                    f"{self._buffered} events held in memory") from exc

    def _write_events(self, count: int) -> None:
        data = concatenate(self._buffer)
        self._buffer = [data] if len(data) else []
        head = data[:count]
        n0 = self._events.n
        extra = {"out_of_order": self._damage, "n_out_of_order": self.n_out_of_order} if self.n_out_of_order else {}
        self._events.append({name: head[name] for name in _EVENT_COLUMNS}, **extra)
        self._events_committed_at = time.monotonic()
        tail = data[count:]
        self._buffer = [tail] if len(tail) else []
        self._buffered = len(tail)
        if len(head):
            self._committed_last_t = int(head["t"][-1])
            self._index_entries(n0, head["t"])

    def _index_entries(self, n0: int, t_new: np.ndarray) -> None:
        """The ms-index entries that events ``n0..`` (times ``t_new``, µs) make final, kept until
        :meth:`_extend_index` writes them (the origin and counts are kept here: a failed write may
        leave others in the group's cached metadata)."""
        if self._t0_ms is None:
            self._t0_ms = int(t_new[0] // 1000)
        ms = np.arange(self._t0_ms + self._index.n + self._n_pending_index, int(t_new[-1] // 1000) + 1,
                       dtype=np.int64)
        if len(ms):
            self._pending_index.append(n0 + np.searchsorted(t_new, ms * 1000, side="left"))
            self._n_pending_index += len(ms)

    def _index_committed(self) -> None:
        """The ms-index entries of committed events that the index lacks (a writer killed between
        a chunk's commit and the next flush), computed when the session is opened again."""
        n, k = self._events.n, self._index.n
        if n == 0:
            return
        start = int(self._index.arrays["ms_to_idx"][k - 1]) if k else 0
        self._index_entries(start, np.asarray(self._events.arrays["t"][start:n]))

    def _extend_index(self) -> None:
        """Write the pending ms-index entries. Done at each flush, not at each chunk of events:
        a reader finds the events after the index's last entry by their times."""
        if self._pending_index:
            self._index.append({"ms_to_idx": np.concatenate(self._pending_index)}, t0_ms=self._t0_ms)
            self._pending_index, self._n_pending_index = [], 0

    def append_triggers(self, triggers: np.ndarray) -> None:
        """Append and commit TRIGGER_DTYPE events (held, like events, after a write error)."""
        triggers = np.asarray(triggers)
        if triggers.dtype != TRIGGER_DTYPE:
            raise TypeError(f"triggers must have TRIGGER_DTYPE, got {triggers.dtype}")
        if len(triggers):
            self._pending_triggers.append(triggers)
        if self.write_error is None:
            self._guarded(self._write_triggers)

    def _write_triggers(self) -> None:
        if self._pending_triggers:
            data = concatenate(self._pending_triggers, TRIGGER_DTYPE)
            self._triggers.append({name: data[name] for name in _TRIGGER_COLUMNS})
            self._pending_triggers = []

    def flush_if_due(self) -> None:
        """Commit on schedule: the buffered events once ``flush_interval_s`` has passed since events
        were last committed (at a high rate whole chunks commit sooner, and the partly filled
        last chunk is not written again and again), the ms index and the triggers once it has
        passed since the last such flush."""
        now = time.monotonic()
        if self.write_error is not None:
            return
        if self._buffered and now - self._events_committed_at >= self.flush_interval_s:
            self._guarded(self._write_events, self._buffered)
        if now - self._last_flush >= self.flush_interval_s:
            self._guarded(self._write_index_and_triggers)
            self._last_flush = now

    def flush(self) -> None:
        """Write and commit every buffered event (nothing after a write error: see :meth:`close`)."""
        if self.write_error is None:
            self._guarded(self._write_all)
        self._last_flush = time.monotonic()

    def _write_all(self) -> None:
        if self._buffered:
            self._write_events(self._buffered)
        self._write_index_and_triggers()

    def _write_index_and_triggers(self) -> None:
        self._extend_index()
        self._write_triggers()

    # -- tables and attributes ----------------------------------------------------------------
    def _table(self, name: str, columns: Mapping[str, tuple[str, tuple]]) -> _Table:
        return _Table(_table_group(self.root, name), columns, TABLE_CHUNK)

    def append_track(self, track) -> None:
        """Append ball-track rows (mapping or object with the ``capture.events.TRACK_COLUMNS``; ``sigma_px``
        may be missing: NaN, not measured)."""
        self._table("track", TRACK_COLUMNS).append(_columns_of(track, TRACK_COLUMNS, TRACK_OPTIONAL))

    def write_track(self, track) -> None:
        """Replace the whole ball track."""
        self._table("track", TRACK_COLUMNS).replace(_columns_of(track, TRACK_COLUMNS, TRACK_OPTIONAL))

    def append_spin(self, spin) -> None:
        """Append spin-estimate rows (mapping or object with the ``capture.events.SPIN_COLUMNS``)."""
        self._table("spin", SPIN_COLUMNS).append(spin_table(spin))

    def write_spin(self, spin) -> None:
        """Replace all spin estimates."""
        self._table("spin", SPIN_COLUMNS).replace(spin_table(spin))

    def append_frames(self, t_us, images: np.ndarray | None = None) -> None:
        """Append frame timestamps (µs, event clock) and, optionally, the frames (N, H, W[, 3]) uint8."""
        t_us = np.asarray(t_us, dtype=np.int64)
        columns = {"t_us": ("<i8", ())}
        cols = {"t_us": t_us}
        if images is not None:
            images = np.asarray(images, dtype=np.uint8)
            columns["image"] = ("u1", images.shape[1:])
            cols["image"] = images
        table = _Table(_table_group(self.root, "frames"), columns, 1 if images is not None else TABLE_CHUNK)
        table.append(cols)

    def set_video(self, relpath: str, t_us) -> None:
        """Reference a video file (path relative to the session) with its frame times (µs, event clock)."""
        frames = _table_group(self.root, "frames")
        frames.attrs["video"] = str(relpath)
        _Table(frames, {"t_us": ("<i8", ())}, TABLE_CHUNK).replace({"t_us": np.asarray(t_us, np.int64)})

    def set_attrs(self, **attrs) -> None:
        """Set JSON-serialisable root attributes (sensor, frame_camera, calibration, time_sync, ...)."""
        json.dumps(attrs)  # fail early, with JSON's own message, on non-serialisable values
        self.root.attrs.update(attrs)

    # -- life cycle ---------------------------------------------------------------------------
    def close(self, **attrs) -> None:
        """Flush, mark the session closed (root ``attrs`` written with the mark) and consolidate
        its metadata.

        After a write error the held events and triggers are written now (the reserve file is
        given up first if the retry fails); those that still cannot be are recorded as lost
        (``events.attrs["lost"]``, ``triggers.attrs["lost"]``), the store is closed, and
        :class:`SessionWriteError` says what is missing.

        Raises
        ------
        SessionWriteError
            Something received could not be stored (the store is closed and says what).
        OSError
            The store could not even be closed (it still opens: its committed prefix is intact).
        """
        if self.closed:
            return
        failure = self.write_error if self._not_held else None
        for write in (self._write_triggers, self._write_all, self._write_in_pieces):
            try:  # each part on its own: triggers are small, and pieces of events may fit
                write()
            except OSError as exc:
                failure = exc
        self._release_reserve()
        for table in (self._events, self._index):
            with contextlib.suppress(OSError):  # a full disk: the committed counts still hold
                table.trim()
        lost = []
        if failure is not None:
            n_held = self._buffered + self._not_held
            t_first = int(self._buffer[0]["t"][0]) if self._buffer else -1
            reason = " ".join(str(failure).split())
            if n_held:
                self._events.mark(lost=[self._events.n, t_first, n_held, reason])
                lost.append(f"{n_held} events from index {self._events.n} (t = {t_first} µs) on")
            n_trig = sum(len(t) for t in self._pending_triggers)
            if n_trig:
                self._triggers.mark(lost=[self._triggers.n, -1, n_trig, reason])
                lost.append(f"{n_trig} triggers")
        json.dumps(attrs)
        try:
            self.root.attrs.update({**attrs, "closed": True})
            zarr.consolidate_metadata(str(self.path))
        finally:
            self.closed = True
            self._unlock()
        if lost:
            raise SessionWriteError(f"{self.path}: {' and '.join(lost)} could not be stored ({reason}); "
                                    "the session is closed and marked with what is missing")

    def _write_in_pieces(self, piece: int = TABLE_CHUNK) -> None:
        """Commit the held events a piece at a time (as many as the disk takes)."""
        while self._buffered:
            self._write_events(min(piece, self._buffered))
        self._extend_index()

    def _release_reserve(self) -> None:
        if self._reserve is not None:
            with contextlib.suppress(OSError):
                self._reserve.unlink(missing_ok=True)

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class StoreBehind:
    """Appends ``(events, triggers)`` batches to a :class:`SessionWriter` in a thread of its own,
    so that the caller decodes the next batches meanwhile (decoding and compressing then run on
    two cores). At most ``depth`` batches wait: memory stays bounded, and a slow commit (a
    metadata write, a partly filled chunk written again) does not stall the caller.

    Parameters
    ----------
    writer : SessionWriter
    lock : threading.Lock, optional
        Held around each append (shared with a thread that commits the writer on a schedule).
    on_error : callable, optional
        Called with the OSError of a failed append (disk full); the writer then holds what it is
        given (see :meth:`SessionWriter.append_events`). Without it the error is raised by a
        later call or by :meth:`close`.
    depth : int
        Batches in flight at most.
    """

    def __init__(self, writer: SessionWriter, lock=None, on_error=None, depth: int = 4):
        self._writer = writer
        self._lock = lock if lock is not None else contextlib.nullcontext()
        self._on_error = on_error
        self._depth = max(1, depth)
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="session-behind")
        self._pending: collections.deque = collections.deque()

    def _store(self, events: np.ndarray, triggers: np.ndarray) -> None:
        with self._lock:
            for append, rows in ((self._writer.append_events, events), (self._writer.append_triggers, triggers)):
                try:
                    append(rows)
                except OSError as exc:
                    if self._on_error is None:
                        raise
                    self._on_error(exc)

    def __call__(self, events: np.ndarray, triggers: np.ndarray) -> None:
        """Queue a batch (waiting while ``depth`` batches are in flight)."""
        while len(self._pending) >= self._depth:
            self._pending.popleft().result()
        self._pending.append(self._thread.submit(self._store, events, triggers))

    def close(self) -> None:
        """Wait until every batch is stored (raising the first error, without ``on_error``), then end the thread."""
        try:
            while self._pending:
                self._pending.popleft().result()
        finally:
            self._pending.clear()
            self._thread.shutdown(wait=True)


def create_session(path, *, width: int, height: int, attrs: Mapping | None = None,
                   overwrite: bool = False, flush_interval_s: float = 1.0) -> SessionWriter:
    """Create a new session directory and return its writer.

    Parameters
    ----------
    path : str or Path
        Session directory (must be empty, or left by a creation that was killed before it
        finished; ``overwrite`` replaces an existing store and keeps the directory's other
        files, such as the RAW byte stream and the videos).
    width, height : int
        Event sensor geometry in pixels.
    attrs : mapping, optional
        Extra root attributes (sensor model/serial/format/biases, frame camera, ...).
    """
    path = Path(path)
    lock = _lock_writer(path) if path.is_dir() else None
    try:
        if path.exists() and any(path.iterdir()):
            if not overwrite and not unfinished_session(path):
                raise SessionError(f"{path}: already exists and is not empty")
            _remove_store(path)
    except BaseException:
        _unlock(lock)
        raise
    root_attrs = {
        "kind": SESSION_KIND,
        "schema_version": SCHEMA_VERSION,
        "width": int(width),
        "height": int(height),
        "software_version": software_version(),
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "closed": False,
        **(dict(attrs) if attrs else {}),
    }
    json.dumps(root_attrs)
    path.mkdir(parents=True, exist_ok=True)
    if lock is None:
        lock = _lock_writer(path)
    try:
        return _create_store(path, root_attrs, flush_interval_s, lock)
    except BaseException:
        _unlock(lock)
        raise


def _create_store(path: Path, root_attrs: dict, flush_interval_s: float, lock: int | None) -> SessionWriter:
    reserve = path / RESERVE_NAME
    with reserve.open("wb") as f:
        f.write(bytes(RESERVE_BYTES))
        f.flush()
        os.fsync(f.fileno())
    # the tables first, the root's metadata (with every attribute) last: until it exists the
    # directory is an unfinished creation, which create_session reuses
    _Table(zarr.create_group(str(path / "events"), attributes={"n_committed": 0}, zarr_format=3),
           _EVENT_COLUMNS, EVENT_CHUNK)
    _Table(zarr.create_group(str(path / "triggers"), attributes={"n_committed": 0}, zarr_format=3),
           _TRIGGER_COLUMNS, TABLE_CHUNK)
    _Table(zarr.create_group(str(path / "index"), attributes={"n_committed": 0}, zarr_format=3),
           _INDEX_COLUMNS, TABLE_CHUNK)
    root = zarr.create_group(str(path), attributes=root_attrs, zarr_format=3)
    return SessionWriter(root, path, flush_interval_s, reserve=reserve, lock=lock)


LOCK_TRIES = 25
"""Tries, 20 ms apart, to take a session's one-writer lock before saying it is being written."""


def _lock_writer(path: Path, shared: bool = False) -> int | None:
    """Take the session directory's one-writer lock (``flock``; the system releases it when the
    process ends, also on a kill); returns its descriptor for :func:`_unlock`. A writer tries for
    half a second (a probe may hold it for an instant); ``shared`` takes it shared, once (the
    probe of :func:`being_written`).

    Raises
    ------
    SessionError
        Another process (or another writer in this one) holds it.
    """
    if fcntl is None:  # pragma: no cover
        return None
    fd = os.open(path, os.O_RDONLY)
    for attempt in range(LOCK_TRIES):  # a reader's probe (being_written) holds it for an instant
        try:
            fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
            return fd
        except OSError as exc:
            held = exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)
            if held and not shared and attempt < LOCK_TRIES - 1:
                time.sleep(0.02)
                continue
            os.close(fd)
            if held:
                raise SessionError(f"{path}: the session is being written by another program "
                                   "(a recording or a replay still running)") from None
            return None  # a file system without flock (ENOLCK on some network mounts): unlocked


def _unlock(fd: int | None) -> None:
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)  # closing the descriptor releases the flock


def being_written(path) -> bool:
    """True while a :class:`SessionWriter` of another program (or of this one) holds the session
    at ``path`` open."""
    path = Path(path)
    if fcntl is None or not path.is_dir():  # pragma: no cover
        return False
    try:
        _unlock(_lock_writer(path, shared=True))  # shared: probes do not exclude one another
    except SessionError:
        return True
    except OSError:  # a directory this user cannot open: no writer of theirs either
        return False
    return False


_STORE_ENTRIES = ("zarr.json", "events", "index", "triggers", "frames", "track", "spin", RESERVE_NAME)


def unfinished_session(path) -> bool:
    """True when ``path`` holds only the parts of a session whose creation was cut short
    (killed before its root metadata was written): safe to record into again."""
    path = Path(path)
    if not path.is_dir() or (path / "zarr.json").exists():
        return False
    names = {p.name for p in path.iterdir()}
    if not names or not names <= set(_STORE_ENTRIES):
        return False
    return not any(p.name == "c" for p in path.rglob("c"))  # no chunk written: nothing recorded


def _holds_data(path: Path) -> bool:
    return (path / "events").is_dir() and any(p.is_dir() for p in (path / "events").glob("*/c"))


def _remove_store(path: Path) -> None:
    """Delete a session's Zarr entries, keeping the other files (the RAW stream, the videos)."""
    import shutil

    # writes of a failed creation may still land (or be renamed) from Zarr's I/O thread, during the
    # removal or just after it: remove until nothing has come back 50 ms later
    for attempt in range(20):
        for name in _STORE_ENTRIES:
            entry = path / name
            if entry.is_dir():
                try:
                    shutil.rmtree(entry)
                except OSError as exc:
                    if exc.errno not in (errno.ENOTEMPTY, errno.ENOENT) or attempt == 19:
                        raise
            elif entry.exists():
                entry.unlink()
        time.sleep(0.05)
        if not any((path / name).exists() for name in _STORE_ENTRIES):
            return
    raise OSError(errno.EBUSY, f"{path}: the old store keeps coming back (another process writing it?)")


def update_session(path, flush_interval_s: float = 1.0) -> SessionWriter:
    """Reopen an existing session for writing (e.g. replay writing track and spin)."""
    path = Path(path)
    _check_root(path)
    lock = _lock_writer(path)
    try:
        root = zarr.open_group(str(path), mode="r+", use_consolidated=False)
        root.attrs["closed"] = False
        return SessionWriter(root, path, flush_interval_s, lock=lock)
    except BaseException:
        _unlock(lock)
        raise


def _check_root(path: Path) -> zarr.Group:
    if not path.exists():
        raise SessionError(f"{path}: no such session directory")
    if unfinished_session(path):
        raise SessionError(f"{path}: an unfinished session (its creation was cut short before any data "
                           "was recorded); record into it again with --out")
    if not (path / "zarr.json").is_file():
        if _holds_data(path):
            raise SessionError(f"{path}: damaged session: its root zarr.json is missing (events/ holds data)")
        raise SessionError(f"{path}: not a session (no Zarr v3 group here)")
    try:
        root = zarr.open_group(str(path), mode="r", use_consolidated=False)
    except Exception as exc:  # zarr raises several types for broken metadata
        raise SessionError(f"{path}: not a readable Zarr group ({_reason(exc)})") from exc
    attrs = root.attrs
    if attrs.get("kind") != SESSION_KIND:
        raise SessionError(f"{path}: not a session (Zarr group without kind={SESSION_KIND!r})")
    version = attrs.get("schema_version")
    if not _is_count(version):
        raise SessionError(f"{path}: damaged session: root attribute schema_version = {version!r}")
    if version > SCHEMA_VERSION:
        raise SessionError(f"{path}: session schema version {version} is newer than this software "
                           f"supports ({SCHEMA_VERSION}); upgrade courtside-spin")
    for key in ("width", "height"):
        if not _is_count(attrs.get(key)) or attrs[key] == 0 or attrs[key] > 1 << 16:
            raise SessionError(f"{path}: damaged session: root attribute {key} = {attrs.get(key)!r} "
                               "(expected the sensor size in pixels)")
    return root


def _is_count(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _reason(exc: BaseException) -> str:
    """One line for a low-level exception."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


_REQUIRED_TABLES = {"events": _EVENT_COLUMNS, "triggers": _TRIGGER_COLUMNS, "index": _INDEX_COLUMNS}
_OPTIONAL_TABLES = {"track": TRACK_COLUMNS, "spin": SPIN_COLUMNS, "frames": {"t_us": ("<i8", ()), "image": None}}


def _check_tables(path: Path, root: zarr.Group) -> dict[str, int]:
    """Committed row counts of the tables, after checking that each is whole: its columns
    present, ``n_committed`` a row count within every column, every committed chunk on disk.

    A required table (events, triggers, index) must exist; a column of an optional one may be
    missing (written by an older version: read as NaN or zeros). Raises :class:`SessionError`.
    """
    counts = {}
    for name, columns in {**_REQUIRED_TABLES, **_OPTIONAL_TABLES}.items():
        required = name in _REQUIRED_TABLES
        try:
            group = root[name] if name in root else None
        except Exception as exc:
            raise SessionError(f"{path}: damaged session: {name}/ is unreadable ({_reason(exc)})") from exc
        if group is None or not isinstance(group, zarr.Group):
            if required:
                raise SessionError(f"{path}: damaged session: the {name}/ table is missing")
            counts[name] = 0
            continue
        n = group.attrs.get("n_committed")
        if not _is_count(n):
            raise SessionError(f"{path}: damaged session: {name}/ n_committed = {n!r} (expected a row count)")
        for col in columns:
            if col not in group:
                if required and n and col in _REQUIRED_TABLES[name]:
                    raise SessionError(f"{path}: damaged session: column {name}/{col} is missing "
                                       f"({n} rows committed)")
                continue
            try:
                arr = group[col]
            except Exception as exc:
                raise SessionError(f"{path}: damaged session: {name}/{col} is unreadable ({_reason(exc)})") from exc
            if arr.shape[0] < n:
                raise SessionError(f"{path}: damaged session: {name}/{col} holds {arr.shape[0]} rows, "
                                   f"{n} are committed")
            _check_chunks(path, f"{name}/{col}", arr, n)
        counts[name] = n
    return counts


def _has_checksums(arr) -> bool:
    return any(type(c).__name__ == "Crc32cCodec" for c in arr.metadata.codecs)


def _check_chunks(path: Path, name: str, arr, n: int) -> None:
    """Every chunk holding committed rows must be a file. Stores with checksums write every
    chunk; older ones skip all-zero chunks, so there only time columns are checked."""
    if n == 0 or not (_has_checksums(arr) or name.endswith(("/t", "/t_us"))):
        return
    rows = arr.chunks[0]
    tails = [range(-(-s // c)) for s, c in zip(arr.shape[1:], arr.chunks[1:])]
    encode = arr.metadata.chunk_key_encoding.encode_chunk_key
    for i in range(-(-n // rows)):
        for tail in itertools.product(*tails):
            key = encode((i, *tail))
            if not (path / name / key).is_file():
                raise SessionError(f"{path}: damaged session: {name} chunk {key} (rows {i * rows}.."
                                   f"{min((i + 1) * rows, n) - 1}) is missing or not a file")


class Session:
    """Read-only view of a session.

    Every read looks up the committed lengths anew, so a reader follows a live
    writer's appends; :meth:`reload` refreshes the root attributes, and must follow a store
    replaced under the reader (``create_session(..., overwrite=True)``): the columns' arrays
    are opened once (:meth:`_array`).
    """

    def __init__(self, path, cache_chunks: int = 0):
        self.path = Path(path)
        self._cache_chunks = cache_chunks
        self._chunks: dict[int, np.ndarray] = {}  # chunk number -> its committed events, oldest first
        self._arrays: dict[tuple[str, str], tuple] = {}  # (table, column) -> (Zarr array, codec), see _array
        self.reload()

    def reload(self) -> None:
        # Never through consolidated metadata: it is stale while a session is being written or
        # updated, and the committed lengths are the truth.
        root = _check_root(self.path)
        self._counts = _check_tables(self.path, root)
        self.root = root
        self._arrays = {}
        self.attrs = dict(root.attrs)
        self.width = int(self.attrs["width"])
        self.height = int(self.attrs["height"])

    def _n(self, name: str) -> int:
        """Committed rows of a table, looked up anew (a live writer may have added some)."""
        if name not in self.root:
            return 0
        group = self.root[name]
        n = group.attrs.get("n_committed", 0)
        if _is_count(n) and n <= self._counts.get(name, 0):
            return n
        if not _is_count(n) or any(group[c].shape[0] < n for c in group.array_keys()):
            raise SessionError(f"{self.path}: damaged session: {name}/ n_committed = {n!r} "
                               "(expected a row count within its columns)")
        self._counts[name] = n
        return n

    def read_column(self, name: str, column: str, i0: int, i1: int, step: int | None = None) -> np.ndarray:
        """Rows ``i0:i1[:step]`` of a column's committed rows (sliced as a list is: clipped to them,
        negative indices counted from their end); a damaged chunk (checksum, decompression or file
        error) raises :class:`SessionError` naming the column and the chunk's rows."""
        return self._rows(name, column, i0, i1, step, self._n(name))

    def _rows(self, name: str, column: str, i0: int, i1: int, step: int | None, n: int) -> np.ndarray:
        """:meth:`read_column` of a table of ``n`` committed rows."""
        i0, i1, _ = slice(i0, i1).indices(n)
        i1 = max(i0, i1)
        arr, codec = self._array(name, column, i1)
        rows = arr.chunks[0]
        try:
            if codec is not None and step is None and arr.ndim == 1:
                return codec.read(i0, i1)
            return arr[i0:i1:step]
        except _BadChunk as bad:  # the codec names its chunk
            cause, chunk = bad.__cause__, bad.index
        except Exception as exc:
            cause, chunk = exc, None
            for c in range(i0 // rows, -(-i1 // rows)):  # find the first bad chunk
                try:
                    arr[c * rows:min((c + 1) * rows, arr.shape[0])]
                except Exception as bad:
                    cause, chunk = bad, c
                    break
        if chunk is not None:
            i0, i1 = chunk * rows, min((chunk + 1) * rows, arr.shape[0])
        raise SessionError(f"{self.path}: damaged session: {name}/{column} rows {i0}..{i1 - 1} "
                           f"cannot be read ({_reason(cause)})") from cause

    @property
    def n_events(self) -> int:
        """Number of committed events."""
        return self._n("events")

    @property
    def damage(self) -> str | None:
        """One line on what the store lacks (events left out as out of time order, events that
        could not be written), or None when it holds everything it received."""
        attrs = self.root["events"].attrs
        notes = []
        if attrs.get("n_out_of_order"):
            runs = attrs.get("out_of_order", [])
            first = f", first before index {runs[0][0]} (t = {runs[0][1]} µs)" if runs else ""
            notes.append(f"{attrs['n_out_of_order']} events left out as out of time order (corrupted time "
                         f"words) in {len(runs)} run(s){first}")
        for table in ("events", "triggers"):
            lost = self.root[table].attrs.get("lost")
            if lost:
                notes.append(f"{lost[2]} {table} from index {lost[0]} on were not stored ({lost[3]})")
        if self.cut_short:
            notes.append(f"the recording was cut short (killed or crashed) and its store may end before its RAW "
                         f"file {self.attrs['raw_file']}: `python -m capture.ingest recover {self.path}` completes it")
        raw_error = (self.attrs.get("recording") or {}).get("raw_write_error")
        if raw_error:
            notes.append(f"the recording stopped when its RAW file could not be written ({raw_error}); the RAW "
                         "file may hold events after the store's last one")
        return "; ".join(notes) or None

    @property
    def cut_short(self) -> bool:
        """True for a recording that ended without its recorder closing it (killed, crashed, power
        lost): its store may end before its RAW file (:func:`capture.ingest.recover_session`)."""
        return ("raw_file" in self.attrs and "recording" not in self.attrs
                and (self.path / str(self.attrs["raw_file"])).is_file() and not being_written(self.path))

    @property
    def duration_s(self) -> float:
        """Time from the first to the last committed event, s (0 without events)."""
        n = self.n_events
        if n == 0:
            return 0.0
        return (int(self.read_column("events", "t", n - 1, n)[0]) - int(self.read_column("events", "t", 0, 1)[0])) * 1e-6

    def _array(self, name: str, column: str, rows: int):
        """The Zarr array of a table's column and its :class:`_ChunkCodec` (None where Zarr
        decodes), opened once, and again when a read needs more than its ``shape`` held then (a
        live writer grows it): each opening reads metadata from disk, a fifth of the time of
        reading a session's events in batches before."""
        found = self._arrays.get((name, column))
        if found is None or found[0].shape[0] < rows:
            arr = self.root[name][column]
            found = self._arrays[(name, column)] = (arr, _ChunkCodec(arr) if _ChunkCodec.fits(arr) else None)
        return found

    def _read(self, name: str, columns, i0: int = 0, i1: int | None = None, n: int | None = None
              ) -> dict[str, np.ndarray]:
        """Rows ``i0:i1`` of the table's ``columns`` (None for a column it lacks), of its ``n``
        committed rows (looked up when not given)."""
        n = self._n(name) if n is None else n
        i1 = n if i1 is None else min(i1, n)
        if all((name, c) in self._arrays for c in columns):  # opened before: all there
            present = columns
        else:
            present = set(self.root[name].array_keys()) if name in self.root else set()
        return {c: (self._rows(name, c, i0, i1, None, n) if c in present else None) for c in columns}

    def events_range(self, i0: int, i1: int) -> np.ndarray:
        """Committed events with index ``i0 <= i < i1`` as an EVENT_DTYPE array."""
        n = self.n_events
        i1 = min(i1, n)
        if self._cache_chunks and i1 > i0:
            return self._cached_range(i0, i1)
        out = np.empty(max(0, i1 - i0), dtype=EVENT_DTYPE)
        if len(out):
            for c, v in self._read("events", _EVENT_COLUMNS, i0, i1, n).items():
                out[c] = v
        return out

    def _cached_range(self, i0: int, i1: int) -> np.ndarray:
        """:meth:`events_range` through whole decompressed chunks, the last ``cache_chunks`` kept
        (reads of nearby times then decompress each chunk once, not once per read)."""
        pieces = []
        for c in range(i0 // EVENT_CHUNK, (i1 - 1) // EVENT_CHUNK + 1):
            c0 = c * EVENT_CHUNK
            chunk = self._chunks.pop(c, None)
            if chunk is None or c0 + len(chunk) < min(i1, c0 + EVENT_CHUNK):  # absent, or committed since
                chunk = np.empty(min(self.n_events, c0 + EVENT_CHUNK) - c0, dtype=EVENT_DTYPE)
                for name, v in self._read("events", _EVENT_COLUMNS, c0, c0 + len(chunk)).items():
                    chunk[name] = v
            self._chunks[c] = chunk  # the most recently used last
            pieces.append(chunk[max(i0 - c0, 0):i1 - c0])
        while len(self._chunks) > self._cache_chunks:
            self._chunks.pop(next(iter(self._chunks)))
        return pieces[0].copy() if len(pieces) == 1 else np.concatenate(pieces)

    def _indexed(self) -> bool:
        """Whether the ms index has committed rows to look times up in."""
        return "t0_ms" in self.root["index"].attrs and self._n("index") > 0

    def _index_span(self, t_us: int) -> tuple[int, int]:
        """Event indices ``lo <= hi`` between which the first committed event with ``t >= t_us``
        lies, from the ms index (``(0, n)`` without one)."""
        n = self.n_events
        if not self._indexed():
            return 0, n
        k = t_us // 1000 - int(self.root["index"].attrs["t0_ms"])
        if k < 0:
            return 0, 0
        n_index = self._n("index")
        k = min(k, n_index - 1)
        bounds = self.read_column("index", "ms_to_idx", k, min(k + 2, n_index))  # the next ms's first event
        lo = min(int(bounds[0]), n)  # the index may be committed past our n
        hi = min(int(bounds[1]), n) if len(bounds) > 1 else n
        return lo, max(lo, hi)

    def event_index(self, t_us: int) -> int:
        """Index of the first committed event with ``t >= t_us`` (uses the ms index)."""
        lo, hi = self._index_span(t_us)
        if hi <= lo:
            return lo
        t = self.read_column("events", "t", lo, hi)
        return lo + int(np.searchsorted(t, t_us, side="left"))

    def events(self, t_start_us: int | None = None, t_end_us: int | None = None) -> np.ndarray:
        """Committed events with ``t_start_us <= t < t_end_us`` (``None``: unbounded).

        With the ms index, the events from the start's ms to the end's ms are read at once and
        cut to the exact times (each stored chunk is decompressed once).
        """
        n = self.n_events
        if not self._indexed():  # look each end up (reading only times), then read the range
            i0 = 0 if t_start_us is None else self.event_index(int(t_start_us))
            i1 = n if t_end_us is None else self.event_index(int(t_end_us))
            return self.events_range(i0, i1)
        i0 = 0 if t_start_us is None else self._index_span(int(t_start_us))[0]
        i1 = n if t_end_us is None else self._index_span(int(t_end_us))[1]
        ev = self.events_range(i0, i1)
        return time_slice(ev, t_start_us, t_end_us)

    def iter_events(self, batch: int = EVENT_CHUNK, prefetch: bool = False):
        """Yield committed events in batches of at most ``batch`` (bounded memory).

        With ``prefetch``, the next batch is read and decompressed in a background thread
        while the caller works on the current one (two batches in memory).
        """
        n = self.n_events
        if not prefetch:
            for i0 in range(0, n, batch):
                yield self.events_range(i0, i0 + batch)
            return
        with ThreadPoolExecutor(1, thread_name_prefix="session-prefetch") as reader:
            upcoming = reader.submit(self.events_range, 0, batch) if n else None
            for i0 in range(0, n, batch):
                current = upcoming.result()
                if i0 + batch < n:
                    upcoming = reader.submit(self.events_range, i0 + batch, i0 + 2 * batch)
                yield current

    def events_dask(self) -> dict:
        """The committed events as Dask arrays, one per column (``t`` µs int64, ``x``/``y`` uint16,
        ``p`` int8), chunked as stored (:data:`EVENT_CHUNK` events): for analyses larger than memory
        or spread over a cluster (workers need the session at the same path). Needs ``dask``
        (``pip install 'courtside-spin[cluster]'``).
        """
        import dask.array as da

        n = self.n_events
        return {c: da.from_zarr(self.root["events"][c])[:n] for c in _EVENT_COLUMNS}

    def triggers(self) -> np.ndarray:
        """All committed triggers (TRIGGER_DTYPE)."""
        cols = self._read("triggers", _TRIGGER_COLUMNS)
        out = np.empty(self._n("triggers"), dtype=TRIGGER_DTYPE)
        for c, v in cols.items():
            if v is not None:
                out[c] = v
        return out

    def track(self) -> dict[str, np.ndarray]:
        """Ball track table (``capture.events.TRACK_COLUMNS``); empty columns if none stored."""
        return self._table("track", TRACK_COLUMNS)

    def spin(self) -> dict[str, np.ndarray]:
        """Spin table (``capture.events.SPIN_COLUMNS``); empty columns if none stored."""
        return self._table("spin", SPIN_COLUMNS)

    def frames(self) -> dict:
        """Frame times ``t_us`` (µs, event clock), ``image`` (or None) and ``video`` path (or None)."""
        cols = self._read("frames", ["t_us", "image"])
        t = cols["t_us"] if cols["t_us"] is not None else np.zeros(0, np.int64)
        video = self.root["frames"].attrs.get("video") if "frames" in self.root else None
        return {"t_us": t, "image": cols["image"],
                "video": str(self.path / video) if video else None}

    def _table(self, name: str, columns) -> dict[str, np.ndarray]:
        """The table's columns; a column the store lacks (written by an older version) reads as
        :func:`capture.events.missing_value` says, one per row."""
        n = self._n(name)
        full = empty_table(columns, n)
        for k, (dtype, _) in columns.items():
            full[k][...] = missing_value(k, dtype)
        return {k: (v if v is not None else full[k]) for k, v in self._read(name, columns).items()}


def open_session(path, cache_chunks: int = 0) -> Session:
    """Open a session for reading; raises :class:`SessionError` with a one-line reason.

    ``cache_chunks``: keep this many decompressed chunks of events (2^20 events, 16 MiB each) for
    many reads of nearby times, e.g. one per spin window (0: none, each read decompresses what
    it needs).
    """
    return Session(path, cache_chunks)


def disk_free_bytes(path) -> int:
    """Free bytes on the file system holding ``path``."""
    st = os.statvfs(Path(path))
    return st.f_bavail * st.f_frsize
