"""Recording one session: the event camera (real or fake), optionally a GoPro, live analysis.

:func:`record_session` records and only records: the exact RAW bytes plus the session
store, live detection and spin beside it (never slowing the recording), the GoPro's
video downloaded into the session and aligned to the event clock. The offline analysis
is :mod:`capture.pipeline.replay`'s; ``python -m capture.run`` composes the two.
"""

from __future__ import annotations

import datetime as _dt
import math
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from capture import evk
from capture.evk.errors import EvkConnectionError, EvkError
from capture.ingest import attach_video
from capture.pipeline.live import LiveAnalysis
from capture.review import LiveReview, ReviewError
from capture.session import (SessionError, StoreBehind, create_session, disk_free_bytes, open_session,
                             unfinished_session)

RAW_NAME = "events.raw"
"""The exact byte stream from the sensor, with a RAW header, inside the session directory."""
GOPRO_DIR = "gopro"
LIVE_MAX_BACKLOG_BYTES = 4 << 20
"""While more of the RAW file than this waits to be decoded, the live analysis and viewer skip
batches (counted): decoding and storing catch up first."""


class RecorderError(Exception):
    """A recording could not start or finish; the message is one line for the user."""


@dataclass
class RecordSettings:
    """What to record and how (the command line, as data).

    Attributes
    ----------
    out : Path
        Session directory to create.
    serial : str or None
        EVK serial (None: the first one found).
    backend : object or None
        pyusb backend (a ``capture.evk.fake.FakeEVK`` for the fake); None for real USB.
    biases : dict
        Named sensor biases.
    roi : tuple or None
        ``(x, y, width, height)`` px (pixels outside it are off).
    crop : tuple or None
        ``(x, y, width, height)`` px: the sensor's digital crop (events outside it dropped).
    anti_flicker_hz : (int, int) or None
        The event camera's anti-flicker band, Hz (stored in the session's sensor attributes).
    trail_filter : (str, int) or None
        The event camera's trail filter, ``(kind, threshold_us)`` (``Camera.set_trail_filter``).
    sync_mode : str or None
        ``standalone``, ``master`` or ``slave`` (None: the camera's default, standalone).
    event_format : str or None
        ``EVT3`` or ``EVT21`` (None: EVT3).
    usb_transfers : int or None
        USB requests kept in flight on the data endpoint (None: ``Camera.n_transfers``).
    flicker_hz : float, "auto" or None
        Lights flickering at this frequency: the live tracker leaves their events out.
    erc_ev_s : float or None
        Event-rate cap, ev/s.
    gopro : object or None
        A connected ``capture.gopro.GoPro`` client, or None.
    gopro_settings : dict
        ``GoPro.configure`` keyword arguments.
    led_roi : tuple or None
        Sync-box LED region ``(x0, y0, x1, y1)`` in GoPro pixels (None: found automatically).
    exposure_s : float or None
        GoPro shutter (exposure) time, s, when locked (None: estimated from the sync box).
    viewer : str
        ``spawn``, ``serve`` or ``none``.
    max_duration_s : float or None
        Stop after this long.
    min_free_bytes : int
        Stop recording when the disk has less free space.
    flush_interval_s : float
        Longest wall time between commits of the session store, s. What a kill loses is this
        plus the time to decode and write it (``bench/kill_bench.py`` measures the store's lag).
    quiet : bool
        No status line or progress bars.
    attrs : dict
        Extra session attributes.
    """

    out: Path
    serial: str | None = None
    backend: object | None = None
    biases: dict = field(default_factory=dict)
    roi: tuple | None = None
    crop: tuple | None = None
    erc_ev_s: float | None = None
    anti_flicker_hz: tuple[int, int] | None = None
    trail_filter: tuple[str, int] | None = None
    sync_mode: str | None = None
    event_format: str | None = None
    usb_transfers: int | None = None
    flicker_hz: float | str | None = None
    trigger_in: bool = True
    gopro: object | None = None
    gopro_settings: dict = field(default_factory=dict)
    led_roi: tuple | None = None
    exposure_s: float | None = None
    viewer: str = "none"
    max_duration_s: float | None = None
    min_free_bytes: int = 500 * 2**20
    flush_interval_s: float = 0.2
    quiet: bool = False
    attrs: dict = field(default_factory=dict)


