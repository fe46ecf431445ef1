"""The data contracts shared by every module (see ``docs/conventions.md``), declared once.

- :data:`EVENT_DTYPE`, :data:`TRIGGER_DTYPE`: a batch of change-detection (CD) events is a
  1-D NumPy structured array of :data:`EVENT_DTYPE`; external trigger events use
  :data:`TRIGGER_DTYPE`. Times are integer microseconds on the event camera's clock,
  non-decreasing within a batch.
- :data:`BALL_DIAMETER_M`: the ball presets (``--ball``), their diameters.
- :data:`TRACK_COLUMNS` and :class:`Track`: the ball track (detection's output, the session
  store's ``track/`` table, the review's ball circle).
- :data:`SPIN_COLUMNS` and :func:`spin_table`: spin estimates as columns (the spin
  estimator's output, the session store's ``spin/`` table, the review's plots).

A table is a ``dict`` of equal-length NumPy columns; ``*_COLUMNS`` map each column name to
``(dtype, shape of one row)``.
"""

from __future__ import annotations

import bisect
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields

import numpy as np

EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
"""CD event: ``t`` µs, ``x`` column, ``y`` row, ``p`` 1 = ON, 0 = OFF."""

TRIGGER_DTYPE = np.dtype([("t", "<i8"), ("id", "u1"), ("p", "i1")])
"""External trigger: ``t`` µs, ``id`` channel, ``p`` edge (1 rising, 0 falling)."""


def empty_events(n: int = 0) -> np.ndarray:
    """Zero-filled event array of length ``n`` (EVENT_DTYPE)."""
    return np.zeros(n, dtype=EVENT_DTYPE)


def empty_triggers(n: int = 0) -> np.ndarray:
    """Zero-filled trigger array of length ``n`` (TRIGGER_DTYPE)."""
    return np.zeros(n, dtype=TRIGGER_DTYPE)


def make_events(t_us, x, y, p) -> np.ndarray:
    """Build an EVENT_DTYPE array from four equal-length columns.

    Parameters
    ----------
    t_us : array_like of int, shape (N,)
        Timestamps in microseconds.
    x, y : array_like of int, shape (N,)
        Pixel column and row.
    p : array_like of int or bool, shape (N,)
        Polarity, 1 (ON) or 0 (OFF).
    """
    t_us = np.asarray(t_us)
    out = np.empty(t_us.shape[0], dtype=EVENT_DTYPE)
    out["t"] = t_us
    out["x"] = x
    out["y"] = y
    out["p"] = p
    return out


def make_triggers(t_us, channel, p) -> np.ndarray:
    """Build a TRIGGER_DTYPE array from columns ``t_us``, ``channel`` (id) and edge ``p``."""
    t_us = np.asarray(t_us)
    out = np.empty(t_us.shape[0], dtype=TRIGGER_DTYPE)
    out["t"] = t_us
    out["id"] = channel
    out["p"] = p
    return out


def as_void(records: np.ndarray) -> np.ndarray:
    """Records as opaque bytes (same memory): NumPy copies, joins and gathers those ~20x faster
    than multi-field records of odd size such as EVENT_DTYPE's 13 bytes."""
    return records.view(np.dtype((np.void, records.dtype.itemsize)))


def concatenate(batches: Iterable[np.ndarray], dtype: np.dtype = EVENT_DTYPE) -> np.ndarray:
    """Join batches of records end to end (fast; a single batch is returned as it is); an
    empty iterable gives an empty array of ``dtype``."""
    batches = [np.asarray(b, dtype=dtype) for b in batches]
    if not batches:
        return np.zeros(0, dtype=dtype)
    if len(batches) == 1:
        return batches[0]
    return np.concatenate([as_void(b) for b in batches]).view(dtype)


def first_at(t_us: np.ndarray, value_us: int) -> int:
    """Index of the first element of the non-decreasing ``t_us`` that is ``>= value_us``
    (``np.searchsorted(t_us, value_us, side="left")``), without copying ``t_us``: NumPy copies a
    strided column such as ``events["t"]`` whole before searching it (8 MB per million events),
    a bisection reads about 20 of its elements."""
    return bisect.bisect_left(t_us, value_us)


def time_slice(events: np.ndarray, t_start_us: int | None = None, t_end_us: int | None = None) -> np.ndarray:
    """Events with ``t_start_us <= t < t_end_us`` (a view; ``None`` means unbounded).

    Uses binary search, so ``events["t"]`` must be non-decreasing.
    """
    t = events["t"]
    i0 = 0 if t_start_us is None else first_at(t, t_start_us)
    i1 = len(t) if t_end_us is None else first_at(t, t_end_us)
    return events[i0:max(i0, i1)]


