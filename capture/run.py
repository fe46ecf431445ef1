"""Courtside recorder: ``python -m capture.run``.

Finds the EVK (or streams a RAW file through the fake EVK with ``--fake``, or a
simulated rally with ``--demo``), optionally drives a GoPro (or its fake),
records a session (the exact RAW bytes plus the session store), runs detection
and spin live without ever slowing the recording, and on Ctrl-C stops cleanly:
streams stopped, everything flushed, the GoPro video downloaded and aligned, the
session analysed offline, the store finalised and a Rerun ``.rrd`` written.

Examples
--------
::

    python -m capture.run --demo --out demo_session --viewer none
    python -m capture.run --fake recording.raw --out session --viewer none --speed max
    python -m capture.run --out session --gopro-serial C3461324698765 --bias bias_diff_on=20
"""

from __future__ import annotations

import argparse
import datetime as _dt
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from capture.session import SessionError, create_session, disk_free_bytes

RAW_NAME = "events.raw"
"""The exact byte stream from the sensor, with a RAW header, inside the session directory."""
RRD_NAME = "review.rrd"
GOPRO_DIR = "gopro"


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
        ``(x, y, width, height)`` px.
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
        Longest wall time between commits of the session store (what a crash can lose).
    analyse : bool
        Run the offline analysis (track + spin + ``.rrd``) when the recording ends.
    attrs : dict
        Extra session attributes.
    """

    out: Path
    serial: str | None = None
    backend: object | None = None
    biases: dict = field(default_factory=dict)
    roi: tuple | None = None
    erc_ev_s: float | None = None
    trigger_in: bool = True
    gopro: object | None = None
    gopro_settings: dict = field(default_factory=dict)
    led_roi: tuple | None = None
    exposure_s: float | None = None
    viewer: str = "none"
    max_duration_s: float | None = None
    min_free_bytes: int = 500 * 2**20
    flush_interval_s: float = 0.5
    analyse: bool = True
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
    replay: object | None = None
    messages: list = field(default_factory=list)
    error: str | None = None


class _Status(threading.Thread):
    """Every ``period_s``: prints a status line, commits the store if due (``flush``), and stops the
    recording when the disk is nearly full."""

    def __init__(self, settings: RecordSettings, counters: dict, live, stop: threading.Event,
                 period_s: float = 0.5, flush=None):
        super().__init__(name="status", daemon=True)
        self.settings, self.counters, self.live, self.stop_event = settings, counters, live, stop
        self.flush = flush
        self.period_s = period_s
        self.done = threading.Event()
        self.tty = sys.stderr.isatty()
        self.reason: str | None = None

    def run(self) -> None:
        t_start = time.monotonic()
        last_n, last_t = 0, t_start
        while not self.done.wait(self.period_s):
            now = time.monotonic()
            n = self.counters["events"]
            rate = (n - last_n) / max(now - last_t, 1e-9)
            last_n, last_t = n, now
            if self.flush is not None:
                self.flush()
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
            line = (f"{now - t_start:6.1f} s  {rate / 1e6:6.2f} Mev/s  {n / 1e6:8.2f} Mev  "
                    f"drops {self.counters['drops']}  disk {free / 2**30:.1f} GiB free  ")
            st = self.live.state
            line += (f"ball ({st.ball[1]:.0f},{st.ball[2]:.0f}) r {st.ball[3]:.0f}  " if st.ball else "no ball  ")
            if st.spin is not None:
                line += f"spin {st.spin.rps:.1f} rps (conf {st.spin.confidence:.2f})  "
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
    stopped and its video downloaded. A device failure is reported in
    ``RecordResult.error``.
    """
    from capture import evk
    from capture.evk.errors import EvkConnectionError
    from capture.live import LiveAnalysis
    from capture.review import LiveReview, ReviewError

    stop = stop or threading.Event()
    out = Path(settings.out)
    if out.exists() and any(out.iterdir()):
        raise RecorderError(f"{out}: already exists and is not empty; choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    if disk_free_bytes(out) < settings.min_free_bytes:
        raise RecorderError(f"{out}: only {disk_free_bytes(out) / 2**20:.0f} MiB free on disk")

    camera = evk.open(settings.serial, backend=settings.backend)
    messages: list[str] = []
    writer = live = review = gopro_media = stats = None
    counters = {"events": 0, "triggers": 0, "drops": 0}
    write_error: list[BaseException] = []
    reason = "error"
    device_error: str | None = None
    lock = threading.Lock()  # one writer: the decoder thread appends, the status thread flushes
    try:
        info = camera.info
        if settings.biases:
            camera.set_biases(**settings.biases)
        if settings.roi:
            camera.set_roi(*settings.roi)
        if settings.erc_ev_s:
            camera.set_erc(settings.erc_ev_s)
        if settings.trigger_in:
            camera.enable_trigger_in(True)
        attrs = {"sensor": {"board": info.board, "sensor": info.sensor, "serial": info.serial,
                            "format": info.format, "firmware": info.firmware,
                            "width": info.width, "height": info.height,
                            "biases": camera.get_biases()},
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
        live = LiveAnalysis(info.width, info.height, review=review)

        def on_batch(events, triggers):
            if write_error:
                return
            try:
                with lock:
                    writer.append_events(events)
                    if len(triggers):
                        writer.append_triggers(triggers)
            except OSError as exc:  # disk full or gone: stop, keep what is committed
                write_error.append(exc)
                stop.set()
                return
            counters["events"] += len(events)
            counters["triggers"] += len(triggers)
            live.offer(events)
            if review is not None:
                review.log_events(events)

        if settings.gopro is not None:
            gopro_media = _gopro_start(settings, messages)
        status = _Status(settings, counters, live, stop, flush=lambda: _flush_if_due(writer, lock))
        status.start()
        _log(settings, f"Recording {info.board} {info.sensor} {info.width}x{info.height} "
                       f"(serial {info.serial}) into {out}; Ctrl-C stops")
        try:
            stats = evk.record(camera, out / RAW_NAME, on_batch=on_batch, stop=stop,
                               max_duration_s=settings.max_duration_s)
            reason = stats.stop_reason
        except EvkConnectionError as exc:  # unplugged, stalled...: keep and finalise everything
            stats = getattr(exc, "stats", None)
            device_error = f"{type(exc).__name__}: {exc}"
            reason = "device error"
        finally:
            status.done.set()
            status.join()
        reason = (status.reason or (f"write error: {write_error[0]}" if write_error else None) or reason)
        if write_error:
            messages.append(f"stopped on a write error ({write_error[0]}); everything before it is kept")
        if device_error:
            messages.append(f"the camera failed mid-recording ({device_error}); everything received "
                            "before it is kept")
        if stats is not None:
            counters["drops"] = stats.overflows
            if stats.overflows:
                messages.append(f"{stats.overflows} host-queue overflow(s): {stats.dropped_bytes} bytes "
                                "lost (gaps listed in the session attrs)")
            if stats.time_jumps:
                messages.append(f"{stats.time_jumps} time-base discontinuities in the event stream "
                                "(lost data on the link, or idle periods)")
    finally:
        _finalise(writer, live, review, stats, reason, lock, messages)
        camera.close()
        if gopro_media is not None:
            _gopro_finish(settings, gopro_media, out, messages)

    result = RecordResult(out, counters["events"], counters["triggers"], counters["drops"],
                          live.state.skipped_events, reason, messages=messages, error=device_error)
    if settings.analyse and counters["events"]:
        from capture.replay import replay

        _log(settings, "Analysing the session (detection, spin, Rerun recording)...")
        try:
            result.replay = replay(out, rrd_path=out / RRD_NAME, progress=not settings.quiet)
        except Exception as exc:  # the recording is safe; say why the analysis did not finish
            messages.append(f"analysis failed ({type(exc).__name__}: {exc}); "
                            f"retry with: python -m capture.replay {out}")
    return result


def _flush_if_due(writer, lock: threading.Lock) -> None:
    """Commit buffered events when the flush interval has passed (also while no data arrives)."""
    with lock:
        writer.flush_if_due()


def _finalise(writer, live, review, stats, reason: str, lock: threading.Lock, messages: list[str]) -> None:
    """Stop live analysis and viewer, then flush, describe and close the session store."""
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
        return
    recording = {"stop_reason": reason,
                 "ended_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
    if stats is not None:
        recording.update(overflows=int(stats.overflows), dropped_bytes=int(stats.dropped_bytes),
                         gaps=[list(map(int, g)) for g in stats.gaps], time_jumps=int(stats.time_jumps),
                         payload_bytes=int(stats.payload_bytes))
    with lock:
        writer.set_attrs(recording=recording)
        writer.close()


def _gopro_start(settings: RecordSettings, messages: list[str]):
    """Configure the GoPro and start it recording; returns the media present before."""
    gp = settings.gopro
    gp.open()
    gp.set_date_time()
    if settings.gopro_settings:
        gp.configure(**settings.gopro_settings)
    before = {m.path for m in gp.media_list()}
    gp.start_recording()
    return before


def _gopro_finish(settings: RecordSettings, before, out: Path, messages: list[str]) -> None:
    """Stop the GoPro, download the new video into the session and align it to the event clock."""
    from capture.frames import attach_video

    gp = settings.gopro
    try:
        gp.stop_recording()
        new = [m for m in gp.media_list() if m.path not in before]
        if not new:
            messages.append("the GoPro recorded no new video")
            return
        paths = gp.download_recording(new[-1], out / GOPRO_DIR, progress=not settings.quiet)
        sync = attach_video(out, paths[0], led_roi=settings.led_roi, exposure_s=settings.exposure_s)
        messages.append(f"GoPro video {paths[0].name}: {sync}")
    except Exception as exc:  # the event recording is safe; report the GoPro problem on one line
        messages.append(f"GoPro: {exc}")
    finally:
        gp.close()


def _parse_kv(items: list[str]) -> dict[str, int]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise RecorderError(f"--bias expects NAME=VALUE, got {item!r}")
        try:
            out[name] = int(value)
        except ValueError:
            raise RecorderError(f"--bias {name}: {value!r} is not an integer") from None
    return out


def parse_box(text: str, option: str, form: str) -> tuple[int, int, int, int]:
    """Four comma-separated integers, or a :class:`RecorderError` naming the option."""
    try:
        box = tuple(int(v) for v in text.split(","))
    except ValueError:
        box = ()
    if len(box) != 4:
        raise RecorderError(f"{option} expects {form}, got {text!r}")
    return box


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m capture.run",
                                 description="Record a courtside session: event camera (+ GoPro), live "
                                             "ball tracking and spin, session store and Rerun review.")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--demo", action="store_true",
                     help="simulated rally through the fake EVK and fake GoPro (no hardware)")
    src.add_argument("--fake", metavar="RAW_FILE", help="stream a RAW file through the fake EVK")
    src.add_argument("--serial", help="EVK serial number (default: the first EVK found)")
    ap.add_argument("--out", help="session directory (default: session_YYYYmmdd_HHMMSS)")
    ap.add_argument("--viewer", choices=["spawn", "serve", "none"], default="spawn",
                    help="live Rerun viewer (default: spawn)")
    ap.add_argument("--speed", choices=["recorded", "max"], default="recorded",
                    help="--fake/--demo pace: as recorded, or as fast as possible")
    ap.add_argument("--duration", type=float, help="stop after this many seconds")
    ap.add_argument("--bias", action="append", default=[], metavar="NAME=VALUE", help="sensor bias")
    ap.add_argument("--roi", help="region of interest X,Y,WIDTH,HEIGHT in pixels")
    ap.add_argument("--erc", type=float, metavar="EV_S", help="event-rate cap, events per second")
    ap.add_argument("--gopro-serial", help="GoPro serial (its wired-USB address is derived from it)")
    ap.add_argument("--gopro-fps", type=int, default=240, help="GoPro frame rate (default 240)")
    ap.add_argument("--gopro-res", default="1080", help="GoPro resolution (default 1080)")
    ap.add_argument("--exposure", type=float, metavar="S",
                    help="GoPro shutter time in seconds when locked, e.g. 0.002 (default: estimated)")
    ap.add_argument("--led-roi", help="sync-box LED region X0,Y0,X1,Y1 in GoPro pixels "
                                      "(default: found automatically)")
    ap.add_argument("--no-analysis", action="store_true", help="skip the offline analysis at the end")
    ap.add_argument("--quiet", action="store_true", help="no status line or progress bars")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    out = Path(args.out or _dt.datetime.now().strftime("session_%Y%m%d_%H%M%S"))
    stop = threading.Event()

    def on_sigint(signum, frame):
        if stop.is_set():
            raise KeyboardInterrupt
        print("\nstopping: finishing the session (Ctrl-C again to abort)...", file=sys.stderr)
        stop.set()

    previous_handler = signal.signal(signal.SIGINT, on_sigint)
    try:
        return _run(args, out, stop)
    finally:
        signal.signal(signal.SIGINT, previous_handler)


def _run(args, out: Path, stop: threading.Event) -> int:
    """The body of :func:`main`: one session, errors as one line and an exit code."""
    try:
        if args.demo:
            from capture.demo import run_demo

            return run_demo(out, viewer=args.viewer, speed=args.speed, quiet=args.quiet,
                            analyse=not args.no_analysis, stop=stop)
        settings = RecordSettings(out=out, serial=args.serial, viewer=args.viewer,
                                  biases=_parse_kv(args.bias), erc_ev_s=args.erc,
                                  max_duration_s=args.duration, analyse=not args.no_analysis,
                                  quiet=args.quiet)
        if args.roi:
            settings.roi = parse_box(args.roi, "--roi", "X,Y,WIDTH,HEIGHT")
        settings.exposure_s = args.exposure
        if args.led_roi:
            settings.led_roi = parse_box(args.led_roi, "--led-roi", "X0,Y0,X1,Y1")
        if args.fake:
            from capture.evk.fake import FakeEVK

            if not Path(args.fake).is_file():
                raise RecorderError(f"{args.fake}: no such RAW file")
            settings.backend = FakeEVK(args.fake, pace=args.speed)
        if args.gopro_serial:
            from capture.gopro import GoPro

            settings.gopro = GoPro(args.gopro_serial)
            settings.gopro_settings = {"resolution": args.gopro_res, "fps": args.gopro_fps}
        result = record_session(settings, stop)
    except KeyboardInterrupt:
        print(f"capture.run: aborted; what was committed is in {out} "
              f"(python -m capture.replay {out} analyses it)", file=sys.stderr)
        return 130
    except (RecorderError, SessionError, OSError, ValueError) as exc:
        print(f"capture.run: error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # device errors and the like: one line, not a traceback
        print(f"capture.run: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    print_summary(result)
    if result.error:
        print(f"capture.run: error: {result.error} (session {out} kept)", file=sys.stderr)
        return 1
    return 0


def print_summary(result: RecordResult) -> None:
    """A few lines on what was recorded and found."""
    print(f"Session {result.session}: {result.n_events:,} events, {result.n_triggers} triggers, "
          f"{result.drops} drops; stopped: {result.stop_reason}")
    for m in result.messages:
        print(f"  note: {m}")
    if result.replay is not None:
        sp = result.replay.spin
        print(f"  {len(result.replay.track)} track rows, {len(sp['rps'])} spin estimates; "
              f"review: {result.replay.rrd_path} (open with: rerun {result.replay.rrd_path})")


if __name__ == "__main__":
    sys.exit(main())