@dataclass
class RecordResult:
    """Where the session went and what happened."""

    session: Path
    n_events: int
    n_triggers: int
    drops: int
    skipped_live_events: int
    stop_reason: str
    messages: list = field(default_factory=list)
    error: str | None = None


def ball_status(state) -> str:
    """The status line's ball part from a :class:`capture.pipeline.live.LiveState`: the newest
    circle, or each ball's where two or more are tracked at once."""
    if len(state.balls) > 1:
        return f"{len(state.balls)} balls " + ", ".join(f"({b[1]:.0f},{b[2]:.0f}) r {b[3]:.0f}" for b in state.balls)
    b = state.ball
    return f"ball ({b[1]:.0f},{b[2]:.0f}) r {b[3]:.0f}" if b else "no ball"


def spin_status(state) -> str:
    """The status line's spin part from a :class:`capture.pipeline.live.LiveState`: the newest
    estimate, or each ball's (in the order of :func:`ball_status`) where two or more are tracked."""
    def one(est):
        return f"{est.rps:.1f} rps (conf {est.confidence:.2f})" if est is not None else "-"

    if len(state.spins) > 1:
        return "spin " + " / ".join(one(e) for e in state.spins) + "  "
    return f"spin {one(state.spin)}  " if state.spin is not None else ""


class _Status(threading.Thread):
    """Every ``tick_s`` commits the store if due (``flush``, also while no data arrives); every
    ``period_s`` prints a status line and stops the recording when the disk is nearly full."""

    def __init__(self, settings: RecordSettings, counters: dict, live, stop: threading.Event,
                 period_s: float = 0.5, flush=None, tick_s: float = 0.05, progress=None):
        super().__init__(name="status", daemon=True)
        self.settings, self.counters, self.live, self.stop_event = settings, counters, live, stop
        self.progress = progress  # evk.RecordStats, kept current by evk.record: drops as they happen
        self.flush = flush
        self.period_s = period_s
        self.tick_s = tick_s
        self.done = threading.Event()
        self.tty = sys.stderr.isatty()
        self.reason: str | None = None

    def run(self) -> None:
        t_start = time.monotonic()
        last_n, last_t = 0, t_start
        while not self.done.wait(self.tick_s):
            if self.flush is not None:
                self.flush()
            now = time.monotonic()
            if now - last_t < self.period_s:
                continue
            n = self.counters["events"]
            rate = (n - last_n) / max(now - last_t, 1e-9)
            last_n, last_t = n, now
            try:
                free = disk_free_bytes(self.settings.out)
            except OSError as exc:  # the disk went away: stop rather than write into nothing
                self.reason = f"cannot check the disk ({exc}): recording stopped"
                self.stop_event.set()
                continue
            if free < self.settings.min_free_bytes:
                self.reason = f"disk almost full ({free / 2**20:.0f} MiB free): recording stopped"
                self.stop_event.set()
            if self.settings.quiet:
                continue
            line = f"{now - t_start:6.1f} s  {rate / 1e6:6.2f} Mev/s  {n / 1e6:8.2f} Mev  "
            if self.progress is not None:
                pr = self.progress
                line += (f"drops {pr.overflows} ({pr.dropped_bytes / 1e6:.1f} MB lost)  " if pr.overflows
                         else "drops 0  ") + (f"time jumps {pr.time_jumps}  " if pr.time_jumps else "")
                line += f"possible USB losses {pr.idle_risks}  " if pr.idle_risks else ""
            line += f"disk {free / 2**30:.1f} GiB free  "
            st = self.live.state
            line += ball_status(st) + "  "
            line += spin_status(st)
            if st.skipped_events:
                line += f"live analysis skipped {st.skipped_events / 1e6:.2f} Mev (behind)"
            print(("\r" + line) if self.tty else line, end="" if self.tty else "\n", file=sys.stderr,
                  flush=True)
        if self.tty and not self.settings.quiet:
            print(file=sys.stderr)


def _log(settings: RecordSettings, msg: str) -> None:
    if not settings.quiet:
        print(msg, file=sys.stderr, flush=True)


