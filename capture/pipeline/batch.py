"""Replay of many sessions on Dask distributed (the command line is :mod:`capture.batch`).

Every session's analysis is cut into tasks with plain inputs and outputs, which a Dask
scheduler runs on its workers (worker processes on this machine, or on many machines that see
the sessions at the same path):

- :func:`track_unit` — one per session: the whole ball track (``None`` when the session already
  holds results of the same settings and software, :func:`capture.pipeline.replay.analysed_with`);
- :func:`plan_unit` — the session's spin parts: ``(flight, starts_us)``, ``windows_per_unit``
  consecutive spin windows of one flight each, the same parts as :func:`capture.pipeline.replay.replay`;
- :func:`spin_unit` — one per part: reads the part's events from the store and estimates its
  windows (:func:`capture.pipeline.replay.spin_flight`; the same windows and numbers as replay);
- :func:`store_unit` — writes the track and spin into the session exactly as replay does and
  returns its per-flight and per-window tables (:func:`capture.results.session_results`);
- :func:`tables_unit` — the tables of a session skipped as already analysed.

A worker that dies loses only the tasks it held, which the scheduler runs again elsewhere; a
session whose task fails (a damaged store) is reported with one line and the others go on.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from capture.cliargs import describe
from capture.events import SPIN_COLUMNS, Track, concat_tables
from calib.store import event_camera
from capture.pipeline.replay import (ReplayOptions, analysed_with, one_thread_per_worker, resolved_options,
                                     spin_flight, store_results, track_session)
from capture.results import session_results
from capture.ingest import complete_cut_short
from capture.session import Session, open_session
from detect.track import window_starts_us

try:
    from distributed import WorkerPlugin
except ImportError:  # the optional extra is not installed: only the command needs it
    WorkerPlugin = object


def track_unit(session_path: str, options: ReplayOptions, force: bool) -> Track | None:
    """The session's whole ball track, or None when it is already analysed with ``options`` by this
    software (and not ``force``). A recording cut short is first completed from its RAW file
    (:func:`capture.ingest.complete_cut_short`; when it cannot be, its stored part is analysed and
    its damage note says so). A tracker's ``flicker_hz="auto"`` is resolved first
    (:func:`capture.pipeline.replay.resolved_options`). Raises :class:`capture.session.SessionError`
    on a damaged store."""
    complete_cut_short(session_path, progress=False)
    options = resolved_options(session_path, options)
    if not force and analysed_with(open_session(session_path), options):
        return None
    return track_session(session_path, options, progress=False)


def plan_unit(track: Track | None, options: ReplayOptions) -> list[tuple[int, np.ndarray]] | None:
    """The spin parts of a track: ``(flight, starts_us)`` with at most ``windows_per_unit`` window
    starts (µs) each, in flight and time order (None for a skipped session)."""
    if track is None:
        return None
    n = options.windows_per_unit
    return [(fid, starts[i:i + n]) for fid, starts in window_starts_us(track, options.step_us).items()
            for i in range(0, len(starts), n)]


SPIN_CACHE_CHUNKS = 2
"""Decompressed event chunks a worker keeps per session for its spin parts (16 MiB each): the
parts of a flight read nearby times, several per chunk."""

_SESSIONS: dict[tuple[str, int], Session] = {}
"""Sessions opened by this worker process (opening checks every chunk once), keyed by path and
the root metadata's modification time."""


def _session(session_path: str) -> Session:
    key = (session_path, (Path(session_path) / "zarr.json").stat().st_mtime_ns)
    if key not in _SESSIONS:
        if len(_SESSIONS) >= 4:
            _SESSIONS.pop(next(iter(_SESSIONS)))
        _SESSIONS[key] = open_session(session_path, cache_chunks=SPIN_CACHE_CHUNKS)
    return _SESSIONS[key]


def spin_unit(session_path: str, track: Track, flight: int, starts_us: np.ndarray,
              options: ReplayOptions) -> dict[str, np.ndarray]:
    """Spin columns (:data:`capture.events.SPIN_COLUMNS`) of the windows starting at ``starts_us``
    (µs) of ``flight``, from the session's events and the whole ``track``."""
    s = _session(session_path)
    longest_us = max(options.window_us, options.max_window_us)
    events = s.events(int(starts_us[0]), int(starts_us[-1]) + longest_us)
    return spin_flight(events, track.select(track.flight == flight), options, starts_us, camera=event_camera(s))


@dataclass
class SessionTables:
    """What the batch keeps of one session: its per-flight and per-window tables
    (:mod:`capture.results`) and its damage note (:attr:`capture.session.Session.damage`)."""

    flights: dict
    windows: dict
    damage: str | None


def tables_unit(session_path: str, ball_diameter_m: float | None) -> SessionTables:
    """The per-flight and per-window tables of an analysed session."""
    s = open_session(session_path)
    flights, windows = session_results(s, ball_diameter_m=ball_diameter_m)
    return SessionTables(flights, windows, s.damage)


def store_unit(session_path: str, track: Track, spins: Sequence[dict], options: ReplayOptions,
               ball_diameter_m: float | None) -> SessionTables:
    """Write the session's results as :func:`capture.pipeline.replay.replay` does (``spins``: the
    columns of every part, in any order; a flicker frequency found stamped in place of ``auto``) and
    return its tables."""
    store_results(session_path, track, concat_tables(spins, SPIN_COLUMNS, sort_by="t_start_us"),
                  resolved_options(session_path, options))
    return tables_unit(session_path, ball_diameter_m)


class OneThreadPerWorker(WorkerPlugin):
    """Each Dask worker runs one task at a time on one core: OpenCV's and BLAS's thread pools
    inside it would only oversubscribe the cores."""

    def setup(self, worker) -> None:
        one_thread_per_worker()


