"""The logger shared by the offline writer and the live viewer, and what it counts.

Events are logged per time slice of ``slice_us`` with ``send_columns`` (one call
per batch of slices); a slice ``[t, t + slice_us)`` is stamped at ``t``. A slice
with more than ``max_events_per_slice`` events is decimated by a stride
``k = ceil(n / max_events_per_slice)`` (every k-th event of the slice is kept).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr

from capture.events import EVENT_DTYPE, Track, concatenate, spin_table
from capture.results import window_table
from capture.review.layout import (APPLICATION_ID, AXIS_COLOR, BALL3D, BALL3D_AXIS, BALL3D_SPHERE, BALL_COLOR,
                                   EVENTS_BALL, EVENTS_OFF, EVENTS_ON, EVENTS_SENSOR, EVENTS_SPIN_AXIS,
                                   FRAMES_BALL, FRAMES_IMAGE, OFF_COLOR, ON_COLOR, PIXEL_OFFSET, PLOT_AZIMUTH,
                                   PLOT_AXIS_SIGMA, PLOT_CONFIDENCE, PLOT_ELEVATION, PLOT_EVENT_RATE, PLOT_RPS,
                                   PLOT_RPM_TRUSTED, PLOT_RPM_UNTRUSTED, PLOT_RPS_SIGMA, PLOT_SPIN_PARTS,
                                   PLOT_STATUS, RESULTS_FLIGHTS,
                                   TEXT_LOG, TIMELINE, axis_angles_deg, time_column)


class ReviewError(Exception):
    """The review cannot be written (bad argument, unusable output path, ...)."""


@dataclass
class ReviewStats:
    """What was logged. Counts of events are before/after decimation."""

    n_events: int = 0
    n_events_logged: int = 0
    n_slices: int = 0
    n_slices_decimated: int = 0
    n_track_rows: int = 0
    n_spin_rows: int = 0
    n_frames: int = 0
    notes: list[str] = field(default_factory=list)


def open_recording(recording_id: str | None) -> rr.RecordingStream:
    """A recording of :data:`APPLICATION_ID` that only uses :data:`TIMELINE` (no log_time / log_tick)."""
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    rec.set_log_time_enabled(False)
    rec.set_log_tick_enabled(False)
    return rec


def check_rrd_path(rrd_path) -> Path:
    """The ``.rrd`` output path, its parent folders created; ReviewError if it is a directory."""
    path = Path(rrd_path)
    if path.is_dir():
        raise ReviewError(f"{path}: is a directory, expected an .rrd file path")
    if not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    return path


class ReviewLogger:
    """Logs session content into one RecordingStream with the entity layout of :mod:`capture.review.layout`.

    Parameters
    ----------
    rec : rerun.RecordingStream
        Where to log.
    slice_us : int
        Event slice length, µs.
    max_events_per_slice : int
        Cap on logged events per slice; above it a slice is decimated by a stride.
    width, height : int, optional
        Sensor size in pixels, for the sensor outline.

    Raises
    ------
    ReviewError
        ``slice_us`` or ``max_events_per_slice`` is not positive.
    """

    def __init__(self, rec: rr.RecordingStream, *, slice_us: int, max_events_per_slice: int,
                 width: int | None = None, height: int | None = None):
        if slice_us <= 0:
            raise ReviewError(f"slice_us must be > 0, got {slice_us}")
        if max_events_per_slice <= 0:
            raise ReviewError(f"max_events_per_slice must be > 0, got {max_events_per_slice}")
        self.rec = rec
        self.slice_us = int(slice_us)
        self.cap = int(max_events_per_slice)
        self.stats = ReviewStats()
        self._carry = np.zeros(0, EVENT_DTYPE)
        self._last_sid: int | None = None
        self._t_now = 0
        self._decimation_noted = False
        self._log_static(width, height)

    def _log_static(self, width, height) -> None:
        rec = self.rec
        rec.log(EVENTS_ON, rr.Points2D.from_fields(colors=[ON_COLOR], radii=[0.5]), static=True)
        rec.log(EVENTS_OFF, rr.Points2D.from_fields(colors=[OFF_COLOR], radii=[0.5]), static=True)
        if width and height:
            rec.log(EVENTS_SENSOR, rr.Boxes2D(mins=[0, 0], sizes=[width, height], colors=[(120, 120, 120)]),
                    static=True)
        for path in (EVENTS_BALL, FRAMES_BALL):
            rec.log(path, rr.Ellipses2D.from_fields(colors=[BALL_COLOR], line_radii=[1.0]), static=True)
        rec.log(EVENTS_SPIN_AXIS, rr.Arrows2D.from_fields(colors=[AXIS_COLOR]), static=True)
        rec.log(PLOT_RPM_UNTRUSTED, rr.SeriesPoints(colors=[(150, 150, 150)], names=["not trusted"]), static=True)
        rec.log(PLOT_RPM_TRUSTED, rr.SeriesPoints(colors=[(0, 114, 178)], names=["trusted"]), static=True)
        rec.log(BALL3D, rr.ViewCoordinates.RDF, static=True)
        rec.log(BALL3D_SPHERE, rr.Ellipsoids3D(half_sizes=[[1.0, 1.0, 1.0]], colors=[BALL_COLOR],
                                               fill_mode="majorwireframe"), static=True)
        rec.log(BALL3D_AXIS, rr.Arrows3D.from_fields(colors=[AXIS_COLOR], radii=[0.03]), static=True)
        for path, name in ((PLOT_RPS, "rps"), (PLOT_AZIMUTH, "azimuth (deg)"),
                           (PLOT_ELEVATION, "elevation (deg)"), (PLOT_CONFIDENCE, "confidence"),
                           (PLOT_RPS_SIGMA, "rps sigma (%)"), (PLOT_AXIS_SIGMA, "axis sigma (deg)"),
                           (PLOT_EVENT_RATE, "events (ev/s)")):
            rec.log(path, rr.SeriesLines(names=name), static=True)

    # events ----------------------------------------------------------------------------------
    def events(self, events: np.ndarray) -> None:
        """Queue events (EVENT_DTYPE, shape (N,), time-ordered); every slice that the batch completes is logged."""
        if len(events) == 0:
            return
        self.stats.n_events += len(events)
        self._t_now = max(self._t_now, int(events["t"][-1]))
        ev = concatenate([self._carry, events]) if len(self._carry) else events
        last_start = int(ev["t"][-1]) // self.slice_us * self.slice_us
        cut = int(np.searchsorted(ev["t"], last_start, side="left"))
        self._carry = ev[cut:].copy()
        self._emit(ev[:cut])

    def flush_events(self) -> None:
        """Log the incomplete last slice."""
        carry, self._carry = self._carry, np.zeros(0, EVENT_DTYPE)
        self._emit(carry)
        if self.stats.n_slices_decimated and not self._decimation_noted:
            self._decimation_noted = True
            self.text(f"events decimated: {self.stats.n_slices_decimated} of {self.stats.n_slices} slices "
                      f"had more than {self.cap} events; {self.stats.n_events_logged} of "
                      f"{self.stats.n_events} events logged", level="WARN")

    def _emit(self, ev: np.ndarray) -> None:
        """Log whole slices: one ``send_columns`` per polarity plus one for the event rate.

        A row is logged per non-empty slice and per first empty slice after one
        (an empty row, which clears the points; rate 0).
        """
        if len(ev) == 0:
            return
        S = self.slice_us
        t = ev["t"]
        s0, s1 = int(t[0]) // S, int(t[-1]) // S
        edges = np.searchsorted(t, np.arange(s0, s1 + 2, dtype=np.int64) * S, side="left")
        counts = np.diff(edges)
        stride = np.maximum(1, -(-counts // self.cap))
        n_kept = -(-counts // stride)
        if np.all(stride == 1):
            kept = ev
        else:
            first = np.cumsum(n_kept) - n_kept
            idx = (np.repeat(edges[:-1], n_kept)
                   + (np.arange(n_kept.sum()) - np.repeat(first, n_kept)) * np.repeat(stride, n_kept))
            kept = ev[idx]
        kept_slice = np.repeat(np.arange(len(counts)), n_kept)
        nonempty = counts > 0
        rows = nonempty.copy()
        rows[1:] |= nonempty[:-1]
        gap_before = self._last_sid is not None and s0 > self._last_sid + 1
        row_t = np.r_[[(self._last_sid + 1) * S] if gap_before else [], np.arange(s0, s1 + 1)[rows] * S]
        pad = np.zeros(int(gap_before), np.int64)
        index = [time_column(row_t)]
        xy = np.empty((len(kept), 2), dtype=np.float32)
        xy[:, 0] = kept["x"]
        xy[:, 1] = kept["y"]
        xy += PIXEL_OFFSET
        on = kept["p"] != 0
        for path, mask in ((EVENTS_ON, on), (EVENTS_OFF, ~on)):
            lengths = np.r_[pad, np.bincount(kept_slice[mask], minlength=len(counts))[rows]]
            self.rec.send_columns(path, indexes=index,
                                  columns=rr.Points2D.columns(positions=xy[mask]).partition(lengths))
        rate = np.r_[pad, counts[rows]] / (S * 1e-6)
        self.rec.send_columns(PLOT_EVENT_RATE, indexes=index, columns=rr.Scalars.columns(scalars=rate))
        self._last_sid = s1
        self.stats.n_slices += int(np.count_nonzero(nonempty))
        self.stats.n_slices_decimated += int(np.count_nonzero(stride > 1))
        self.stats.n_events_logged += len(kept)

    # track and spin --------------------------------------------------------------------------
    def track(self, track: Track, *, clear_after_flights: bool = True) -> None:
        """Ball circle per track row.

        With ``clear_after_flights`` (offline, where flights are complete) the circle is
        cleared ``max(slice_us, 2 * median track step)`` after each flight's last row,
        unless the track has a row before then.
        """
        if len(track) == 0:
            return
        c = np.c_[track.cx, track.cy] + PIXEL_OFFSET
        self.rec.send_columns(EVENTS_BALL, indexes=[time_column(track.t_us)],
                              columns=rr.Ellipses2D.columns(centers=c, half_sizes=np.c_[track.r, track.r]))
        self.stats.n_track_rows += len(track)
        if not clear_after_flights:
            return
        step = np.diff(track.t_us)
        delay = max(self.slice_us, 2 * int(np.median(step)) if len(step) else 0)
        ends = np.array([track.t_us[track.flight == f][-1] for f in track.flight_ids()], np.int64)
        after = np.searchsorted(track.t_us, ends, side="right")
        next_t = np.r_[track.t_us, np.iinfo(np.int64).max][after]
        clear_t = (ends + delay)[next_t > ends + delay]
        if len(clear_t):
            self.rec.send_columns(EVENTS_BALL, indexes=[time_column(clear_t)],
                                  columns=rr.Ellipses2D.columns(half_sizes=np.zeros((0, 2)))
                                  .partition(np.zeros(len(clear_t), np.int64)))

    def spin(self, spin, track: Track | None = None) -> None:
        """Spin estimates at their window centre: time series, 3D axis arrow, 2D projected axis.

        Parameters
        ----------
        spin : mapping, object or iterable of objects
            Spin estimates in a form :func:`capture.events.spin_table` takes (a table of
            :data:`capture.events.SPIN_COLUMNS`, one estimate or estimates).
        track : Track, optional
            Puts the 2D axis arrow on the ball circle at each estimate's time.

        Raises
        ------
        ReviewError
            ``spin`` lacks one of the spin columns.
        """
        try:
            cols = spin_table(spin)
        except (KeyError, AttributeError) as exc:
            raise ReviewError(f"spin estimates lack a column of SPIN_COLUMNS ({exc})") from exc
        n = len(cols["t_start_us"])
        if n == 0:
            return
        t = (cols["t_start_us"] + cols["t_end_us"]) // 2
        axis = cols["axis"]
        rps = cols["rps"]
        az, el = axis_angles_deg(axis)
        index = [time_column(t)]
        for path, values in ((PLOT_RPS, rps), (PLOT_AZIMUTH, az), (PLOT_ELEVATION, el),
                             (PLOT_CONFIDENCE, cols["confidence"].astype(np.float64)),
                             (PLOT_RPS_SIGMA, cols["rps_sigma_pct"].astype(np.float64)),
                             (PLOT_AXIS_SIGMA, cols["axis_sigma_deg"].astype(np.float64))):
            self.rec.send_columns(path, indexes=index, columns=rr.Scalars.columns(scalars=values))
        win = window_table(Track.empty() if track is None else track, cols)
        for path, sel in ((PLOT_RPM_TRUSTED, win["trusted"]), (PLOT_RPM_UNTRUSTED, ~win["trusted"])):
            if sel.any():
                self.rec.send_columns(path, indexes=[time_column(t[sel])],
                                      columns=rr.Scalars.columns(scalars=win["rpm"][sel]))
        for name in ("topspin", "sidespin", "gyro"):
            self.rec.send_columns(f"{PLOT_SPIN_PARTS}/{name}_rpm", indexes=index,
                                  columns=rr.Scalars.columns(scalars=win[f"{name}_rpm"]))
        labels = [f"{v:.1f} rps ±{s:.1f} %" if np.isfinite(s) else f"{v:.1f} rps"
                  for v, s in zip(rps, cols["rps_sigma_pct"])]
        self.rec.send_columns(BALL3D_AXIS, indexes=index,
                              columns=rr.Arrows3D.columns(origins=-1.6 * axis, vectors=3.2 * axis, labels=labels))
        if track is not None and len(track):
            cx, cy, r, valid = track.circles_at(t)
            arrows = rr.Arrows2D.columns(origins=(np.c_[cx, cy] + PIXEL_OFFSET)[valid],
                                         vectors=(axis[:, :2] * r[:, None])[valid])
            self.rec.send_columns(EVENTS_SPIN_AXIS, indexes=index, columns=arrows.partition(valid.astype(np.int64)))
        self.stats.n_spin_rows += n

    # frames ----------------------------------------------------------------------------------
    def frame_image(self, t_us: int, image: np.ndarray, jpeg_quality: int) -> None:
        """One GoPro frame at ``t_us`` (µs), (H, W) or (H, W, 3) RGB uint8, JPEG-compressed."""
        self.rec.set_time(TIMELINE, duration=np.timedelta64(int(t_us), "us"))
        self.rec.log(FRAMES_IMAGE, rr.Image(np.ascontiguousarray(image)).compress(jpeg_quality=jpeg_quality))
        self.stats.n_frames += 1

    def frame_circles(self, t_us, track: Track, event_to_frame: Callable[[np.ndarray], np.ndarray]) -> None:
        """Track circle at frame times ``t_us`` (µs, shape (N,)), mapped into the frame by
        ``event_to_frame`` (circles (N, 3) -> (N, 3), px); empty where the track has no ball."""
        t_us = np.asarray(t_us, np.int64)
        cx, cy, r, valid = track.circles_at(t_us)
        if not valid.any():
            return
        mapped = np.asarray(event_to_frame(np.c_[cx[valid], cy[valid], r[valid]]), dtype=np.float64).reshape(-1, 3)
        cols = rr.Ellipses2D.columns(centers=mapped[:, :2] + PIXEL_OFFSET, half_sizes=mapped[:, [2, 2]])
        self.rec.send_columns(FRAMES_BALL, indexes=[time_column(t_us)], columns=cols.partition(valid.astype(np.int64)))

    # status and notes --------------------------------------------------------------------------
    def status(self, t_us: int, numbers: Mapping[str, float]) -> None:
        """Status numbers at ``t_us`` (µs), one scalar entity each under ``plots/status``; None is skipped."""
        for name, value in numbers.items():
            if value is not None:
                self.rec.send_columns(f"{PLOT_STATUS}/{name}", indexes=[time_column([t_us])],
                                      columns=rr.Scalars.columns(scalars=[float(value)]))

    def flights(self, text: str) -> None:
        """The per-flight table (:func:`capture.results.format_flight_table`) as a text view (a Markdown
        code block, so that its columns line up)."""
        self.rec.log(RESULTS_FLIGHTS, rr.TextDocument(f"```\n{text}\n```", media_type=rr.MediaType.MARKDOWN),
                     static=True)

    def text(self, message: str, level: str = "INFO", t_us: int | None = None) -> None:
        """A note in the log, at ``t_us`` (µs; default: the latest event time seen)."""
        self.stats.notes.append(message)
        t = self._t_now if t_us is None else int(t_us)
        self.rec.send_columns(TEXT_LOG, indexes=[time_column([t])],
                              columns=rr.TextLog.columns(text=[message], level=[level]))