def record_session(settings: RecordSettings, stop: threading.Event | None = None) -> RecordResult:
    """Record one session from an EVK (real or fake) and optionally a GoPro.

    Returns when ``stop`` is set (Ctrl-C), ``max_duration_s`` passes, the disk is
    nearly full, or a fake device's file ends. Whatever happens after the session
    is created (a device unplugged mid-stream, a write error, a second Ctrl-C),
    everything received is kept: the store is flushed and closed, the GoPro is
    stopped and its video downloaded. A device failure or a write error (disk full:
    the recording stops, what could not be stored is marked in the store) is reported
    in ``RecordResult.error``. Events whose times go back (corrupted words on the link)
    do not stop the recording: they are left out of the store, counted and placed there,
    and the RAW file keeps their bytes.
    """
    stop = stop or threading.Event()
    out = Path(settings.out)
    if out.exists() and any(out.iterdir()) and not unfinished_session(out):
        raise RecorderError(f"{out}: already exists and is not empty; choose another --out" + _cut_short_hint(out))
    out.mkdir(parents=True, exist_ok=True)
    if disk_free_bytes(out) < settings.min_free_bytes:
        raise RecorderError(f"{out}: only {disk_free_bytes(out) / 2**20:.0f} MiB free on disk")

    camera = evk.open(settings.serial, backend=settings.backend)
    if settings.usb_transfers is not None:
        camera.n_transfers = settings.usb_transfers
    messages: list[str] = []
    writer = store = live = review = gopro_media = stats = None
    progress = evk.RecordStats(raw_path=out / RAW_NAME)
    counters = {"events": 0, "triggers": 0, "drops": 0}
    write_error: list[BaseException] = []
    raw_error = False
    reason = "error"
    device_error: str | None = None
    lock = threading.Lock()  # one writer: the store thread appends, the status thread flushes
    try:
        info = camera.info
        camera.configure(biases=settings.biases, roi=settings.roi, crop=settings.crop, erc_ev_s=settings.erc_ev_s or None,
                         trigger_in=settings.trigger_in or None, anti_flicker_hz=settings.anti_flicker_hz,
                         trail_filter=settings.trail_filter, sync_mode=settings.sync_mode,
                         event_format=settings.event_format)
        attrs = {"sensor": {"board": info.board, "sensor": info.sensor, "serial": info.serial,
                            "format": info.format, "firmware": info.firmware,
                            "width": info.width, "height": info.height,
                            "biases": camera.get_biases(), "erc_ev_s": settings.erc_ev_s,
                            "erc": _erc_status(camera),
                            "anti_flicker_hz": settings.anti_flicker_hz, "roi": settings.roi, "crop": settings.crop,
                            "trail_filter": list(camera.trail_filter) if camera.trail_filter else None,
                            "sync_mode": camera.sync_mode,
                            "temperature_c": _reading(camera.temperature_c, 1),
                            "illuminance_lux": _reading(camera.illuminance_lux, 0)},
                 "raw_file": RAW_NAME, **settings.attrs}
        writer = create_session(out, width=info.width, height=info.height, attrs=attrs,
                                flush_interval_s=settings.flush_interval_s)
        if settings.viewer != "none":
            try:
                review = LiveReview(settings.viewer, width=info.width, height=info.height,
                                    name=out.name, frames=False)
            except ReviewError as exc:  # the recording matters more than the viewer
                first_line = str(exc).strip().splitlines()[0]
                messages.append(f"live viewer not started ({first_line}); recording without it")
                _log(settings, messages[-1])
            if review is not None and review.url:
                _log(settings, f"Rerun viewer: {review.url}")
        live = LiveAnalysis(info.width, info.height, review=review, flicker_hz=settings.flicker_hz)

        def _write_failed(exc: OSError) -> None:  # disk full or gone: stop; what cannot be stored gets marked
            if not write_error:
                write_error.append(exc)
            stop.set()

        # stored in a thread of its own while the next batch decodes (after a write error the
        # writer holds what it is given, for its close)
        store = StoreBehind(writer, lock=lock, on_error=_write_failed)

        def on_batch(events, triggers):
            store(events, triggers)
            counters["events"] += len(events)
            counters["triggers"] += len(triggers)
            if progress.decode_backlog_bytes > LIVE_MAX_BACKLOG_BYTES:
                live.skip(events)  # decoding and storing are behind: they come first
                return
            live.offer(events)
            if review is not None:
                review.log_events(events)

        if settings.gopro is not None:
            gopro_media = _gopro_start(settings, messages)
        status = _Status(settings, counters, live, stop, progress=progress,
                         flush=lambda: _flush_if_due(writer, lock, _write_failed))
        status.start()
        _log(settings, f"Recording {info.board} {info.sensor} {info.width}x{info.height} "
                       f"(serial {info.serial}) into {out}; Ctrl-C stops")
        try:
            stats = evk.record(camera, out / RAW_NAME, on_batch=on_batch, stop=stop, stats=progress,
                               max_duration_s=settings.max_duration_s)
            reason = stats.stop_reason
        except EvkConnectionError as exc:  # unplugged, stalled...: keep and finalise everything
            stats = getattr(exc, "stats", None)
            device_error = f"{type(exc).__name__}: {exc}"
            reason = "device error"
        except OSError as exc:  # the RAW file could not be written (disk full): finalise the store
            _write_failed(exc)
            raw_error = True
        finally:
            status.done.set()
            status.join()
        reason = (status.reason or (f"write error: {write_error[0]}" if write_error else None) or reason)
        if write_error:
            messages.append(f"stopped on a write error ({' '.join(str(write_error[0]).split())})")
        if device_error:
            messages.append(f"the camera failed mid-recording ({device_error}); everything received "
                            "before it is kept")
        if stats is not None:
            counters["drops"] = stats.overflows
            if stats.overflows:
                messages.append(f"{stats.overflows} host-queue overflow(s): {stats.dropped_bytes} bytes "
                                "lost (gaps listed in the session attrs)")
            if stats.idle_risks:
                messages.append(f"{stats.idle_risks} spell(s) without a USB request long enough to overflow the "
                                "camera's buffer: data may have been lost there unseen (the machine was too busy)")
            if stats.time_jumps:
                messages.append(f"{stats.time_jumps} time-base discontinuities in the event stream "
                                "(lost data on the link, or idle periods)")
            if not stats.time_base_monitored:
                messages.append(f"{stats.raw_path.name} is {camera.info.format}: its time base is not checked "
                                "for gaps, so data lost on the USB link would go unseen (EVT3 is)")
    finally:
        if store is not None:
            store.close()
        store_error = _finalise(writer, live, review, stats, reason, lock, messages,
                                raw_write_error=str(write_error[0]) if raw_error else None,
                                temperature_c=_reading(camera.temperature_c, 1) if device_error is None else None)
        camera.close()
        if gopro_media is not None:
            _gopro_finish(settings, gopro_media, out, messages)

    if write_error and not store_error:
        what = " ".join(str(write_error[0]).split())
        store_error = (f"{RAW_NAME} could not be written ({what}); the store holds the {counters['events']} events "
                       "decoded before it" if raw_error else
                       f"write error: {what}; every event received is in the store")
    return RecordResult(out, counters["events"], counters["triggers"], counters["drops"],
                        live.state.skipped_events, reason, messages=messages,
                        error=device_error or store_error)


