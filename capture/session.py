"""Crash-safe session store: one Zarr v3 group per recorded session.

Layout (names are fixed; other tools rely on them)::

    SESSION_DIR/                    root group, attrs: kind, schema_version, sensor, ...
        events/{t,x,y,p}            CD events as 1-D columns (t µs int64, x/y uint16, p int8)
        index/ms_to_idx             first event index with t >= (t0_ms + k) * 1000
        triggers/{t,id,p}           external trigger events
        frames/{t_us}               frame timestamps on the event clock (+ optional image)
        track/{t_us,cx,cy,r,vx,vy,score,flight}           capture.events.TRACK_COLUMNS
        spin/{t_start_us,t_end_us,axis,omega_rad_s,...}   capture.events.SPIN_COLUMNS

Every table is a group of arrays sharing their first axis plus an attribute
``n_committed``. A writer resizes, writes the data and only then raises
``n_committed``; readers never look past it. A writer killed mid-append
therefore leaves a store whose committed prefix is intact (Zarr's local store
writes each file atomically). Metadata is consolidated when a session is closed.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import time
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from importlib import metadata
from pathlib import Path

import warnings

import numpy as np
import zarr
from zarr.codecs import BloscCodec
from zarr.codecs.numcodecs import Delta

from capture.events import EVENT_DTYPE, SPIN_COLUMNS, TRACK_COLUMNS, TRIGGER_DTYPE, concatenate, empty_table, spin_table

# We knowingly use two Zarr extensions (the numcodecs Delta filter, consolidated metadata).
warnings.filterwarnings("ignore", message="Numcodecs codecs are not in", category=UserWarning)
warnings.filterwarnings("ignore", message="Consolidated metadata is currently not", category=UserWarning)
# A session directory also holds non-Zarr files (the RAW byte stream, the GoPro video).
warnings.filterwarnings("ignore", message="Object at .* is not recognized as a component", category=UserWarning)

SCHEMA_VERSION = 1
SESSION_KIND = "courtside-spin session"
EVENT_CHUNK = 1 << 20
"""Events per chunk of each ``events/*`` array."""
TABLE_CHUNK = 1 << 16
"""Rows per chunk of the smaller tables."""

_EVENT_COLUMNS = {"t": ("<i8", ()), "x": ("<u2", ()), "y": ("<u2", ()), "p": ("i1", ())}
_TRIGGER_COLUMNS = {"t": ("<i8", ()), "id": ("u1", ()), "p": ("i1", ())}


class SessionError(Exception):
    """A path is not a usable session (missing, not a session, newer schema, ...)."""


def _software_version() -> str:
    try:
        return metadata.version("courtside-spin")
    except metadata.PackageNotFoundError:
        return "unknown"


def _codecs(name: str, dtype: str):
    compressor = BloscCodec(cname="zstd", clevel=3, shuffle="bitshuffle")
    filters = [Delta(dtype=dtype)] if name in ("t", "t_us") else None
    return filters, compressor


def _columns_of(rows, fields: Mapping) -> dict[str, np.ndarray]:
    """Columns from a mapping, an object with attributes, or a structured array."""
    out = {}
    for name in fields:
        if isinstance(rows, np.ndarray) and rows.dtype.names:
            value = rows[name]
        elif isinstance(rows, Mapping):
            value = rows[name]
        else:
            value = getattr(rows, name)
        out[name] = np.asarray(value)
    lengths = {len(v) for v in out.values()}
    if len(lengths) > 1:
        raise ValueError(f"columns have different lengths: { {k: len(v) for k, v in out.items()} }")
    return out


class _Table:
    """Writer side of one table: arrays sharing the first axis plus ``n_committed``."""

    def __init__(self, group: zarr.Group, columns: Mapping[str, tuple[str, tuple]], chunk: int):
        self.group = group
        self.columns = dict(columns)
        self.arrays = {}
        for name, (dtype, tail) in self.columns.items():
            if name in group:
                self.arrays[name] = group[name]
            else:
                filters, compressor = _codecs(name, dtype)
                self.arrays[name] = group.create_array(
                    name, shape=(0, *tail), chunks=(chunk, *tail), dtype=dtype,
                    filters=filters, compressors=compressor, fill_value=0)
        if "n_committed" not in group.attrs:
            group.attrs["n_committed"] = 0
        self.n = int(group.attrs["n_committed"])

    def append(self, cols: Mapping[str, np.ndarray]) -> None:
        m = len(next(iter(cols.values())))
        if m == 0:
            return
        n_new = self.n + m
        for name, arr in self.arrays.items():
            arr.resize((n_new, *arr.shape[1:]))
            arr[self.n:n_new] = np.asarray(cols[name], dtype=arr.dtype)
        self.n = n_new
        self.group.attrs["n_committed"] = n_new

    def replace(self, cols: Mapping[str, np.ndarray]) -> None:
        self.group.attrs["n_committed"] = 0
        self.n = 0
        for arr in self.arrays.values():
            arr.resize((0, *arr.shape[1:]))
        self.append(cols)


class SessionWriter:
    """The one writer of a session. Use :func:`create_session` or :func:`update_session`.

    Events are buffered and written in whole chunks of :data:`EVENT_CHUNK`; the
    buffer is also flushed (committed) at least every ``flush_interval_s``
    seconds of wall time, so a crash loses at most that much.
    """

    def __init__(self, root: zarr.Group, path: Path, flush_interval_s: float = 1.0):
        self.root = root
        self.path = path
        self.flush_interval_s = flush_interval_s
        self._events = _Table(root.require_group("events"), _EVENT_COLUMNS, EVENT_CHUNK)
        self._triggers = _Table(root.require_group("triggers"), _TRIGGER_COLUMNS, TABLE_CHUNK)
        index = root.require_group("index")
        if "ms_to_idx" not in index:
            filters, compressor = _codecs("ms_to_idx", "<i8")
            index.create_array("ms_to_idx", shape=(0,), chunks=(TABLE_CHUNK,), dtype="<i8",
                               compressors=compressor, fill_value=0)
            index.attrs["n_committed"] = 0
        self._index = index
        self._buffer: list[np.ndarray] = []
        self._buffered = 0
        self._last_flush = time.monotonic()
        self._last_t = None
        if self._events.n:
            self._last_t = int(self._events.arrays["t"][self._events.n - 1])
        self.closed = False

    # -- events -----------------------------------------------------------------------------
    @property
    def n_events(self) -> int:
        """Events committed plus events buffered."""
        return self._events.n + self._buffered

    def append_events(self, events: np.ndarray) -> None:
        """Queue a batch of EVENT_DTYPE events (t non-decreasing, also across batches)."""
        events = np.asarray(events)
        if events.dtype != EVENT_DTYPE:
            raise TypeError(f"events must have EVENT_DTYPE, got {events.dtype}")
        if len(events):
            t = events["t"]
            if (self._last_t is not None and t[0] < self._last_t) or np.any(t[1:] < t[:-1]):
                raise ValueError("event timestamps must be non-decreasing across appends")
            self._last_t = int(t[-1])
            self._buffer.append(events)
            self._buffered += len(events)
        aligned = (self._events.n + self._buffered) // EVENT_CHUNK * EVENT_CHUNK
        if aligned > self._events.n:
            self._write_events(aligned - self._events.n)
        self.flush_if_due()

    def _write_events(self, count: int) -> None:
        data = concatenate(self._buffer)
        head, tail = data[:count], data[count:]
        self._buffer = [tail] if len(tail) else []
        self._buffered = len(tail)
        n0 = self._events.n
        self._events.append({name: head[name] for name in _EVENT_COLUMNS})
        self._extend_index(head["t"], n0)

    def _extend_index(self, t_new: np.ndarray, n0: int) -> None:
        """Add the ms-index entries that the new events make final."""
        idx_arr = self._index["ms_to_idx"]
        k = int(self._index.attrs["n_committed"])
        if "t0_ms" not in self._index.attrs:
            self._index.attrs["t0_ms"] = int(t_new[0] // 1000)
        t0_ms = int(self._index.attrs["t0_ms"])
        last_ms = int(t_new[-1] // 1000)
        ms = np.arange(t0_ms + k, last_ms + 1, dtype=np.int64)
        if len(ms) == 0:
            return
        entries = n0 + np.searchsorted(t_new, ms * 1000, side="left")
        idx_arr.resize((k + len(ms),))
        idx_arr[k:] = entries
        self._index.attrs["n_committed"] = k + len(ms)

    def append_triggers(self, triggers: np.ndarray) -> None:
        """Append and commit TRIGGER_DTYPE events."""
        triggers = np.asarray(triggers)
        if triggers.dtype != TRIGGER_DTYPE:
            raise TypeError(f"triggers must have TRIGGER_DTYPE, got {triggers.dtype}")
        self._triggers.append({name: triggers[name] for name in _TRIGGER_COLUMNS})

    def flush_if_due(self) -> None:
        """Flush when ``flush_interval_s`` has passed since the last flush."""
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self.flush()

    def flush(self) -> None:
        """Write and commit every buffered event."""
        if self._buffered:
            self._write_events(self._buffered)
        self._last_flush = time.monotonic()

    # -- tables and attributes ----------------------------------------------------------------
    def _table(self, name: str, columns: Mapping[str, tuple[str, tuple]]) -> _Table:
        return _Table(self.root.require_group(name), columns, TABLE_CHUNK)

    def append_track(self, track) -> None:
        """Append ball-track rows (mapping or object with the ``capture.events.TRACK_COLUMNS``)."""
        self._table("track", TRACK_COLUMNS).append(_columns_of(track, TRACK_COLUMNS))

    def write_track(self, track) -> None:
        """Replace the whole ball track."""
        self._table("track", TRACK_COLUMNS).replace(_columns_of(track, TRACK_COLUMNS))

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
        table = _Table(self.root.require_group("frames"), columns, 1 if images is not None else TABLE_CHUNK)
        table.append(cols)

    def set_video(self, relpath: str, t_us) -> None:
        """Reference a video file (path relative to the session) with its frame times (µs, event clock)."""
        frames = self.root.require_group("frames")
        frames.attrs["video"] = str(relpath)
        _Table(frames, {"t_us": ("<i8", ())}, TABLE_CHUNK).replace({"t_us": np.asarray(t_us, np.int64)})

    def set_attrs(self, **attrs) -> None:
        """Set JSON-serialisable root attributes (sensor, frame_camera, calibration, time_sync, ...)."""
        json.dumps(attrs)  # fail early, with JSON's own message, on non-serialisable values
        self.root.attrs.update(attrs)

    # -- life cycle ---------------------------------------------------------------------------
    def close(self) -> None:
        """Flush, mark the session closed and consolidate its metadata."""
        if self.closed:
            return
        self.flush()
        self.root.attrs["closed"] = True
        zarr.consolidate_metadata(str(self.path))
        self.closed = True

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def create_session(path, *, width: int, height: int, attrs: Mapping | None = None,
                   overwrite: bool = False, flush_interval_s: float = 1.0) -> SessionWriter:
    """Create a new session directory and return its writer.

    Parameters
    ----------
    path : str or Path
        Session directory (must be empty; ``overwrite`` replaces an existing store and keeps the
        directory's other files, such as the RAW byte stream and the videos).
    width, height : int
        Event sensor geometry in pixels.
    attrs : mapping, optional
        Extra root attributes (sensor model/serial/format/biases, frame camera, ...).
    """
    path = Path(path)
    if path.exists() and any(path.iterdir()):
        if not overwrite:
            raise SessionError(f"{path}: already exists and is not empty")
        _remove_store(path)
    root = zarr.open_group(str(path), mode="a" if overwrite else "w-", zarr_format=3)
    root.attrs.update({
        "kind": SESSION_KIND,
        "schema_version": SCHEMA_VERSION,
        "width": int(width),
        "height": int(height),
        "software_version": _software_version(),
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "closed": False,
        **(dict(attrs) if attrs else {}),
    })
    return SessionWriter(root, path, flush_interval_s)


_STORE_ENTRIES = ("zarr.json", "events", "index", "triggers", "frames", "track", "spin")


def _remove_store(path: Path) -> None:
    """Delete a session's Zarr entries, keeping the other files (the RAW stream, the videos)."""
    import shutil

    for name in _STORE_ENTRIES:
        entry = path / name
        if entry.is_dir():
            shutil.rmtree(entry)
        elif entry.exists():
            entry.unlink()


def update_session(path, flush_interval_s: float = 1.0) -> SessionWriter:
    """Reopen an existing session for writing (e.g. replay writing track and spin)."""
    path = Path(path)
    _check_root(path)
    root = zarr.open_group(str(path), mode="r+", use_consolidated=False)
    root.attrs["closed"] = False
    return SessionWriter(root, path, flush_interval_s)


def _check_root(path: Path) -> zarr.Group:
    if not path.exists():
        raise SessionError(f"{path}: no such session directory")
    if not (path / "zarr.json").is_file():
        raise SessionError(f"{path}: not a session (no Zarr v3 group here)")
    try:
        root = zarr.open_group(str(path), mode="r", use_consolidated=False)
    except Exception as exc:  # zarr raises several types for broken metadata
        raise SessionError(f"{path}: not a readable Zarr group ({exc})") from exc
    attrs = root.attrs
    if attrs.get("kind") != SESSION_KIND:
        raise SessionError(f"{path}: not a session (Zarr group without kind={SESSION_KIND!r})")
    version = int(attrs.get("schema_version", -1))
    if version > SCHEMA_VERSION:
        raise SessionError(f"{path}: session schema version {version} is newer than this software "
                           f"supports ({SCHEMA_VERSION}); upgrade courtside-spin")
    return root


class Session:
    """Read-only view of a session.

    Every read looks up the committed lengths anew, so a reader follows a live
    writer's appends; :meth:`reload` refreshes the root attributes.
    """

    def __init__(self, path):
        self.path = Path(path)
        self.reload()

    def reload(self) -> None:
        # Never through consolidated metadata: it is stale while a session is being written or
        # updated, and the committed lengths are the truth.
        root = _check_root(self.path)
        self.root = root
        self.attrs = dict(root.attrs)
        self.width = int(self.attrs["width"])
        self.height = int(self.attrs["height"])

    def _n(self, name: str) -> int:
        return int(self.root[name].attrs.get("n_committed", 0)) if name in self.root else 0

    @property
    def n_events(self) -> int:
        """Number of committed events."""
        return self._n("events")

    @property
    def duration_s(self) -> float:
        """Time from the first to the last committed event, s (0 without events)."""
        n = self.n_events
        if n == 0:
            return 0.0
        t = self.root["events"]["t"]
        return (int(t[n - 1]) - int(t[0])) * 1e-6

    def _read(self, name: str, columns, i0: int = 0, i1: int | None = None) -> dict[str, np.ndarray]:
        n = self._n(name)
        i1 = n if i1 is None else min(i1, n)
        group = self.root[name] if name in self.root else None
        return {c: (group[c][i0:i1] if group is not None and c in group else None) for c in columns}

    def events_range(self, i0: int, i1: int) -> np.ndarray:
        """Committed events with index ``i0 <= i < i1`` as an EVENT_DTYPE array."""
        i1 = min(i1, self.n_events)
        out = np.empty(max(0, i1 - i0), dtype=EVENT_DTYPE)
        if len(out):
            for c, v in self._read("events", _EVENT_COLUMNS, i0, i1).items():
                out[c] = v
        return out

    def event_index(self, t_us: int) -> int:
        """Index of the first committed event with ``t >= t_us`` (uses the ms index)."""
        n = self.n_events
        if n == 0:
            return 0
        index = self.root["index"]
        k_max = int(index.attrs.get("n_committed", 0))
        lo, hi = 0, n
        if k_max and "t0_ms" in index.attrs:
            k = t_us // 1000 - int(index.attrs["t0_ms"])
            ms_to_idx = index["ms_to_idx"]
            if k < 0:
                return 0
            if k < k_max:
                lo = int(ms_to_idx[k])
            else:
                lo = int(ms_to_idx[k_max - 1])
            if k + 1 < k_max:
                hi = int(ms_to_idx[k + 1])
            lo, hi = min(lo, n), min(hi, n)  # the index may be committed past our n
        if hi <= lo:
            return lo
        t = self.root["events"]["t"][lo:hi]
        return lo + int(np.searchsorted(t, t_us, side="left"))

    def events(self, t_start_us: int | None = None, t_end_us: int | None = None) -> np.ndarray:
        """Committed events with ``t_start_us <= t < t_end_us`` (``None``: unbounded)."""
        i0 = 0 if t_start_us is None else self.event_index(int(t_start_us))
        i1 = self.n_events if t_end_us is None else self.event_index(int(t_end_us))
        return self.events_range(i0, i1)

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
        """The table's columns; a column the store lacks (written by an older version) reads as NaN
        (floats) or zeros, one per row."""
        n = self._n(name)
        full = empty_table(columns, n)
        for k, (dtype, _) in columns.items():
            if np.dtype(dtype).kind == "f":
                full[k][...] = np.nan
        return {k: (v if v is not None else full[k]) for k, v in self._read(name, columns).items()}


def open_session(path) -> Session:
    """Open a session for reading; raises :class:`SessionError` with a one-line reason."""
    return Session(path)


def disk_free_bytes(path) -> int:
    """Free bytes on the file system holding ``path``."""
    st = os.statvfs(Path(path))
    return st.f_bavail * st.f_frsize
