"""The logger shared by the offline writer and the live viewer, and what it counts.

Events are logged per time slice of ``slice_us`` with ``send_columns`` (one call
per batch of slices); a slice ``[t, t + slice_us)`` is stamped at ``t``. A slice
with more than ``max_events_per_slice`` events is decimated by a stride
``k = ceil(n / max_events_per_slice)`` (every k-th event of the slice is kept).
Given the ball's track, the events on the ball (within 1.25 radii of its circle) are
thinned apart, to at most ``max_ball_events_per_slice``, so that the ball stays sharp
while the background is thinned.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr

from capture.events import EVENT_DTYPE, Track, concatenate, first_at, spin_table
from capture.results import TRUST, format_flight_table, spin_components, window_table
from capture.review.layout import (APPLICATION_ID, AXIS_COLOR, BALL3D, BALL3D_AXIS, BALL3D_SPHERE, BALL_AXIS,
                                   BALL_COLOR, BALL_IMAGE, BALL_RIM, DEFAULT_MAX_BALL_EVENTS_PER_SLICE, EVENTS_BALL,
                                   EVENTS_OFF, EVENTS_ON, EVENTS_SENSOR, EVENTS_SPIN_AXIS, EVENTS_SPIN_POLE,
                                   FRAMES_BALL, FRAMES_IMAGE, FRAMES_NOTE, OFF_COLOR, ON_COLOR, PIXEL_OFFSET,
                                   PLOT_AZIMUTH, PLOT_AXIS_SIGMA, PLOT_BALL_SIGMA, PLOT_CONFIDENCE, PLOT_ELEVATION,
                                   PLOT_EVENT_RATE, PLOT_RPM_FLIGHT, PLOT_RPM_TRUSTED, PLOT_RPM_TRUTH,
                                   PLOT_RPM_UNTRUSTED, PLOT_RPS, PLOT_RPS_SIGMA, PLOT_SPEED_FLIGHT, PLOT_SPEED_IMAGE,
                                   PLOT_SPIN_PARTS, PLOT_STATUS, PLOT_TRUST, RESULTS_FLIGHTS, TEXT_LOG, TIMELINE,
                                   TRUTH_COLOR, UNTRUSTED_COLOR, axis_angles_deg, time_column)

_SPIN_PARTS = ("topspin", "sidespin", "gyro")
_BALL_MARGIN = 1.25
"""Events within this many radii of the track's circle count as the ball's when thinning."""


def _circles_at(track: Track, t_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The circles of every flight of ``track`` whose span holds each time of ``t_us`` (µs, shape
    (N,); two balls in view at once give two): ``(circles (K, 3) cx, cy, r px in the order of the times,
    lengths (N,) int64, the number of circles at each time)``."""
    t_us = np.asarray(t_us, np.int64)
    index, circles = [], []
    for fid in track.flight_ids().tolist():
        rows = track.select(track.flight == fid)
        at = np.flatnonzero((t_us >= rows.t_us[0]) & (t_us <= rows.t_us[-1]))
        t = t_us[at]
        index.append(at)
        circles.append(np.c_[np.interp(t, rows.t_us, rows.cx), np.interp(t, rows.t_us, rows.cy),
                             np.interp(t, rows.t_us, rows.r)])
    if not index:
        return np.zeros((0, 3)), np.zeros(len(t_us), np.int64)
    index = np.concatenate(index)
    order = np.argsort(index, kind="stable")
    return np.concatenate(circles)[order], np.bincount(index, minlength=len(t_us)).astype(np.int64)


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
    ball_track : Track, optional
        The ball's track (offline, known before the events): its events are thinned apart.
    max_ball_events_per_slice : int
        Cap on logged ball events per slice.

    Raises
    ------
    ReviewError
        ``slice_us`` or an events cap is not positive.
    """

    def __init__(self, rec: rr.RecordingStream, *, slice_us: int, max_events_per_slice: int,
                 width: int | None = None, height: int | None = None, ball_track: Track | None = None,
                 max_ball_events_per_slice: int = DEFAULT_MAX_BALL_EVENTS_PER_SLICE):
        if slice_us <= 0:
            raise ReviewError(f"slice_us must be > 0, got {slice_us}")
        if max_events_per_slice <= 0:
            raise ReviewError(f"max_events_per_slice must be > 0, got {max_events_per_slice}")
        if max_ball_events_per_slice <= 0:
            raise ReviewError(f"max_ball_events_per_slice must be > 0, got {max_ball_events_per_slice}")
        self.rec = rec
        self.slice_us = int(slice_us)
        self.cap = int(max_events_per_slice)
        self.ball_cap = int(max_ball_events_per_slice)
        self.ball_track = ball_track if ball_track is not None and len(ball_track) else None
        self._ball_spans = self.ball_track.spans() if self.ball_track is not None else None
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
        rec.log(BALL_RIM, rr.Ellipses2D.from_fields(colors=[(86, 180, 233)], line_radii=[0.4]), static=True)
        rec.log(BALL_AXIS, rr.Arrows2D.from_fields(colors=[(240, 228, 66)], radii=[0.8]), static=True)
        rec.log(PLOT_RPM_UNTRUSTED, rr.SeriesPoints(colors=[UNTRUSTED_COLOR], names=["not trusted"]), static=True)
        rec.log(PLOT_RPM_TRUSTED, rr.SeriesPoints(colors=[(0, 114, 178)], names=["trusted"]), static=True)
        rec.log(PLOT_RPM_FLIGHT, rr.SeriesLines(colors=[(213, 94, 0)], names=["flight (median of trusted)"]),
                static=True)
        rec.log(PLOT_RPM_TRUTH, rr.SeriesLines(colors=[TRUTH_COLOR], names=["truth"]), static=True)
        rec.log(PLOT_TRUST, rr.SeriesLines(colors=[UNTRUSTED_COLOR], names=[f"trust threshold {TRUST}"]),
                static=True)
        rec.log(PLOT_SPEED_IMAGE, rr.SeriesLines(names=["image speed (px/s)"]), static=True)
        rec.log(PLOT_SPEED_FLIGHT, rr.SeriesLines(colors=[(213, 94, 0)], names=["flight 3D speed (m/s)"]),
                static=True)
        rec.log(BALL3D, rr.ViewCoordinates.RDF, static=True)
        rec.log(BALL3D_SPHERE, rr.Ellipsoids3D(half_sizes=[[1.0, 1.0, 1.0]], colors=[BALL_COLOR],
                                               fill_mode="majorwireframe"), static=True)
        rec.log(BALL3D_AXIS, rr.Arrows3D.from_fields(colors=[AXIS_COLOR], radii=[0.03]), static=True)
        for path, name in ((PLOT_RPS, "rps"), (PLOT_AZIMUTH, "azimuth (deg)"),
                           (PLOT_ELEVATION, "elevation (deg)"), (PLOT_CONFIDENCE, "confidence"),
                           (PLOT_RPS_SIGMA, "rps sigma (%)"), (PLOT_AXIS_SIGMA, "axis sigma (deg)"),
                           (PLOT_BALL_SIGMA, "ball circle sigma (px)"),
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
        cut = first_at(ev["t"], last_start)
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
        n_slices = len(counts)
        slice_of = np.repeat(np.arange(n_slices), counts)
        on_ball = self._on_ball(ev)
        if on_ball is None:
            idx = _thin(slice_of, n_slices, self.cap)
        else:
            ball, rest = np.flatnonzero(on_ball), np.flatnonzero(~on_ball)
            idx = np.sort(np.r_[ball[_thin(slice_of[ball], n_slices, self.ball_cap)],
                                rest[_thin(slice_of[rest], n_slices, self.cap)]])
        kept = ev if len(idx) == len(ev) else ev[idx]
        kept_slice = slice_of[idx]
        n_kept = np.bincount(kept_slice, minlength=n_slices)
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
            lengths = np.r_[pad, np.bincount(kept_slice[mask], minlength=n_slices)[rows]]
            self.rec.send_columns(path, indexes=index,
                                  columns=rr.Points2D.columns(positions=xy[mask]).partition(lengths))
        rate = np.r_[pad, counts[rows]] / (S * 1e-6)
        self.rec.send_columns(PLOT_EVENT_RATE, indexes=index, columns=rr.Scalars.columns(scalars=rate))
        self._last_sid = s1
        self.stats.n_slices += int(np.count_nonzero(nonempty))
        self.stats.n_slices_decimated += int(np.count_nonzero(n_kept < counts))
        self.stats.n_events_logged += len(kept)

    def _on_ball(self, ev: np.ndarray) -> np.ndarray | None:
        """Which events lie within :data:`_BALL_MARGIN` radii of the ball's circle at their time
        (bool, shape (N,)); None without a track."""
        track = self.ball_track
        if track is None:
            return None
        ids, first, last = self._ball_spans
        flights = ids[(first <= ev["t"][-1]) & (last >= ev["t"][0])]
        inside = np.zeros(len(ev), bool)
        for fid in flights.tolist():  # (two balls in view at once: on either)
            cx, cy, r, valid = track.select(track.flight == fid).circles_at(ev["t"])
            d2 = (ev["x"][valid] - cx[valid]) ** 2 + (ev["y"][valid] - cy[valid]) ** 2
            inside[valid] |= d2 <= (_BALL_MARGIN * r[valid]) ** 2
        return inside

    # track and spin --------------------------------------------------------------------------
    def track(self, track: Track, *, clear_after_flights: bool = True) -> None:
        """Ball circle per track row, the ball's image speed and the circle's uncertainty (rows that
        have one: :attr:`capture.events.Track.sigma_px`).

        With ``clear_after_flights`` (offline, where flights are complete) the circle is
        cleared after each flight (:meth:`clear_after_flights`).
        """
        if len(track) == 0:
            return
        t_us = np.unique(track.t_us)
        circles, lengths = _circles_at(track, t_us)  # every ball in view at each row's time
        c = circles[:, :2] + PIXEL_OFFSET
        self.rec.send_columns(EVENTS_BALL, indexes=[time_column(t_us)], columns=rr.Ellipses2D.columns(
            centers=c, half_sizes=circles[:, [2, 2]]).partition(lengths))
        self.rec.send_columns(PLOT_SPEED_IMAGE, indexes=[time_column(track.t_us)],
                              columns=rr.Scalars.columns(scalars=np.hypot(track.vx, track.vy)))
        known = np.isfinite(track.sigma_px)
        if known.any():
            self.rec.send_columns(PLOT_BALL_SIGMA, indexes=[time_column(track.t_us[known])],
                                  columns=rr.Scalars.columns(scalars=track.sigma_px[known].astype(np.float64)))
        self.stats.n_track_rows += len(track)
        if clear_after_flights:
            self.clear_after_flights(track, [EVENTS_BALL])

    def clear_after_flights(self, track: Track, paths) -> None:
        """Clear the entities ``paths`` ``max(slice_us, 2 * median track step)`` after each flight's
        last row, unless the track has a row before then (offline, where flights are complete)."""
        step = np.diff(track.t_us)
        delay = max(self.slice_us, 2 * int(np.median(step)) if len(step) else 0)
        ends = track.spans()[2]
        after = np.searchsorted(track.t_us, ends, side="right")
        next_t = np.r_[track.t_us, np.iinfo(np.int64).max][after]
        clear_t = (ends + delay)[next_t > ends + delay]
        if len(clear_t) == 0:
            return
        for path in paths:
            self.rec.send_columns(path, indexes=[time_column(clear_t)],
                                  columns=rr.Clear.columns(is_recursive=np.zeros(len(clear_t), bool)))

    def spin(self, spin, track: Track | None = None, *, clear_after_flights: bool = False) -> None:
        """Spin estimates at their window centre: time series, 3D axis arrow, 2D projected axis and
        its visible pole. Windows below the trust threshold are grey and labelled so.

        Parameters
        ----------
        spin : mapping, object or iterable of objects
            Spin estimates in a form :func:`capture.events.spin_table` takes (a table of
            :data:`capture.events.SPIN_COLUMNS`, one estimate or estimates).
        track : Track, optional
            Puts the 2D axis arrow on the ball circle at each estimate's time.
        clear_after_flights : bool
            Clear the axis arrows after each flight of ``track`` (offline).

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
        self.rec.send_columns(PLOT_TRUST, indexes=[time_column([t[0], t[-1]])],
                              columns=rr.Scalars.columns(scalars=[TRUST, TRUST]))
        win = window_table(Track.empty() if track is None else track, cols)
        trusted = win["trusted"]
        for path, sel in ((PLOT_RPM_TRUSTED, trusted), (PLOT_RPM_UNTRUSTED, ~trusted)):
            if sel.any():
                self.rec.send_columns(path, indexes=[time_column(t[sel])],
                                      columns=rr.Scalars.columns(scalars=win["rpm"][sel]))
        for name in _SPIN_PARTS:
            self.rec.send_columns(f"{PLOT_SPIN_PARTS}/{name}_rpm", indexes=index,
                                  columns=rr.Scalars.columns(scalars=win[f"{name}_rpm"]))
        labels = [f"{60 * v:.0f} rpm ±{s:.1f} %" if ok and np.isfinite(s) else
                  (f"{60 * v:.0f} rpm" if ok else f"not trusted ({c:.2f})")
                  for v, s, ok, c in zip(rps, cols["rps_sigma_pct"], trusted, cols["confidence"])]
        colors = np.where(trusted[:, None], np.array(AXIS_COLOR), np.array(UNTRUSTED_COLOR)).astype(np.uint8)
        self.rec.send_columns(BALL3D_AXIS, indexes=index,
                              columns=rr.Arrows3D.columns(origins=-1.6 * axis, vectors=3.2 * axis, labels=labels,
                                                          colors=colors))
        if track is not None and len(track):
            cx, cy, r, valid = track.circles_at(t, cols["flight"])
            centre = np.c_[cx, cy] + PIXEL_OFFSET
            pole = np.where(axis[:, 2:3] <= 0, axis, -axis)  # the pole on the camera's side (camera: -Z)
            arrows = rr.Arrows2D.columns(origins=centre[valid], vectors=(axis[:, :2] * r[:, None])[valid],
                                         colors=colors[valid])
            self.rec.send_columns(EVENTS_SPIN_AXIS, indexes=index, columns=arrows.partition(valid.astype(np.int64)))
            poles = rr.Points2D.columns(positions=(centre + pole[:, :2] * r[:, None])[valid],
                                        radii=np.maximum(2.0, 0.12 * r[valid]), colors=colors[valid])
            self.rec.send_columns(EVENTS_SPIN_POLE, indexes=index, columns=poles.partition(valid.astype(np.int64)))
            if clear_after_flights:
                self.clear_after_flights(track, [BALL3D_AXIS, EVENTS_SPIN_AXIS, EVENTS_SPIN_POLE])
        self.stats.n_spin_rows += n

    def flights(self, table: dict) -> None:
        """The per-flight table (:func:`capture.results.flight_table`): as a text view (a Markdown code
        block, so that its columns line up), each flight's rate and 3D speed drawn over the flight,
        and its start and end in the log."""
        self.rec.log(RESULTS_FLIGHTS, rr.TextDocument(f"```\n{format_flight_table(table)}\n```",
                                                      media_type=rr.MediaType.MARKDOWN), static=True)
        for i, fl in enumerate(table["flight"]):
            t0, t1 = int(round(table["t_start_s"][i] * 1e6)), int(round(table["t_end_s"][i] * 1e6))
            for path, value in ((PLOT_RPM_FLIGHT, table["rpm"][i]), (PLOT_SPEED_FLIGHT, table["speed_m_s"][i])):
                if np.isfinite(value):
                    self._span(path, t0, t1, float(value))
            period = table.get("period_rpm", [np.nan] * len(table["flight"]))[i]
            spin = (f"{table['rpm'][i]:.0f} ± {table['rpm_sigma'][i]:.0f} rpm, tilt {table['tilt'][i]}"
                    if np.isfinite(table["rpm"][i]) else
                    f"no trusted axis, {period:.0f} ± {table['period_rpm_sigma'][i]:.0f} rpm from the image's period"
                    if np.isfinite(period) else "no trusted estimate")
            self.text(f"flight {fl} starts: {spin}, {table['n_trusted'][i]}/{table['n_windows'][i]} windows "
                      "trusted", t_us=t0, note=False)
            self.text(f"flight {fl} ends ({table['duration_ms'][i]:.0f} ms)", t_us=t1, note=False)

    def truth(self, rps: float, axis, track: Track) -> None:
        """The simulated truth (``rps`` rev/s about unit ``axis``, camera frame) as reference lines
        over each flight of ``track``: rpm, and topspin / sidespin / gyro in the flight's frame."""
        w = np.asarray(axis, np.float64) * float(rps)
        for fl, t0, t1 in zip(*track.spans()):
            sel = track.flight == fl
            self._span(PLOT_RPM_TRUTH, int(t0), int(t1), 60.0 * float(rps))
            parts = spin_components(w, (np.median(track.vx[sel]), np.median(track.vy[sel])))
            for name, value in zip(_SPIN_PARTS, parts):
                self._span(f"{PLOT_SPIN_PARTS}/truth_{name}_rpm", int(t0), int(t1), 60.0 * value)
        for name in _SPIN_PARTS:
            self.rec.log(f"{PLOT_SPIN_PARTS}/truth_{name}_rpm",
                         rr.SeriesLines(colors=[TRUTH_COLOR], names=[f"truth {name}"]), static=True)

    def _span(self, path: str, t0_us: int, t1_us: int, value: float) -> None:
        """A constant ``value`` from ``t0_us`` to ``t1_us`` (a line), broken after it (NaN)."""
        self.rec.send_columns(path, indexes=[time_column([t0_us, t1_us, t1_us + 1])],
                              columns=rr.Scalars.columns(scalars=[value, value, np.nan]))

    def ball_view(self, t_us: int, view, *, trusted: bool) -> None:
        """The ball close-up of one spin window (:class:`capture.pipeline.ball_view.BallView`) at
        ``t_us`` (µs): as recorded (left) and turned back by the estimated spin (right), each
        scaled to its own 99.5th percentile, with the rim and (right) the spin axis drawn."""
        from matplotlib import colormaps  # matplotlib is a core dependency (the HTML report)

        bins = view.recorded.shape[0]
        gap = max(2, bins // 32)
        panels = []
        for h in (view.recorded, view.turned):
            top = np.percentile(h[h > 0], 99.5) if (h > 0).any() else 1.0
            panels.append(np.clip(h / top, 0.0, 1.0))
        image = np.concatenate([panels[0], np.zeros((bins, gap)), panels[1]], axis=1)
        rgb = (colormaps["magma"](image)[..., :3] * 255).astype(np.uint8)
        if not trusted:
            rgb = (0.5 * rgb).astype(np.uint8)
        scale = bins / (2.0 * view.half_px)  # image px per sensor px
        centres = np.array([[bins / 2, bins / 2], [bins + gap + bins / 2, bins / 2]])
        when = [time_column([t_us])]
        self.rec.send_columns(BALL_IMAGE, indexes=when,
                              columns=rr.Image.columns(buffer=rgb.reshape(1, -1),
                                                       format=rr.components.ImageFormat(
                                                           width=rgb.shape[1], height=bins,
                                                           color_model="RGB", channel_datatype="U8")))
        self.rec.send_columns(BALL_RIM, indexes=when, columns=rr.Ellipses2D.columns(
            centers=centres, half_sizes=np.full((2, 2), view.r_px * scale)).partition([2]))
        self.rec.send_columns(BALL_AXIS, indexes=when, columns=rr.Arrows2D.columns(
            origins=centres[1:], vectors=[view.axis[:2] * view.r_px * scale]).partition([1]))

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
        circles, lengths = _circles_at(track, t_us)
        if not len(circles):
            return
        mapped = np.asarray(event_to_frame(circles), dtype=np.float64).reshape(-1, 3)
        cols = rr.Ellipses2D.columns(centers=mapped[:, :2] + PIXEL_OFFSET, half_sizes=mapped[:, [2, 2]])
        self.rec.send_columns(FRAMES_BALL, indexes=[time_column(t_us)], columns=cols.partition(lengths))

    def frames_note(self, text: str, at_px: tuple[float, float]) -> None:
        """A note shown in the GoPro view at ``at_px`` (frame pixels; the label is centred there),
        e.g. why it has no ball circle."""
        self.rec.log(FRAMES_NOTE, rr.Points2D([at_px], radii=[0.5], labels=[text], colors=[(255, 255, 255)]),
                     static=True)

    # status and notes --------------------------------------------------------------------------
    def status(self, t_us: int, numbers: Mapping[str, float]) -> None:
        """Status numbers at ``t_us`` (µs), one scalar entity each under ``plots/status``; None is skipped."""
        for name, value in numbers.items():
            if value is not None:
                self.rec.send_columns(f"{PLOT_STATUS}/{name}", indexes=[time_column([t_us])],
                                      columns=rr.Scalars.columns(scalars=[float(value)]))

    def text(self, message: str, level: str = "INFO", t_us: int | None = None, *, note: bool = True) -> None:
        """A line in the log, at ``t_us`` (µs; default: the latest event time seen); with ``note``
        it is also kept in :attr:`ReviewStats.notes`."""
        if note:
            self.stats.notes.append(message)
        t = self._t_now if t_us is None else int(t_us)
        self.rec.send_columns(TEXT_LOG, indexes=[time_column([t])],
                              columns=rr.TextLog.columns(text=[message], level=[level]))


def _thin(slice_of: np.ndarray, n_slices: int, cap: int) -> np.ndarray:
    """Positions kept when each slice's events are thinned to at most ``cap`` by a stride
    ``ceil(n / cap)`` from the slice's first event. ``slice_of``: slice of each event (sorted, shape (N,))."""
    counts = np.bincount(slice_of, minlength=n_slices)
    stride = np.maximum(1, -(-counts // cap))
    if np.all(stride == 1):
        return np.arange(len(slice_of))
    first = np.cumsum(counts) - counts
    pos = np.arange(len(slice_of)) - first[slice_of]
    return np.flatnonzero(pos % stride[slice_of] == 0)