def _reading(read, digits: int) -> float | None:
    """A sensor reading (temperature, °C; light level, lux) rounded to ``digits``, or None where
    the sensor reports none or the reading fails (the recording does not depend on it)."""
    try:
        return round(float(read()), digits)
    except (EvkError, OSError, ValueError):
        return None


def _erc_status(camera) -> dict | None:
    """The event rate controller as the sensor reports it (``{"enabled", "cap_ev_s"}``), or None
    where it has none or the reading fails."""
    try:
        enabled, cap = camera.erc_status()
    except (EvkError, OSError):
        return None
    return {"enabled": bool(enabled), "cap_ev_s": round(cap) if math.isfinite(cap) else None}


def _cut_short_hint(out: Path) -> str:
    """What to do with a directory that holds a recording cut short (killed, crashed)."""
    try:
        if open_session(out).cut_short:
            return f" (it holds a recording cut short: `python -m capture.ingest recover {out}` completes it)"
    except SessionError:
        pass
    return ""


def _flush_if_due(writer, lock: threading.Lock, on_error) -> None:
    """Commit buffered events when the flush interval has passed (also while no data arrives);
    a write error goes to ``on_error`` (the status thread goes on)."""
    try:
        with lock:
            writer.flush_if_due()
    except OSError as exc:
        on_error(exc)


