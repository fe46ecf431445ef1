"""Live review: the recorder's Rerun viewer, fed from a background thread that never blocks the caller."""

from __future__ import annotations

import logging
import queue
import threading

import numpy as np

from capture.events import Track
from capture.review.layout import DEFAULT_SLICE_US, blueprint
from capture.review.logger import ReviewError, ReviewLogger, ReviewStats, check_rrd_path, open_recording

log = logging.getLogger(__name__)

LIVE_MODES = ("spawn", "serve", "none", "rrd")
"""Where :class:`LiveReview` logs: a spawned local viewer, a gRPC server, nowhere, an ``.rrd`` file."""

TRACK_KEPT = 4096
"""Newest track rows kept by the logging thread, to place the ball on frames and spin arrows."""


class LiveReview:
    """Live Rerun logging for the recorder; never blocks the caller.

    Calls only put work on a bounded queue (``put_nowait``); a background thread
    slices, decimates and logs it. When the queue is full the item is skipped and
    counted (:attr:`skipped`), and a note is logged. Mode ``"none"`` does nothing.

    Parameters
    ----------
    mode : {"spawn", "serve", "none", "rrd"}
        ``spawn`` a local viewer, ``serve`` over gRPC (see :attr:`url`), write ``rrd_path``, or nothing.
    rrd_path : str or Path, optional
        Output for mode ``"rrd"``.
    width, height : int, optional
        Sensor size in pixels.
    recording_id : str, optional
        Rerun recording id (e.g. :func:`capture.review.session_recording_id` of the session being recorded).
    name : str, optional
        Recording name shown in the viewer.
    frames : bool
        Show the GoPro frames view.
    slice_us, max_events_per_slice : int
        Event slice length (µs) and per-slice cap (see :mod:`capture.review.logger`); keep the cap low live.
    max_queue : int
        Items waiting for the logging thread before new ones are skipped.
    event_to_frame : callable, optional
        Event-sensor circles (N, 3) -> frame circles (N, 3), px, for the circle on frames.
    jpeg_quality : int
        JPEG quality of logged frame images.
    grpc_port : int, optional
        Port for ``serve`` / ``spawn``.

    Raises
    ------
    ReviewError
        Unknown mode, mode ``"rrd"`` without ``rrd_path``, or the viewer cannot be started.
    """

    def __init__(self, mode: str = "none", *, rrd_path=None, width: int | None = None,
                 height: int | None = None, recording_id: str | None = None, name: str | None = None,
                 frames: bool = True, slice_us: int = DEFAULT_SLICE_US, max_events_per_slice: int = 1000,
                 max_queue: int = 64, event_to_frame=None, jpeg_quality: int = 70,
                 grpc_port: int | None = None):
        if mode not in LIVE_MODES:
            raise ReviewError(f"viewer mode must be one of {LIVE_MODES}, got {mode!r}")
        if mode == "rrd" and rrd_path is None:
            raise ReviewError("viewer mode 'rrd' needs rrd_path")
        self.mode = mode
        self.url: str | None = None
        self.skipped: dict[str, int] = {}
        self.error: BaseException | None = None
        self._event_to_frame = event_to_frame
        self._jpeg_quality = jpeg_quality
        self._closed = mode == "none"
        if self._closed:
            return
        rec = open_recording(recording_id)
        bp = blueprint(frames=frames, width=width, height=height, status=True)
        if mode == "rrd":
            rec.save(check_rrd_path(rrd_path))
        else:
            try:
                if mode == "spawn":
                    rec.spawn(port=grpc_port or 9876, default_blueprint=bp)
                else:
                    self.url = rec.serve_grpc(grpc_port=grpc_port, default_blueprint=bp)
            except Exception as exc:  # rerun raises several types (missing viewer, port in use)
                raise ReviewError(f"cannot start the Rerun viewer (mode {mode!r}): {exc}") from exc
        rec.send_blueprint(bp)
        if name:
            rec.send_recording_name(name)
        self._rec = rec
        self._logger = ReviewLogger(rec, slice_us=slice_us, max_events_per_slice=max_events_per_slice,
                                    width=width, height=height)
        self._track = Track.empty()
        self._queue: queue.Queue = queue.Queue(maxsize=max_queue)
        self._thread = threading.Thread(target=self._run, name="live-review", daemon=True)
        self._thread.start()

    @property
    def stats(self) -> ReviewStats | None:
        """What the logging thread has logged so far (None in mode ``"none"``)."""
        return None if self.mode == "none" else self._logger.stats

    # caller side: cheap, never blocking -----------------------------------------------------------
    def _put(self, kind: str, payload) -> None:
        if self._closed:
            return
        try:
            self._queue.put_nowait((kind, payload))
        except queue.Full:
            self.skipped[kind] = self.skipped.get(kind, 0) + 1

    def log_events(self, events: np.ndarray) -> None:
        """An event batch (EVENT_DTYPE, shape (N,), time-ordered; not modified by the caller afterwards)."""
        if len(events):
            self._put("events", events)

    def log_track(self, track) -> None:
        """New track rows (:class:`capture.events.Track` or a mapping of the track columns)."""
        self._put("track", track)

    def log_spin(self, spin) -> None:
        """Spin estimate(s): one estimate (e.g. ``spin.SpinEstimate``), a list, or a mapping of spin columns."""
        self._put("spin", spin)

    def log_frame(self, t_us: int, image: np.ndarray | None = None) -> None:
        """A GoPro frame at ``t_us`` (µs, event clock); ``image`` (H, W[, 3]) RGB uint8."""
        self._put("frame", (int(t_us), image))

    def log_status(self, t_us: int, **numbers: float) -> None:
        """Status numbers at ``t_us`` (µs), e.g. ``event_rate_ev_s=..., drops=...`` (plotted under plots/status)."""
        self._put("status", (int(t_us), numbers))

    def log_message(self, text: str, level: str = "INFO") -> None:
        """A note in the viewer's log."""
        self._put("text", (text, level))

    def close(self, timeout_s: float = 10.0) -> None:
        """Log what is queued, flush and close the sink (waits at most ``timeout_s`` for the thread)."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(("stop", None))
        self._thread.join(timeout_s)
        self._rec.flush()
        self._rec.disconnect()

    def __enter__(self) -> LiveReview:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # logging thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        lg = self._logger
        noted = 0
        while True:
            kind, payload = self._queue.get()
            try:
                if kind == "stop":
                    lg.flush_events()
                    if self.skipped:
                        lg.text(f"live review skipped (queue full): {self.skipped}", level="WARN")
                    return
                n_skipped = sum(self.skipped.values())
                if n_skipped > noted:
                    noted = n_skipped
                    lg.text(f"live review behind: skipped so far {self.skipped}", level="WARN")
                self._handle(kind, payload)
            except Exception as exc:  # never let a viewer problem reach the recorder
                if self.error is None:
                    self.error = exc
                    log.warning("live review: %s: %s", type(exc).__name__, exc)

    def _handle(self, kind: str, payload) -> None:
        lg = self._logger
        if kind == "events":
            lg.events(payload)
        elif kind == "track":
            rows = Track.from_columns(payload)
            lg.track(rows, clear_after_flights=False)
            self._track = Track.concat([self._track, rows]).select(slice(-TRACK_KEPT, None))
        elif kind == "spin":
            lg.spin(payload, self._track)
        elif kind == "frame":
            t_us, image = payload
            if image is not None:
                lg.frame_image(t_us, image, self._jpeg_quality)
            if self._event_to_frame is not None and len(self._track):
                lg.frame_circles([t_us], self._track, self._event_to_frame)
        elif kind == "status":
            lg.status(*payload)
        elif kind == "text":
            lg.text(*payload)
