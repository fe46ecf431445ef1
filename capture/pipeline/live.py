"""Live analysis beside the recorder: ball tracking and spin on the incoming stream.

The recorder hands every decoded batch to :meth:`LiveAnalysis.offer`, which never
blocks: batches go to a bounded queue and are skipped (and counted) when the
analysis thread falls behind, so the recording is never slowed down.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass

import numpy as np

import spin
from spin import _kernels as spin_kernels
from capture.events import Track, concatenate, in_order_mask, time_slice
from detect import BallTracker, spin_windows


@dataclass
class LiveState:
    """What the live analysis knows now (read by the status display).

    Attributes
    ----------
    ball : tuple or None
        Last ball circle ``(t_us, cx, cy, r)`` in px, or None.
    balls : tuple
        The last circle ``(t_us, cx, cy, r)`` of each ball being tracked (two balls in view at
        once: two), oldest flight first.
    spin : object or None
        Last spin estimate (``spin.SpinEstimate``), or None.
    spins : tuple
        The last spin estimate of each ball in ``balls`` (None where it has none yet): with two
        balls in view the estimates take turns between them.
    analysed_events, skipped_events : int
        Events analysed and events skipped because the analysis was behind.
    """

    ball: tuple | None = None
    balls: tuple = ()
    spin: object | None = None
    spins: tuple = ()
    analysed_events: int = 0
    skipped_events: int = 0


class LiveAnalysis:
    """Background thread running :class:`detect.BallTracker` and spin on recent events.

    Parameters
    ----------
    width, height : int
        Sensor geometry, px.
    review : capture.review.LiveReview, optional
        Where to log track rows and spin estimates.
    spin_every_us : int
        Sensor time per live spin estimate, µs (with two balls in view they take turns; 0: each
        ball with new rows, every batch of events).
    window_us, min_events, max_events :
        Spin window settings (see :func:`detect.track.spin_windows`).
    max_queue : int
        Batches waiting before new ones are skipped.
    keep_us : int
        Sensor time of recent events kept for spin windows (the tracker reports with a delay), µs.
    camera : calib.Intrinsics, optional
        The event camera's intrinsics (e.g. ``calib.stereo.CameraPair.event`` of the
        calibration): spin then models the lens (``spin.estimate_spin``'s ``camera``); None:
        orthographic.
    flicker_hz : float or "auto", optional
        Lights flickering at this frequency: their events are left out of detection
        (``detect.BallTracker``'s ``flicker_hz``).
    """

    def __init__(self, width: int, height: int, *, review=None, spin_every_us: int = 100_000,
                 window_us: int = 2000, min_events: int = 1500, max_events: int = 20000,
                 max_queue: int = 16, keep_us: int = 200_000, camera=None, flicker_hz: float | str | None = None):
        self.tracker = BallTracker(width, height, flicker_hz=flicker_hz)
        spin_kernels.load()  # here, not in the first live estimate (it would hold the GIL a stream needs)
        self.camera = camera
        self.review = review
        self.state = LiveState()
        self.error: BaseException | None = None
        self._spin_every_us = spin_every_us
        self._window = dict(window_us=window_us, min_events=min_events, max_events=max_events)
        self._queue: queue.Queue = queue.Queue(maxsize=max_queue)
        self._recent: list[np.ndarray] = []
        self._keep_us = keep_us
        self._last_circle: dict[int, tuple] = {}  # flight -> its newest (t_us, cx, cy, r)
        self._last_spin_t = -(1 << 62)
        self._last_spin: dict[int, object] = {}  # flight -> its newest spin estimate
        self._spin_t_us: dict[int, int] = {}  # flight -> sensor time of its newest spin estimate
        self._thread = threading.Thread(target=self._run, name="live-analysis", daemon=True)
        self._thread.start()

    def offer(self, events: np.ndarray) -> None:
        """Queue a batch for analysis; skip it (and count it) if the analysis is behind."""
        if len(events) == 0:
            return
        if self.error is not None:  # the analysis thread has stopped: nothing will take it
            return
        try:
            self._queue.put_nowait(events)
        except queue.Full:
            self.state.skipped_events += len(events)

    def skip(self, events: np.ndarray) -> None:
        """Count a batch as skipped without looking at it (the recorder sheds live work when
        decoding and storing fall behind)."""
        self.state.skipped_events += len(events)

    def close(self, timeout_s: float = 10.0) -> None:
        """Stop the thread after the queued batches (waits at most ``timeout_s``)."""
        if self._thread.is_alive():
            try:
                self._queue.put(None, timeout=timeout_s)
            except queue.Full:  # the thread is stuck: leave it (daemon) rather than hang
                return
        self._thread.join(timeout_s)

    def _run(self) -> None:
        try:
            while (batch := self._queue.get()) is not None:
                self._analyse(batch)
        except Exception as exc:  # reported by the recorder; the recording goes on regardless
            self.error = exc

    def _analyse(self, batch: np.ndarray) -> None:
        # Corrupted words on the link give events out of order or off the sensor: the store
        # counts them; the live analysis leaves them out.
        keep = in_order_mask(batch["t"], self.tracker.last_t_us)
        keep &= (batch["x"] < self.tracker.width) & (batch["y"] < self.tracker.height)
        batch = batch[keep]
        if not len(batch):
            return
        rows = self.tracker.update(batch)
        for k in range(len(rows)):  # the newest circle of each ball being tracked
            self._last_circle[int(rows.flight[k])] = (int(rows.t_us[k]), float(rows.cx[k]), float(rows.cy[k]),
                                                      float(rows.r[k]))
        active = self.tracker.active_flights
        self._last_circle = {i: c for i, c in self._last_circle.items() if i in active}
        self._last_spin = {i: e for i, e in self._last_spin.items() if i in active}
        self._spin_t_us = {i: t for i, t in self._spin_t_us.items() if i in active}
        self.state.balls = tuple(self._last_circle[i] for i in active if i in self._last_circle)
        self.state.spins = self._spins_shown()
        self.state.analysed_events += len(batch)
        t_now = int(batch["t"][-1])
        self._recent.append(batch)
        while len(self._recent) > 1 and self._recent[0]["t"][-1] < t_now - self._keep_us:
            self._recent.pop(0)
        if len(rows) == 0:
            return
        if self.review is not None:
            self.review.log_track(rows)
        self.state.ball = (int(rows.t_us[-1]), float(rows.cx[-1]), float(rows.cy[-1]), float(rows.r[-1]))
        due = (t_now - self._last_spin_t) // max(self._spin_every_us, 1)  # estimates owed: one per spin_every_us
        if due < 1:
            return
        self._last_spin_t = t_now
        # the balls whose spin was estimated longest ago (never: first) among those with new rows, those
        # still tracked first (a flight that ended in this batch is no longer shown)
        turns = sorted(np.unique(rows.flight).tolist(),
                       key=lambda i: (i not in active, self._spin_t_us.get(i, -(1 << 62))))
        for flight in turns[:due]:
            self._spin_t_us[flight] = t_now
            self._estimate_spin(rows.select(rows.flight == flight))

    def _estimate_spin(self, rows: Track) -> None:
        """One spin estimate on the window that ends at the newest row of ``rows`` (one flight's)."""
        w_us = self._window["window_us"]
        last = rows.select(rows.t_us >= rows.t_us[-1] - w_us)
        t0 = int(last.t_us[0])
        events = time_slice(concatenate(b for b in self._recent if b["t"][-1] >= t0), t0, t0 + w_us)
        windows = list(spin_windows(events, last, **self._window))[:1]
        est = spin.estimate_windows(windows, camera=self.camera)
        if est:
            self.state.spin = est[0]
            self._last_spin[int(rows.flight[-1])] = est[0]
            self.state.spins = self._spins_shown()
            if self.review is not None:
                self.review.log_spin(est[0])

    def _spins_shown(self) -> tuple:
        """The last spin estimate of each ball shown in ``state.balls`` (None where it has none yet)."""
        return tuple(self._last_spin.get(i) for i in self.tracker.active_flights if i in self._last_circle)
