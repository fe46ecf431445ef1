"""Offline replay: run detection and spin over a stored session and store the results.

The command line is ``python -m capture.replay`` (:mod:`capture.replay`). The work is split into independent units with plain inputs and outputs, so that
a batch of sessions can later run on a distributed engine unchanged:

- :func:`track_session` — one per session: session path in, the whole track out, and each
  :class:`SpinPart` (some consecutive spin windows of a flight, each with its ball events
  and track prior) handed out as soon as tracking has passed it;
- :func:`spin_part` — one per part: plain data in, spin columns out; a flight's parts give
  the same windows as the whole flight (:func:`spin_flight`), so splitting only spreads
  the work;
- :func:`flight_part` — one per done flight (:class:`FlightPart`, its events on the track's disc):
  the period of its image;
- :func:`whole_flight_spin` — one per flight whose windows give no spin (:class:`WholeFlightPart`):
  its spin from all its events at its period's speed;
- :func:`replay` — drives them for one session (spin parts and done flights in worker processes while
  tracking goes on) and writes the results.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

import spin
from calib.intrinsics import Intrinsics
from calib.store import event_camera
from capture.events import EVENT_DTYPE, SPIN_COLUMNS, Track, concat_tables, concatenate, first_at, spin_table
from capture.gopro import read_video
from capture.pipeline.workers import SharedWork
from capture.pipeline.ball_view import ball_view
from capture.session import open_session, software_version, update_session
from detect import BallTracker, spin_windows
from detect.flicker import FLICKER_SAMPLE_EVENTS, find_flicker_hz
from detect.track import events_near
from spin.flight import FlightSpin, flight_spin
from spin.period import FLIGHT_MAX_EVENTS, flight_period, on_track_disc

BATCH_EVENTS = 1 << 20
"""Events read from the store per detection step (bounds memory)."""
REVIEW_NAME = "review.rrd"
"""The session's Rerun recording, inside the session directory."""