def _finalise(writer, live, review, stats, reason: str, lock: threading.Lock, messages: list[str],
              raw_write_error: str | None = None, temperature_c: float | None = None) -> str | None:
    """Stop live analysis and viewer, then flush, describe and close the session store; the
    one-line error when the store could not hold everything (or could not be closed).
    ``raw_write_error``: the RAW file could not be written; the store is marked as possibly
    behind it (``recording.raw_write_error``). ``temperature_c``: the sensor's at the end, °C
    (``recording.temperature_c``)."""
    if live is not None:
        live.close()
        if live.error is not None:
            messages.append(f"live analysis stopped early: {live.error}")
        elif live.state.skipped_events:
            messages.append(f"live analysis skipped {live.state.skipped_events} events to keep up "
                            "(the offline analysis covers everything)")
    if review is not None:
        review.close()
    if writer is None:
        return None
    if writer.write_error is None:  # the disk may fill on the last commit: the store then says so
        with lock:
            try:
                writer.flush()
            except OSError as exc:
                what = " ".join(str(exc).split())
                reason = f"write error: {what}"
                messages.append(f"stopped on a write error ({what})")
    recording = {"stop_reason": reason,
                 "ended_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
    if stats is not None:
        recording.update(overflows=int(stats.overflows), dropped_bytes=int(stats.dropped_bytes),
                         gaps=[list(map(int, g)) for g in stats.gaps],
                         time_jumps=int(stats.time_jumps) if stats.time_base_monitored else None,
                         idle_risks=int(stats.idle_risks),
                         payload_bytes=int(stats.payload_bytes), usb_transfers=int(stats.n_transfers))
    if raw_write_error:
        recording["raw_write_error"] = " ".join(raw_write_error.split())
    if temperature_c is not None:
        recording["temperature_c"] = temperature_c
    if writer.n_out_of_order:
        recording["out_of_order_events"] = int(writer.n_out_of_order)
        messages.append(f"{writer.n_out_of_order} events with times out of order (corrupted words) left out "
                        f"of the store (placed in its events attrs 'out_of_order'; {RAW_NAME} keeps their bytes)")
    with lock:
        try:
            writer.close(recording=recording)
        except OSError as exc:  # SessionWriteError: closed and marked; other: could not close at all
            return " ".join(str(exc).split())
    return None


def _gopro_start(settings: RecordSettings, messages: list[str]):
    """Prepare the GoPro and start it recording; returns the media present before.

    Model, video preset, settings (read back) and health are checked first. A GoPro that cannot
    record (refused, busy, no card...) is said in one line and the event recording goes on
    without video: ``None`` is returned then.
    """
    from capture.gopro import GoProError

    gp = settings.gopro
    try:
        gp.open()
        try:
            gp.set_date_time()
        except GoProError as exc:
            messages.append(f"GoPro clock not set ({exc}); the video is aligned by the clock sync anyway")
        if settings.gopro_settings:
            gp.configure(**settings.gopro_settings)
        messages.extend(gp.notes)
        messages.extend(gp.health())
        before = {m.path for m in gp.media_list()}
        gp.start_recording(timeout_s=10.0)
        return before
    except GoProError as exc:
        msg = f"GoPro not recording ({exc}); the event camera records without video"
        messages.append(msg)
        _log(settings, msg)
        gp.close()
        return None


def _gopro_finish(settings: RecordSettings, before, out: Path, messages: list[str]) -> None:
    """Stop the GoPro, wait for its file, download the new video into the session and align it.

    The new video is what the card lists after the stop and did not list before it (not "the
    last file"); its chapters are downloaded together.
    """
    gp = settings.gopro
    try:
        gp.stop_recording()
        new = [m for m in gp.media_list() if m.path not in before and m.recording is not None]
        recordings = sorted({m.recording for m in new}, key=lambda r: r[1])
        if not recordings:
            messages.append("the GoPro recorded no new video")
            return
        if len(recordings) > 1:
            messages.append(f"the GoPro card gained {len(recordings)} videos during the session; "
                            "the first is attached")
        first = next(m for m in new if m.recording == recordings[0])
        paths = gp.download_recording(first, out / GOPRO_DIR, progress=not settings.quiet)
        sync = attach_video(out, paths[0], led_roi=settings.led_roi, exposure_s=settings.exposure_s)
        messages.append(f"GoPro video {paths[0].name}: {sync}")
    except Exception as exc:  # the event recording is safe; report the GoPro problem on one line
        messages.append(f"GoPro: {exc}")
    finally:
        gp.close()