def signed_polarity(events: np.ndarray) -> np.ndarray:
    """Polarity as ``+1`` (ON) / ``-1`` (OFF), int8, shape (N,)."""
    return (2 * events["p"].astype(np.int8) - 1).astype(np.int8)


def is_sorted(events: np.ndarray) -> bool:
    """True if ``events["t"]`` is non-decreasing."""
    t = events["t"]
    return bool(t.size < 2 or np.all(t[1:] >= t[:-1]))



def in_order_mask(t_us: np.ndarray, floor_us: int | None = None) -> np.ndarray:
    """Which events to keep so that the times are non-decreasing, leaving out as few as a
    local rule can (a corrupted time word puts a short run of events out of line).

    Events below ``floor_us`` (the last time already kept before this batch) are left out.
    Of the rest, every maximal run of indices involved in an inversion is repaired by leaving
    out either the events that are later than some event after them ("high") or those earlier
    than some event before them ("low"), whichever are fewer in that run. A run is bounded by
    events later than all before and earlier than all after them, so the runs' repairs are
    independent.

    Parameters
    ----------
    t_us : ndarray of int64, shape (N,)
        Event times, µs.
    floor_us : int, optional
        Least time allowed, µs (None: no floor).

    Returns
    -------
    ndarray of bool, shape (N,)
        True for the events kept; ``t_us[mask]`` is non-decreasing and ``>= floor_us``.
    """
    t = np.asarray(t_us, dtype=np.int64)
    keep = np.ones(len(t), dtype=bool)
    if floor_us is not None:
        keep &= t >= floor_us
    idx = np.flatnonzero(keep)
    u = t[idx]
    if len(u) < 2 or np.all(u[1:] >= u[:-1]):
        return keep
    before_max = np.maximum.accumulate(u)  # max of u[:i+1]
    low = np.zeros(len(u), dtype=bool)
    low[1:] = u[1:] < before_max[:-1]
    after_min = np.minimum.accumulate(u[::-1])[::-1]  # min of u[i:]
    high = np.zeros(len(u), dtype=bool)
    high[:-1] = u[:-1] > after_min[1:]
    flagged = (low | high).astype(np.int8)
    edges = np.diff(np.concatenate(([0], flagged, [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    n_low = np.add.reduceat(low, starts) if len(starts) else np.zeros(0, int)
    n_high = np.add.reduceat(high, starts) if len(starts) else np.zeros(0, int)
    drop = np.zeros(len(u), dtype=bool)
    for a, b, nl, nh in zip(starts.tolist(), ends.tolist(), n_low.tolist(), n_high.tolist()):
        drop[a:b] = low[a:b] if nl <= nh else high[a:b]
    keep[idx[drop]] = False
    return keep

# -- tables ------------------------------------------------------------------------------------

BALL_DIAMETER_M = {"volleyball": 0.21, "soccer": 0.22, "basketball": 0.24, "tennis": 0.067,
                   "tabletennis": 0.040, "baseball": 0.074, "handball": 0.19}
"""Ball diameters by sport (m), for distances and speeds."""

TRACK_COLUMNS: dict[str, tuple[str, tuple]] = {
    "t_us": ("<i8", ()), "cx": ("<f8", ()), "cy": ("<f8", ()), "r": ("<f8", ()),
    "vx": ("<f8", ()), "vy": ("<f8", ()), "score": ("<f4", ()), "flight": ("<i4", ()), "sigma_px": ("<f4", ())}
"""Ball track: update time µs, centre and radius px, centre velocity px/s, score 0..1, flight number,
and the circle's uncertainty (1 sigma, px: see :class:`Track`; NaN where not measured, e.g. sessions
written before this column existed)."""

TRACK_OPTIONAL = ("sigma_px",)
"""Track columns that a table or track given by a caller may lack (then NaN: not measured)."""

SPIN_COLUMNS: dict[str, tuple[str, tuple]] = {
    "t_start_us": ("<i8", ()), "t_end_us": ("<i8", ()), "axis": ("<f8", (3,)),
    "omega_rad_s": ("<f8", ()), "rps": ("<f8", ()), "velocity_px_s": ("<f8", (2,)),
    "confidence": ("<f4", ()), "axis_sigma_deg": ("<f4", ()), "rps_sigma_pct": ("<f4", ()),
    "rps_lag_pct": ("<f4", ()), "flight": ("<i4", ())}
"""Spin estimates: window µs (end exclusive), unit axis in the camera frame, rad/s, rev/s,
centre velocity px/s, confidence 0..1, uncertainty (1 sigma) of the axis in degrees and of the
rate in %, and the part of the latter from the sensor's lag in % (a bias the windows of a flight
share; NaN where not measured, e.g. sessions written before these columns existed), and the flight
number of the window (the track's: two balls in view at once give windows of two flights at the
same time; -1 where not known: the flight is then the one whose track rows span the window)."""


def missing_value(name: str, dtype) -> float | int:
    """What a table column holds where it was not given (rows written before it existed, by an
    older version): NaN for floats (not measured), -1 for ``flight`` (not known), else 0."""
    return np.nan if np.dtype(dtype).kind == "f" else (-1 if name == "flight" else 0)


def empty_table(columns: Mapping[str, tuple[str, tuple]], n: int = 0) -> dict[str, np.ndarray]:
    """Zero-filled table of ``n`` rows with the given columns (e.g. :data:`SPIN_COLUMNS`)."""
    return {k: np.zeros((n, *shape), dtype) for k, (dtype, shape) in columns.items()}


def concat_tables(parts: Iterable[Mapping[str, np.ndarray]], columns: Mapping[str, tuple[str, tuple]],
                  sort_by: str | None = None) -> dict[str, np.ndarray]:
    """Rows of ``parts`` one after another (stably sorted by column ``sort_by`` if given)."""
    parts = [p for p in parts if len(next(iter(p.values())))]
    if not parts:
        return empty_table(columns)
    out = {k: np.concatenate([np.asarray(p[k], dtype) for p in parts]) for k, (dtype, _) in columns.items()}
    if sort_by is not None:
        order = np.argsort(out[sort_by], kind="stable")
        out = {k: v[order] for k, v in out.items()}
    return out


def spin_table(spin) -> dict[str, np.ndarray]:
    """Spin estimates as a table of :data:`SPIN_COLUMNS`.

    Parameters
    ----------
    spin : mapping, object or iterable of objects
        A mapping of columns, one estimate, or estimates: any object with the attributes
        named in :data:`SPIN_COLUMNS` (e.g. ``spin.SpinEstimate``).

    The uncertainty columns (``axis_sigma_deg``, ``rps_sigma_pct``, ``rps_lag_pct``) may be missing:
    they are then NaN (not measured); so may ``flight``: it is then -1 (not known).

    Raises
    ------
    KeyError
        A column other than the uncertainties is missing.
    """
    optional = ("axis_sigma_deg", "rps_sigma_pct", "rps_lag_pct", "flight")
    if isinstance(spin, Mapping):
        rows = {k: np.asarray(spin[k]) for k in SPIN_COLUMNS if k in spin or k not in optional}
    else:
        items = [spin] if hasattr(spin, "axis") else list(spin)
        rows = {k: [getattr(s, k) for s in items] for k in SPIN_COLUMNS
                if k not in optional or all(hasattr(s, k) for s in items)}
    n = len(rows["t_start_us"])
    for k in optional:
        rows.setdefault(k, np.full(n, missing_value(k, SPIN_COLUMNS[k][0])))
    return {k: np.asarray(rows[k], dtype=dtype).reshape(n, *shape) for k, (dtype, shape) in SPIN_COLUMNS.items()}


@dataclass
class Track:
    """Ball track, one row per track update, sorted by time; the columns of :data:`TRACK_COLUMNS`.

    Attributes
    ----------
    t_us : ndarray of int64, shape (N,)
        Update time, µs on the event clock.
    cx, cy, r : ndarray of float64, shape (N,)
        Ball circle (centre and radius) in pixels at ``t_us``.
    vx, vy : ndarray of float64, shape (N,)
        Image velocity of the centre, px/s.
    score : ndarray of float32, shape (N,)
        Confidence of the update, 0..1.
    flight : ndarray of int32, shape (N,)
        Flight number (a new one each time the ball enters, is hit or bounces).
    sigma_px : ndarray of float32, shape (N,)
        Uncertainty of the circle (1 sigma), px: the true centre lies within ``2 sigma_px`` of
        ``(cx, cy)``, and the true radius within ``2 sigma_px`` of ``r``, on 95 % of rows
        (:func:`detect.event_detector.circle_sigma_px`). NaN where not measured (not given: tracks of older
        versions); 0 for a simulation's truth.
    """

    t_us: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    r: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    score: np.ndarray
    flight: np.ndarray
    sigma_px: np.ndarray | None = None

    def __post_init__(self):
        if self.sigma_px is None:
            self.sigma_px = np.full(np.shape(self.t_us), np.nan)
        for f in fields(self):
            dtype = TRACK_COLUMNS[f.name][0]
            setattr(self, f.name, np.asarray(getattr(self, f.name), dtype=dtype).reshape(-1))
        n = {len(getattr(self, f.name)) for f in fields(self)}
        if len(n) > 1:
            raise ValueError("track columns have different lengths")

    def __len__(self) -> int:
        return len(self.t_us)

    @classmethod
    def empty(cls) -> Track:
        return cls(**empty_table(TRACK_COLUMNS))

    @classmethod
    def from_columns(cls, columns) -> Track:
        """From a mapping with the :data:`TRACK_COLUMNS` (or an object with those attributes);
        ``sigma_px`` may be missing (NaN: not measured)."""
        if isinstance(columns, cls):
            return columns
        if isinstance(columns, Mapping):
            return cls(**{name: columns[name] for name in TRACK_COLUMNS
                          if name not in TRACK_OPTIONAL or name in columns})
        return cls(**{name: getattr(columns, name) for name in TRACK_COLUMNS
                      if name not in TRACK_OPTIONAL or hasattr(columns, name)})

    def columns(self) -> dict[str, np.ndarray]:
        """The track as a table of :data:`TRACK_COLUMNS`."""
        return {name: getattr(self, name) for name in TRACK_COLUMNS}

    def flight_ids(self) -> np.ndarray:
        """Distinct flight numbers in order of appearance."""
        _, first = np.unique(self.flight, return_index=True)
        return self.flight[np.sort(first)]

    def spans(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each flight (:meth:`flight_ids` order) with the times (µs) of its first and last update.

        Returns
        -------
        flight : ndarray of int32, t_first_us, t_last_us : ndarray of int64, each shape (F,)
        """
        ids = self.flight_ids()
        times = [self.t_us[self.flight == f] for f in ids]
        return ids, np.array([t[0] for t in times], np.int64), np.array([t[-1] for t in times], np.int64)

    @classmethod
    def concat(cls, tracks) -> Track:
        """Rows of ``tracks`` one after another (an empty track if there are none)."""
        return cls(**concat_tables([t.columns() for t in tracks], TRACK_COLUMNS))

    def select(self, mask) -> Track:
        """Rows where ``mask`` is true (or the given indices)."""
        return Track(**{name: getattr(self, name)[mask] for name in TRACK_COLUMNS})

    def at(self, t_us: float, flight: int | None = None) -> tuple[float, float, float, float, float]:
        """Circle and velocity ``(cx, cy, r, vx, vy)`` at time ``t_us`` (µs).

        Linear interpolation between the updates of one flight (the flight of the
        nearest update unless ``flight`` is given); outside a flight's span the
        centre is extrapolated with the end velocity.
        """
        if len(self) == 0:
            raise ValueError("empty track")
        if flight is None:
            flight = int(self.flight[np.argmin(np.abs(self.t_us - t_us))])
        rows = self.select(self.flight == flight)
        t = rows.t_us.astype(np.float64)
        if t_us <= t[0] or t_us >= t[-1] or len(rows) == 1:
            i = 0 if t_us <= t[0] else len(rows) - 1
            dt_s = (t_us - t[i]) * 1e-6
            return (float(rows.cx[i] + rows.vx[i] * dt_s), float(rows.cy[i] + rows.vy[i] * dt_s),
                    float(rows.r[i]), float(rows.vx[i]), float(rows.vy[i]))
        return tuple(float(np.interp(t_us, t, getattr(rows, c))) for c in ("cx", "cy", "r", "vx", "vy"))

    def circles_at(self, t_us, flight=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Ball circles at times ``t_us`` (µs, shape (N,)) by linear interpolation inside each
        flight's span (no extrapolation, unlike :meth:`at`): that of ``flight`` (int, shape (N,)),
        where given and not -1, else that of the first flight whose span holds the time.

        Returns
        -------
        cx, cy, r : ndarray of float64, shape (N,)
            Circle in pixels (NaN where invalid).
        valid : ndarray of bool, shape (N,)
            True where ``t_us`` lies within a flight's first and last track update.
        """
        t = np.asarray(t_us, dtype=np.float64).reshape(-1)
        wanted = np.full(len(t), -1) if flight is None else np.asarray(flight).reshape(-1)
        out = np.full((3, len(t)), np.nan)
        valid = np.zeros(len(t), dtype=bool)
        for fid in self.flight_ids():
            rows = self.select(self.flight == fid)
            ft = rows.t_us.astype(np.float64)
            m = (t >= ft[0]) & (t <= ft[-1]) & ~valid & ((wanted == fid) | (wanted < 0))
            for k, col in enumerate((rows.cx, rows.cy, rows.r)):
                out[k, m] = np.interp(t[m], ft, col)
            valid |= m
        return out[0], out[1], out[2], valid