@dataclass
class ReplayOptions:
    """Settings of the offline analysis.

    Attributes
    ----------
    window_us : int
        Shortest spin window, µs.
    max_window_us : int
        Longest spin window, µs: where the ball fires few events, a window is
        lengthened up to this until it holds ``min_events``.
    step_us : int
        Time between the starts of two spin windows, µs (spin changes slowly in flight:
        50 estimates per second of flight by default).
    min_events : int
        Fewest ball events for a spin window.
    max_events : int
        Most ball events used per spin window.
    method : str
        Spin method, ``"fast"`` or ``"paper"``.
    workers : int
        Processes for the spin units, this one included (1: all in this process); the
        others start spin work while this one is still tracking (sessions shorter than
        ``WORKERS_MIN_SPAN_S`` use this process alone).
    windows_per_unit : int
        Spin windows per unit of work when flights are split across workers.
    tracker : dict
        Options of :class:`detect.BallTracker`.
    """

    window_us: int = 2000
    max_window_us: int = 20000
    step_us: int = 20000
    min_events: int = 1500
    max_events: int = 30000
    method: str = "fast"
    workers: int = 2
    windows_per_unit: int = 4
    tracker: dict = field(default_factory=dict)

    def check(self) -> None:
        """Raise ValueError naming the first count or duration that is not positive."""
        for name in ("window_us", "max_window_us", "step_us", "min_events", "max_events", "workers",
                     "windows_per_unit"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass
class SpinPart:
    """Spin work for consecutive windows of one ball flight, as plain data.

    Attributes
    ----------
    flight : int
        Flight number.
    starts_us : ndarray of int64
        Start times of the windows, µs (on the flight's grid: every ``step_us`` from its
        first track row); those with too few ball events have no window.
    windows : list of detect.track.SpinWindow
        The windows, each with its ball events and the track's prior: exactly those that
        :func:`detect.track.spin_windows` cuts from all events with the whole track.
    camera : calib.Intrinsics or None
        The event camera's intrinsics (:func:`event_camera`), or None (orthographic spin model).
    """

    flight: int
    starts_us: np.ndarray
    windows: list
    camera: Intrinsics | None = None


REACH_MARGIN = (1.25, 8.0)
"""Events within ``1.25 r + 8 px`` of the ball (extrapolated from the last track row) are
kept for spin: a wide superset of the ``r + 1 px`` circle of :func:`detect.track.spin_windows`,
which covers the difference between the causal and the smoothed track."""


def _near_ball(t_us: np.ndarray, x: np.ndarray, y: np.ndarray, rows: Track, longest_us: int) -> np.ndarray:
    """Indices of events ``(t_us, x, y)`` (time-sorted; columns of an event array, any strides) that
    a spin window of ``rows``' flight may use: within :data:`REACH_MARGIN` of the circle of the
    flight's last row at or before it, moved along that row's velocity, and less than
    ``longest_us`` after the flight's last row (:func:`detect.track.events_near`)."""
    return events_near(t_us, x, y, rows, REACH_MARGIN[0] * rows.r + REACH_MARGIN[1], longest_us)


@dataclass
class _OpenFlight:
    """What :func:`track_session` keeps of a flight until all its spin parts are out."""

    causal: Track  # rows as tracked (for keeping the events near the ball)
    final: Track  # final rows from the one bracketing ``next_start_us`` on
    next_start_us: int  # first window start not handed out yet
    near: list  # events near the ball from ``next_start_us`` on
    ended: bool = False
    seen: list = field(default_factory=list)  # every event near the ball, for its image's period
    rows: list = field(default_factory=list)  # every final row


def _hand_out_parts(flight: _OpenFlight, options: ReplayOptions, assigned_before_us, on_part,
                    camera: Intrinsics | None) -> None:
    """Hand out the flight's parts whose windows have final track rows and all their events
    (``assigned_before_us``: events before it are assigned; None: all), with the event ``camera``."""
    longest_us = max(options.window_us, options.max_window_us)
    while len(flight.final):
        limit = int(flight.final.t_us[-1])  # windows start on or before the last final row
        starts = np.arange(flight.next_start_us, limit + 1, options.step_us, dtype=np.int64)
        starts = starts[:options.windows_per_unit]
        if not len(starts) or (len(starts) < options.windows_per_unit and not flight.ended):
            return
        if assigned_before_us is not None and starts[-1] + longest_us > assigned_before_us:
            return
        end_us = int(starts[-1]) + longest_us
        pieces = []
        for chunk in flight.near:  # time-ordered chunks: join only the part's span
            t = chunk["t"]
            if t[0] >= end_us:
                break
            pieces.append(chunk[first_at(t, starts[0]):first_at(t, end_us)])
        rows = flight.final
        i0 = int(np.searchsorted(rows.t_us, starts[0], side="right")) - 1
        i1 = int(np.searchsorted(rows.t_us, starts[-1], side="right")) + 1  # rows may share a time
        fid = int(rows.flight[0])
        windows = spin_windows(concatenate(pieces), rows.select(slice(i0, i1)), window_us=options.window_us,
                               min_events=options.min_events, max_events=options.max_events,
                               max_window_us=options.max_window_us, starts_us={fid: starts})
        on_part(SpinPart(fid, starts, list(windows), camera))
        flight.next_start_us = int(starts[-1]) + options.step_us
        near = []
        for chunk in flight.near:
            if chunk["t"][-1] >= flight.next_start_us:
                near.append(chunk[first_at(chunk["t"], flight.next_start_us):])
        flight.near = near
        flight.final = rows.select(slice(max(0, int(np.searchsorted(rows.t_us, flight.next_start_us,
                                                                     side="right")) - 1), None))


def session_flicker_hz(session_path) -> float | None:
    """The frequency (Hz) at which lights flicker in a stored session's first events
    (:func:`detect.flicker.find_flicker_hz`), or None."""
    s = open_session(session_path)
    return find_flicker_hz(s.events_range(0, min(s.n_events, FLICKER_SAMPLE_EVENTS)), s.width, s.height)


def resolved_options(session_path, options: ReplayOptions) -> ReplayOptions:
    """``options`` for one session, a tracker's ``flicker_hz="auto"`` replaced by what its events
    show (:func:`session_flicker_hz`: the frequency, or no filter): the settings stored with the
    results then say what detection did, and a second run with ``auto`` finds them the same."""
    if options.tracker.get("flicker_hz") != "auto":
        return options
    found = session_flicker_hz(session_path)
    tracker = {k: v for k, v in options.tracker.items() if k != "flicker_hz"}
    return replace(options, tracker={**tracker, "flicker_hz": found} if found else tracker)


def iter_session_frames(session, width: int, height: int) -> Iterator[tuple[int, np.ndarray]]:
    """Frames of a session in event-sensor geometry: ``(t_us, image)``, lazily.

    Frames come from the stored images or from the attached video. They are
    warped by the stored frame-to-event homography (attrs ``calibration``, key
    ``homography``, see ``calib.stereo.CameraPair``); without one, only frames
    already of the sensor's size are used (the same view), and none otherwise.
    """
    frames = session.frames()
    H = (session.attrs.get("calibration") or {}).get("homography")
    H = None if H is None else np.asarray(H, np.float64).reshape(3, 3)

    def to_sensor(img):
        if H is not None:
            return cv2.warpPerspective(img, H, (width, height))
        return img if img.shape[:2] == (height, width) else None

    if frames["image"] is not None:
        source = ((int(t), img) for t, img in zip(frames["t_us"], frames["image"]))
    elif frames["video"] is not None:
        video = read_video(frames["video"])
        source = ((int(frames["t_us"][i]), img) for i, _, img in video.frames())
    else:
        return
    for t_us, img in source:
        img = to_sensor(img)
        if img is None:
            return
        yield t_us, img


def _flight_part_of(fl: _OpenFlight, flicker_hz: float | None, camera: Intrinsics | None) -> FlightPart:
    """The :class:`FlightPart` of a done flight (with track rows) from the events kept near its ball."""
    seen = concatenate(fl.seen) if fl.seen else np.zeros(0, EVENT_DTYPE)
    rows = Track.concat(fl.rows)
    return next(flight_parts(lambda t0, t1: seen[first_at(seen["t"], t0):first_at(seen["t"], t1)], rows,
                             flicker_hz=flicker_hz, camera=camera))


def track_session(session_path, options: ReplayOptions | None = None, progress: bool = True,
                  on_part=None, on_flight=None) -> Track:
    """Detect and track the ball over a session, streaming its events in batches.

    Parameters
    ----------
    session_path : path
        Session directory.
    on_part : callable, optional
        Called with each :class:`SpinPart` as soon as its windows have final track rows and
        all their events have been read, while tracking goes on; every window of every
        flight is in exactly one part, in order within a flight.  Parts carry the session's
        event camera (:func:`event_camera`).
    on_flight : callable, optional
        With ``on_part``: called with each flight's :class:`FlightPart` (from the events kept near
        its ball, not read again) once the flight is done; not for a flight the tracker dropped
        (it has no track rows).

    Returns
    -------
    Track
        The whole track (as ``BallTracker.finish``).

    Memory stays bounded: of the events read, only those near the ball are kept, and only
    until their windows are handed out.
    """
    options = options or ReplayOptions()
    longest_us = max(options.window_us, options.max_window_us)
    s = open_session(session_path)
    camera = event_camera(s)
    tracker = BallTracker(s.width, s.height, **options.tracker)
    frames = iter_session_frames(s, s.width, s.height)
    pending = next(frames, None)
    flights: dict[int, _OpenFlight] = {}
    unread: list[np.ndarray] = []  # events not yet assigned to flights

    newest = -1  # the highest flight number seen

    def take_rows(causal: Track, final: Track):
        """Add the tracker's new causal rows (for keeping events near the ball) and final rows."""
        nonlocal newest
        for fid in np.unique(causal.flight).tolist():
            rows = causal.select(causal.flight == fid)
            if fid in flights:
                flights[fid].causal = Track.concat([flights[fid].causal, rows])
            elif fid > newest:
                flights[fid] = _OpenFlight(rows, Track.empty(), int(rows.t_us[0]), [])
            newest = max(newest, fid)
        for fid in np.unique(final.flight).tolist():
            rows = final.select(final.flight == fid)
            flights[fid].final = Track.concat([flights[fid].final, rows])
            flights[fid].rows.append(rows)
        for fid, fl in flights.items():
            fl.ended = fid not in tracker.active_flights

    def assign(before_us):
        """Keep, per flight, the events near its ball among those before ``before_us`` (all: None)."""
        while unread:
            ev = unread[0]
            k = len(ev) if before_us is None else first_at(ev["t"], before_us)
            if k == 0:
                break
            columns = [ev[c][:k] for c in ("t", "x", "y")]
            for fl in flights.values():
                idx = _near_ball(*columns, fl.causal, longest_us)
                if len(idx):
                    fl.near.append(np.take(ev, idx))  # 10x faster than ev[idx] on records
                    fl.seen.append(fl.near[-1])
            if k < len(ev):
                unread[0] = ev[k:]
                break
            unread.pop(0)

    def hand_out(assigned_before_us):
        for fid in list(flights):
            fl = flights[fid]
            if on_part is None:  # tracking only: nothing to keep
                if fl.ended:
                    del flights[fid]
                continue
            _hand_out_parts(fl, options, assigned_before_us, on_part, camera)
            done = fl.ended and (not len(fl.final) or fl.next_start_us > fl.final.t_us[-1])
            if done and (assigned_before_us is None or fl.causal.t_us[-1] + longest_us <= assigned_before_us):
                if on_flight is not None and fl.rows:  # (a flight the tracker dropped has no rows)
                    on_flight(_flight_part_of(fl, tracker.flicker_hz, camera))  # (the flicker it filtered)
                del flights[fid]

    bar = tqdm(total=s.n_events, unit="ev", unit_scale=True, desc="tracking", disable=not progress,
               leave=False)
    for batch in s.iter_events(BATCH_EVENTS, prefetch=True):
        if not len(batch):
            continue
        while pending is not None and pending[0] <= batch["t"][-1]:
            tracker.update_frame(pending[1], pending[0])
            pending = next(frames, None)
        take_rows(tracker.update(batch), tracker.take_final())
        if on_part is not None:
            unread.append(batch)
        final_before_us = tracker.rows_final_before_us
        if final_before_us is not None:
            assign(final_before_us)
            hand_out(final_before_us)
        bar.update(len(batch))
    bar.close()
    track = tracker.finish()
    final = tracker.take_final()
    for fid, fl in flights.items():  # the rows of the last updates: those of the final track
        fl.causal = track.select(track.flight == fid)
    take_rows(final.select(final.flight > newest), final)
    if unread:
        assign(None)
    hand_out(None)
    return track


def spin_flight(events: np.ndarray, track: Track, options: ReplayOptions | None = None,
                starts_us=None, camera: Intrinsics | None = None) -> dict[str, np.ndarray]:
    """Spin estimates of one ball flight (or of some of its windows).

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Events covering the flight's time span (or the windows' span); events far from
        the ball may be left out.
    track : Track
        The flight's track rows.
    starts_us : array_like of int, optional
        Start times of the windows to estimate, µs (default: all of the flight's).
    camera : calib.Intrinsics, optional
        The event camera's intrinsics (perspective spin model); None: orthographic.

    Returns
    -------
    dict
        Spin columns (``capture.events.SPIN_COLUMNS``), one row per spin window.
    """
    options = options or ReplayOptions()
    if starts_us is not None:
        starts_us = {int(track.flight[0]): np.asarray(starts_us, np.int64)}
    windows = spin_windows(events, track, window_us=options.window_us, step_us=options.step_us,
                           min_events=options.min_events, max_events=options.max_events,
                           max_window_us=options.max_window_us, starts_us=starts_us)
    return spin_table(spin.estimate_windows(windows, method=options.method, camera=camera))


def spin_part(part: SpinPart, options: ReplayOptions) -> dict[str, np.ndarray]:
    """Spin columns of one :class:`SpinPart` (the unit of spin work; plain data in and out).
    Its windows are estimated in order, each warm-started from the one before (see
    ``spin.estimate_windows``), with the part's camera."""
    return spin_table(spin.estimate_windows(part.windows, method=options.method, camera=part.camera))


def _replay_unit(args):
    """A unit of replay's shared work: a :class:`SpinPart`'s spin columns, a :class:`FlightPart`'s
    ``("period", flight, period)`` (:func:`flight_part`) or a :class:`WholeFlightPart`'s ``("spin", flight,
    FlightSpin)`` (:func:`whole_flight_spin`)."""
    part, options = args
    if isinstance(part, FlightPart):
        return "period", part.flight, flight_part(part)
    if isinstance(part, WholeFlightPart):
        return "spin", part.part.flight, whole_flight_spin(part)
    return spin_part(part, options)


WORKERS_MIN_SPAN_S = 1.0
"""Shorter sessions are analysed in this process alone: worker processes take about a second of
CPU to start, more than the spin work of such a session."""

WORKER_PRELOAD = ["capture.session", "detect", "spin"]
"""Imported once by the worker processes' forkserver (most of their start-up time)."""


def one_thread_per_worker() -> None:
    """Worker processes already run in parallel: BLAS and OpenCV thread pools inside them only
    oversubscribe the cores (measured: a 2-worker pool 3x slower than one process without this)."""
    cv2.setNumThreads(1)
    threadpool_limits(1)


ANALYSED_SOURCES = ("detect", "spin", "calib", "capture/events.py", "capture/pipeline/replay.py")
"""The code whose results a session's analysis stamp vouches for (packages or modules, relative to
the project's import root): a change to any of them makes :func:`analysis_stamp` differ."""


@functools.cache
def _source_digest() -> str:
    """Short SHA-256 of the source files of :data:`ANALYSED_SOURCES` (read once per process, as the
    code it runs was imported once)."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for name in ANALYSED_SOURCES:
        entry = root / name
        for f in sorted(entry.rglob("*.py")) if entry.is_dir() else [entry]:
            digest.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()[:12]


def analysis_stamp(options: ReplayOptions) -> dict:
    """What a session's results were computed with: ``{"software": VERSION+SOURCE_DIGEST,
    "settings": {...}}`` (the options that change results: all but ``workers``), as stored in the
    session's ``analysis`` attribute and compared by :func:`analysed_with`."""
    settings = {k: v for k, v in asdict(options).items() if k != "workers"}
    return json.loads(json.dumps({"software": f"{software_version()}+{_source_digest()}",
                                  "settings": settings}))