WORKER_CONFIG = {"distributed.worker.profile.enabled": False}
"""Dask settings of the workers: no statistical profiler (its thread samples the running task
every 10 ms, which made spin tasks 3-7 % slower in ``bench/batch_bench.py``; the dashboard's
profile page stays empty). Remote workers take it from ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False``."""


def local_cluster(n_workers: int, *, dashboard_address: str | None = None):
    """A ``distributed.LocalCluster`` of ``n_workers`` worker processes of one thread each, with
    :data:`WORKER_CONFIG`, its logs silenced (failures are reported by :func:`run_batch`) and no
    warning when the dashboard's port is taken (it moves to a free one: see ``dashboard_link``)."""
    import logging
    import warnings

    import dask
    from distributed import LocalCluster

    with dask.config.set(WORKER_CONFIG), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                            dashboard_address=dashboard_address, silence_logs=logging.CRITICAL)


@dataclass
class BatchResult:
    """What a batch did.

    Attributes
    ----------
    flights, windows : dict of ndarray
        The season tables: every session's per-flight (per-window) table, in the order the
        sessions were given, with a first column ``session`` (its path).
    analysed, skipped : list of str
        Sessions analysed now; sessions skipped as already analysed with the same settings (in the
        order given, as absolute paths).
    failed : dict of str to str
        Session -> one-line reason, for the sessions that could not be analysed.
    """

    flights: dict
    windows: dict
    analysed: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    failed: dict = field(default_factory=dict)


def _season_table(paths: Sequence[str], tables: dict[str, dict]) -> dict[str, np.ndarray]:
    """Tables of several sessions one after another, with a first column ``session``."""
    done = [p for p in paths if p in tables]
    if not done:
        return {"session": np.zeros(0, dtype=str)}
    names = list(tables[done[0]])
    session = np.concatenate([np.full(len(tables[p][names[0]]), p) for p in done])
    return {"session": session, **{k: np.concatenate([np.asarray(tables[p][k]) for p in done]) for k in names}}


def run_batch(session_paths: Sequence, client, options: ReplayOptions | None = None, *, force: bool = False,
              ball_diameter_m: float | None = None, progress: bool = True,
              note: Callable[[str], None] | None = None) -> BatchResult:
    """Analyse sessions as Dask tasks on ``client`` and collect their season tables.

    Parameters
    ----------
    session_paths : sequence of path
        Session directories, as the workers see them (a shared filesystem for remote workers).
    client : distributed.Client
        The Dask client whose scheduler runs the tasks.
    options : ReplayOptions, optional
        Analysis settings (``workers`` is not used: the cluster's workers run the tasks).
    force : bool
        Analyse sessions again even when they hold results of the same settings and software.
    ball_diameter_m : float, optional
        The ball's diameter, m: distances and speeds in the per-flight tables (with a calibration).
    note : callable, optional
        Called with one line per failed or damaged session (default: printed on stderr).
    """
    from distributed import as_completed

    options = options or ReplayOptions()
    note = note or (lambda line: tqdm.write(line, file=sys.stderr))
    paths = list(dict.fromkeys(str(Path(p).resolve()) for p in session_paths))
    result = BatchResult({}, {})
    tables: dict[str, SessionTables] = {}
    role: dict[str, tuple[str, str]] = {}  # future key -> (kind, session)
    held: dict[str, list] = {p: [] for p in paths}  # the futures of each unfinished session
    tracks = {}
    done = as_completed()

    def submit(kind: str, path: str, fn, *args):
        future = client.submit(fn, *args, pure=False)
        role[future.key] = (kind, path)
        held[path].append(future)
        done.add(future)
        return future

    sessions = tqdm(total=len(paths), unit="session", desc="sessions", disable=not progress, position=0)
    parts = tqdm(total=0, unit="part", desc="spin parts", disable=not progress, position=1)
    for path in paths:
        tracks[path] = submit("track", path, track_unit, path, options, force)
    for future in done:
        kind, path = role.pop(future.key)
        if path not in held:  # the session failed already; its other tasks were cancelled
            continue
        if future.status != "finished":
            reason = describe(future.exception()) if future.status == "error" else f"task {future.status}"
            result.failed[path] = reason
            note(f"batch: {reason}" if reason.startswith(path) else f"batch: {path}: {reason}")
            client.cancel(held.pop(path))
            del tracks[path]
            sessions.update()
            continue
        if kind == "track":
            submit("plan", path, plan_unit, future, options)
        elif kind == "plan":
            plan = future.result()
            if plan is None:
                result.skipped.append(path)
                submit("tables", path, tables_unit, path, ball_diameter_m)
                continue
            spins = [submit("spin", path, spin_unit, path, tracks[path], fid, starts, options) for fid, starts in plan]
            parts.total += len(spins)
            parts.refresh()
            submit("store", path, store_unit, path, tracks[path], spins, options, ball_diameter_m)
        elif kind == "spin":
            parts.update()
        else:  # "store" or "tables": the session is done
            tables[path] = future.result()
            if kind == "store":
                result.analysed.append(path)
            if tables[path].damage:
                note(f"note: {path}: {tables[path].damage}")
            del held[path], tracks[path]  # the workers may forget its data
            sessions.update()
    parts.close()
    sessions.close()
    result.analysed.sort(key=paths.index)  # in the order given, as the tables
    result.skipped.sort(key=paths.index)
    result.failed = {p: result.failed[p] for p in paths if p in result.failed}
    result.flights = _season_table(paths, {p: t.flights for p, t in tables.items()})
    result.windows = _season_table(paths, {p: t.windows for p, t in tables.items()})
    return result