def analysed_with(session, options: ReplayOptions) -> bool:
    """True when ``session`` (a :class:`capture.session.Session`) holds results that this software
    computed with these ``options`` (its ``analysis`` attribute equals :func:`analysis_stamp`)."""
    return session.attrs.get("analysis") == analysis_stamp(options)


PERIOD_CHUNK_US = 50_000
"""A flight's events are read and placed on its track in pieces of this length (µs)."""
PERIOD_FLICKER_TOLERANCE = 0.01
"""A period within this share of a flickering light's period (or of 1/4 to 4 times it) is the light's."""


@dataclass(frozen=True)
class FlightPart:
    """A done flight's ball events as plain data: the unit of its period (:func:`flight_part`), and with it
    of its whole-flight spin (:class:`WholeFlightPart`).

    Attributes
    ----------
    flight : int
        Flight number.
    columns : tuple of ndarray (N,)
        ``t_us, x_px, y_px, p, cx_px, cy_px, r_px``: its events within ``spin.period.FLIGHT_INNER`` of
        the track's circle at their own times (thinned evenly to about ``spin.period.FLIGHT_MAX_EVENTS``)
        and those circles (px).
    flicker_hz : float or None
        The lights' flicker the tracker filtered (Hz): a period that is its is not the ball's.
    ray : ndarray (3,) or None
        The line of sight to the ball's middle position (camera frame) where the camera is known.
    """

    flight: int
    columns: tuple
    flicker_hz: float | None = None
    ray: np.ndarray | None = None


def flight_parts(events_between, track: Track, *, flicker_hz: float | None = None,
                 camera: Intrinsics | None = None) -> Iterator[FlightPart]:
    """One :class:`FlightPart` per flight of ``track``, from the events, lazily (one flight's events at a time).

    ``events_between(t0_us, t1_us)`` gives the events with ``t0_us <= t < t1_us`` (EVENT_DTYPE; e.g. a
    session's ``events``). A flight's events are read in pieces of :data:`PERIOD_CHUNK_US`, placed on
    the track interpolated at each one's time, those off the ball's inner disc dropped
    (:func:`spin.period.on_track_disc`), and what is left thinned evenly so that the flight keeps
    about ``spin.period.FLIGHT_MAX_EVENTS``."""
    for fl in track.flight_ids():
        sel = track.flight == fl
        t_rows, cx_rows, cy_rows, r_rows = track.t_us[sel], track.cx[sel], track.cy[sel], track.r[sel]
        t_first, t_last = int(t_rows[0]), int(t_rows[-1]) + 1
        share = max(int(FLIGHT_MAX_EVENTS * PERIOD_CHUNK_US / (t_last - t_first)), 1)  # events kept per piece
        pieces = []
        for t0 in range(t_first, t_last, PERIOD_CHUNK_US):
            ev = events_between(t0, min(t0 + PERIOD_CHUNK_US, t_last))
            on, cx, cy, r = on_track_disc(ev["t"], ev["x"], ev["y"], t_rows, cx_rows, cy_rows, r_rows)
            step = max(-(-len(on) // share), 1)
            on, cx, cy, r = on[::step], cx[::step], cy[::step], r[::step]
            pieces.append((ev["t"][on], ev["x"][on], ev["y"][on], ev["p"][on], cx, cy, r))
        ray = None
        if camera is not None:
            mid = len(t_rows) // 2
            ray = camera.rays([[cx_rows[mid], cy_rows[mid]]])[0]
        yield FlightPart(int(fl), tuple(np.concatenate(c) for c in zip(*pieces)), flicker_hz, ray)


def flight_part(part: FlightPart, *, max_rps: float = 1200.0) -> tuple | None:
    """A done flight's image period (:func:`spin.period.flight_period`: ``(period_s, peak, span_s)``), or None.

    A period that is a flickering light's (``part.flicker_hz``; within :data:`PERIOD_FLICKER_TOLERANCE` of
    1/4 to 4 times its period) is not the ball's: None."""
    columns = part.columns
    found = flight_period(*columns, max_rps=max_rps) if len(columns[0]) > 1 else None
    if found is not None and part.flicker_hz:
        ratio = found[0] * part.flicker_hz
        if any(abs(ratio / q - 1.0) < PERIOD_FLICKER_TOLERANCE for q in (0.25, 1 / 3, 0.5, 1.0, 2.0, 3.0, 4.0)):
            found = None
    return found


@dataclass(frozen=True)
class WholeFlightPart:
    """A flight's events and its image period: the unit of its whole-flight spin (:func:`whole_flight_spin`)."""

    part: FlightPart
    period: tuple


def whole_flight_spin(work: WholeFlightPart) -> FlightSpin | None:
    """The flight's spin from all its events at its period's speed (:func:`spin.flight.flight_spin`), the
    rate's sigma that of the period (:func:`capture.results.period_sigma_pct`; times the fold it finds)."""
    from capture.results import period_sigma_pct

    period_s, _, span_s = work.period
    return flight_spin(*work.part.columns, period_s, period_sigma_pct=period_sigma_pct(period_s, span_s),
                       ray=work.part.ray)


def windowless_flights(track: Track, spin_columns: dict, periods: dict) -> list[int]:
    """The flights with a period whose spin the flight table does not take from their windows (no window
    trusted, or the trusted ones contradicted by the period: :func:`capture.results.flight_table`): those
    a whole-flight spin serves."""
    from capture.results import flight_table

    table = flight_table(track, spin_columns, periods=periods)
    return [int(f) for f, src in zip(table["flight"], table["spin_from"])
            if src != "windows" and periods.get(int(f)) is not None]


def flight_analysis(events_between, track: Track, *, max_rps: float = 1200.0, flicker_hz: float | None = None,
                    camera: Intrinsics | None = None, spin_columns: dict | None = None) -> tuple[dict, dict]:
    """Each flight's image period (:func:`flight_part`) and whole-flight spin (:func:`whole_flight_spin`):
    ``({flight: (period_s, peak, span_s) or None}, {flight: FlightSpin})``. The spin is found for every
    flight with a period, or, given the windows' ``spin_columns``, for the :func:`windowless_flights` only
    (their events are read again)."""
    periods = {part.flight: flight_part(part, max_rps=max_rps)
               for part in flight_parts(events_between, track, flicker_hz=flicker_hz, camera=camera)}
    wanted = [f for f, p in periods.items() if p is not None] if spin_columns is None else \
        windowless_flights(track, spin_columns, periods)
    spins = {part.flight: whole_flight_spin(WholeFlightPart(part, periods[part.flight]))
             for part in flight_parts(events_between, track.select(np.isin(track.flight, wanted)),
                                      flicker_hz=flicker_hz, camera=camera)}
    return periods, spins


def session_flights(session_path, track: Track, options: ReplayOptions,
                    spin_columns: dict | None = None) -> tuple[dict, dict]:
    """:func:`flight_analysis` of a stored session, with the flicker its tracker filtered
    (:func:`resolved_options`) and its event camera."""
    flicker = resolved_options(session_path, options).tracker.get("flicker_hz")
    s = open_session(session_path, cache_chunks=2)
    return flight_analysis(s.events, track, flicker_hz=float(flicker) if flicker else None, camera=event_camera(s),
                           spin_columns=spin_columns)


def spin_attrs(spins: dict) -> dict:
    """``{flight: FlightSpin or None}`` as a session stores it (attrs ``flight_spins``): ``{"flight": {axis,
    omega_rad_s, fold, ratio, excess, trusted, axis_sigma_deg, rps_sigma_pct, turns, fold_ratio, rate_trusted}
    or None}``."""
    return {str(k): None if v is None else {**{f: (bool(x) if f in ("trusted", "rate_trusted") else int(x) if f == "fold" else float(x))
                                               for f, x in asdict(v).items() if f != "axis"},
                                            "axis": [float(a) for a in v.axis]}
            for k, v in spins.items()}


def store_results(session_path, track: Track, spin_columns: dict, options: ReplayOptions,
                  flights: tuple[dict, dict] | None = None) -> None:
    """Replace a session's track and spin tables with these, and its flights' image periods and
    whole-flight spins (``flights``: ``(periods, spins)`` as :func:`flight_analysis` gives them, default
    :func:`session_flights`, spins for the :func:`windowless_flights`; attrs ``flight_periods``: ``{flight: [period_s, peak, span_s] or None}``,
    ``flight_spins``: :func:`spin_attrs`), and stamp them (:func:`analysis_stamp`). The old stamp,
    periods and spins go first: a write cut short leaves a session that no batch skips, and nothing of
    other flights."""
    periods, spins = session_flights(session_path, track, options, spin_columns) if flights is None else flights
    writer = update_session(session_path)
    writer.set_attrs(analysis=None, flight_periods=None, flight_spins=None)
    writer.write_track(track.columns())
    writer.write_spin(spin_columns)
    writer.set_attrs(flight_periods={str(k): None if v is None else [float(x) for x in v] for k, v in periods.items()},
                     flight_spins=spin_attrs(spins))
    writer.close(analysis=analysis_stamp(options))


@dataclass
class ReplayResult:
    """What a replay found: the track, the spin columns and where the review file went."""

    track: Track
    spin: dict[str, np.ndarray]
    rrd_path: Path | None


def replay(session_path, *, rrd_path=None, options: ReplayOptions | None = None,
           progress: bool = True) -> ReplayResult:
    """Run detection and spin over a stored session, store the results, write the ``.rrd``.

    Parameters
    ----------
    session_path : path
        Session directory (see ``capture.session``).
    rrd_path : path, optional
        Where to write the Rerun recording (none if ``None``).
    """
    options = options or ReplayOptions()
    options.check()
    if rrd_path is not None and Path(rrd_path).is_dir():
        raise ValueError(f"{rrd_path}: is a directory; give the .rrd file to write")
    # each part of a flight's spin work goes to a worker process as soon as tracking has passed it (and
    # each done flight's period); once tracking is done, this process joins in. Then each flight whose
    # windows give no spin gets its spin from all its events, its events read again (most flights: none)
    workers = options.workers if open_session(session_path).duration_s >= WORKERS_MIN_SPAN_S else 1
    with SharedWork(_replay_unit, workers, preload=WORKER_PRELOAD,
                    initializer=one_thread_per_worker) as work:
        add = lambda part: work.add((part, options))  # noqa: E731
        track = track_session(session_path, options, progress, on_part=add, on_flight=add)
        results = work.results(progress, desc="spin")
        spin_columns = concat_tables([r for r in results if isinstance(r, dict)], SPIN_COLUMNS,
                                     sort_by="t_start_us")
        periods = {r[1]: r[2] for r in results if isinstance(r, tuple)}  # ("period", flight, period)
        s = open_session(session_path, cache_chunks=2)
        wanted = windowless_flights(track, spin_columns, periods)
        for part in flight_parts(s.events, track.select(np.isin(track.flight, wanted)), camera=event_camera(s)):
            add(WholeFlightPart(part, periods[part.flight]))
        spins = {r[1]: r[2] for r in work.results(progress, desc="whole flights")[len(results):]}
    store_results(session_path, track, spin_columns, options, (periods, spins))
    if rrd_path is not None:
        from capture.review import write_rrd  # Rerun's SDK takes 0.3 s to import: only when a review is asked for

        write_rrd(session_path, rrd_path, progress=progress, ball_view=ball_view)
    return ReplayResult(track, spin_columns, Path(rrd_path) if rrd_path else None)
