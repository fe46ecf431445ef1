"""Getting data into a session: a RAW file, a frame-camera video aligned to the event clock.

- :func:`convert_raw`: decode a Prophesee RAW file into a new session store.
- :func:`attach_video`: copy an MP4 into the session and store its frame times on the event
  clock (fitted by :func:`fit_time_map`: sync box, else event activity against frame motion).
- :func:`session_from_raw`: both, for a bare RAW file and its video.
- :func:`recover_session`: complete the store of a recording cut short (killed, crashed) from
  the RAW file the recorder wrote beside it, which holds every byte received
  (:func:`complete_cut_short`: the same before an analysis, when needed).

The video file stays an MP4 (copied into ``SESSION/gopro/``); the store keeps
its per-frame times already mapped onto the event camera's clock
(``frames/t_us``), the fitted clock map (attrs ``time_sync``) and the frame
camera's description (attrs ``frame_camera``).

Command line::

    python -m capture.ingest raw recording.raw SESSION_DIR [--time-shift] [--overwrite]
    python -m capture.ingest video SESSION_DIR GX010042.MP4 [--led-roi X0,Y0,X1,Y1] [--exposure S]
    python -m capture.ingest recover SESSION_DIR
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import shutil
import warnings
from pathlib import Path

import numpy as np

from calib import store, sync
from capture.cliargs import add_ball_args, ball_attr, box, print_fields, run_command
from capture.events import EVENT_DTYPE
from capture.gopro import chapter_paths, gpmf, read_video
from capture.gopro.mp4 import gpmf_samples
from capture.raw import RawFormatError, RawReader, scan
from capture.raw.stream import DEFAULT_CHUNK_BYTES
from capture.session import SessionError, StoreBehind, create_session, open_session, update_session

def convert_raw(path, session_dir, *, time_shift: bool = False, overwrite: bool = False,
                chunk_bytes: int = DEFAULT_CHUNK_BYTES, progress: bool = True, ball: dict | None = None) -> dict:
    """Decode a RAW file into a new session store (events, triggers; header in the root attrs).

    Root attrs written: ``sensor`` (format, geometry, serial, plugin, header fields),
    ``raw_source`` (file name, size, header style, time shift, decoder counters) and, when
    given, ``ball`` (``{"type", "diameter_m"}``, see :func:`capture.cliargs.ball_attr`).

    Returns
    -------
    dict
        ``session`` (the directory), the counts and time range of :func:`capture.raw.scan`, and
        ``damage`` (a one-line description of damaged words, or None).
    """
    reader = RawReader(path, chunk_bytes=chunk_bytes, time_shift=time_shift)
    if reader.width is None or reader.height is None:
        reader.close()
        raise RawFormatError(f"{path}: the header gives no sensor geometry")
    fields = reader.header["fields"]
    sensor = {"format": reader.format, "width": reader.width, "height": reader.height,
              "endianness": reader.header["endianness"], "serial": fields.get("serial_number"),
              "plugin_name": fields.get("plugin_name"), "system_ID": fields.get("system_ID"),
              "raw_header": dict(fields)}
    writer = create_session(session_dir, width=reader.width, height=reader.height,
                            attrs={"sensor": sensor, **({"ball": ball} if ball else {})}, overwrite=overwrite)
    try:
        store = StoreBehind(writer)
        try:
            summary = scan(reader, store, progress=progress)
        finally:
            store.close()
        writer.set_attrs(raw_source={
            "file": str(path), "size_bytes": reader.size_bytes, "header_style": reader.header["style"],
            "time_shift_us": reader.decoder.time_shift_us, "stats": reader.decoder.stats,
            "damage": reader.damage_message()})
    finally:
        writer.close()
    return {"session": str(session_dir), **summary, "damage": reader.damage_message()}


def recover_session(session_dir, *, progress: bool = True, chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> dict:
    """Complete the store of a recording cut short (killed, crashed, power lost) from its RAW file.

    The recorder writes every byte received to the RAW file before decoding it; its store
    commits a little later (a kill loses the store's last fraction of a second, never the RAW
    file's). This decodes the RAW file, finds the store's last committed event in it (the same
    time, position and polarity), appends every event and trigger after it, and closes the
    session with ``attrs["recording"]`` saying it was recovered. Events whose times go back
    are left out and placed as the recorder does (:meth:`capture.session.SessionWriter.append_events`).
    Nothing is written unless the store's last event is found.

    Returns
    -------
    dict
        ``session``, ``events_added``, ``triggers_added``, ``seconds_added`` (event time, s),
        ``events``, ``triggers`` (the totals now) and ``damage`` (the RAW file's damaged words,
        e.g. the last word cut short by the kill, or None).

    Raises
    ------
    SessionError
        Not a recording cut short (closed by its recorder, no RAW file, or still being
        written), or the RAW file does not hold the store's last event.
    """
    path = Path(session_dir)
    session = open_session(path)
    if not session.cut_short:
        raise SessionError(f"{path}: nothing to recover: not a recording cut short (closed by its recorder, "
                           "without a RAW file, or still being written)")
    n = session.n_events
    stored_triggers = len(session.triggers())
    last, same_t = _last_event(session)
    raw_path = path / str(session.attrs["raw_file"])
    reader = RawReader(raw_path, chunk_bytes=chunk_bytes)
    found = n == 0
    seen_same_t = seen_events = seen_triggers = 0
    held_triggers: list[np.ndarray] = []
    writer = store = None
    added = {"triggers": 0, "t_from": None, "t_to": None}

    def on_batch(events, triggers):
        nonlocal found, seen_same_t, seen_events, seen_triggers, writer, store
        k = max(0, stored_triggers - seen_triggers)
        seen_triggers += len(triggers)
        triggers = triggers[k:]
        seen_events += len(events)
        if not found:
            # the store holds every received event but those left out as out of order, so its last
            # ones are at stream index n - same_t or later: an earlier event at that time is a
            # corrupted one the recorder left out
            at_t = np.flatnonzero(events["t"] == last["t"])
            at_t = at_t[at_t >= n - same_t - (seen_events - len(events))]
            if len(at_t) < same_t - seen_same_t:
                seen_same_t += len(at_t)
                held_triggers.append(triggers)
                return
            i = int(at_t[same_t - seen_same_t - 1])
            if events[i] != last:
                raise SessionError(f"{path}: {raw_path.name} does not match the store (its event at t = "
                                   f"{int(last['t'])} µs differs): not recovered")
            found, events = True, events[i + 1:]
            triggers = np.concatenate([*held_triggers, triggers])
        if writer is None:
            writer = update_session(path)
            writer.set_attrs(analysis=None)  # an analysis of the shorter store no longer covers it
            store = StoreBehind(writer)
        if len(events):
            added["t_from"] = added["t_from"] if added["t_from"] is not None else int(events["t"][0])
            added["t_to"] = int(events["t"][-1])
        added["triggers"] += len(triggers)
        store(events, triggers)

    try:
        with warnings.catch_warnings():  # the kill cut the last word short: reported as damage
            warnings.simplefilter("ignore")
            scan(reader, on_batch, progress=progress)
        if not found:
            raise SessionError(f"{path}: {raw_path.name} does not hold the store's last event (t = "
                               f"{int(last['t'])} µs): not recovered")
        if writer is None:  # the RAW file ends with the store's last event
            writer = update_session(path)
        if store is not None:
            store.close()
    except BaseException:
        if writer is not None:  # what was appended stays committed; the session stays cut short
            with contextlib.suppress(OSError):
                if store is not None:
                    store.close()
                writer.close()
        raise
    damage = reader.damage_message()
    n_added = writer.n_events - n  # the writer left out events whose times go back
    writer.close(recording={
        "stop_reason": "cut short (killed or crashed); the store was completed from its RAW file",
        "recovered_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "recovered_events": n_added, "recovered_triggers": added["triggers"],
        "payload_bytes": reader.size_bytes - reader.header_size, "raw_damage": damage})
    t_span = (added["t_to"] - added["t_from"]) * 1e-6 if added["t_from"] is not None else 0.0
    return {"session": str(path), "events_added": n_added, "triggers_added": added["triggers"],
            "seconds_added": round(t_span, 6), "events": n + n_added, "triggers": stored_triggers + added["triggers"],
            "damage": damage}


def complete_cut_short(session_dir, *, progress: bool = True) -> str | None:
    """Before analysing a session: complete it with :func:`recover_session` if it is a recording cut
    short. Returns one line on what was done, or why it could not be (its stored part is then
    analysed), or None for a session that was not cut short."""
    if not open_session(session_dir).cut_short:
        return None
    try:
        got = recover_session(session_dir, progress=progress)
    except (SessionError, RawFormatError, OSError) as exc:  # the stored part is still worth analysing
        return (f"the recording was cut short and its store could not be completed ({' '.join(str(exc).split())}); "
                "analysing the stored part")
    return (f"the recording was cut short (killed or crashed); its store was completed from its RAW file: "
            f"{got['events_added']} events, {got['seconds_added']:.3f} s, {got['triggers_added']} triggers added")


def _last_event(session) -> tuple[np.ndarray, int]:
    """The store's last committed event, and how many committed events share its time."""
    n = session.n_events
    if n == 0:
        return np.zeros((), EVENT_DTYPE), 0
    k = 1 << 12
    while True:
        tail = session.events_range(max(0, n - k), n)
        t_last = tail["t"][-1]
        if tail["t"][0] != t_last or k >= n:
            return tail[-1], int(np.count_nonzero(tail["t"] == t_last))
        k *= 4


MIN_SYNC_TRIGGERS = 4
"""Fewest trigger events for the sync-box method; with fewer, activity correlation is used."""


def _event_times_sample(session, max_events: int = 5_000_000) -> np.ndarray:
    """Event times (µs) of the session, every k-th event when there are more than ``max_events``."""
    n = session.n_events
    step = max(1, n // max_events)
    return np.asarray(session.read_column("events", "t", 0, n, step))


def fit_time_map(session_dir, video, *, exposure_s=None, led_roi=None):
    """Fit the frame-clock -> event-clock map of ``video`` for a session.

    Uses the sync box (LED in the frames, wired to the EVK trigger input) when the
    session holds trigger events, else the cross-correlation of event activity with
    frame-difference energy. ``exposure_s``: one for the clip or one per frame (s); None:
    estimated.

    Returns
    -------
    time_map : calib.sync.TimeMap
    exposure_s : float
        The exposure time used (their median when one per frame; estimated by the sync-box fit
        when not given), s.
    """
    s = open_session(session_dir)
    triggers = s.triggers()
    if len(triggers) >= MIN_SYNC_TRIGGERS:
        brightness, roi = sync.led_brightness(video.frames(gray=True), roi=led_roi)
        if led_roi is None:  # the block found holds part of the LED: its own pixels
            brightness, roi = sync.refine_led_roi(video.frames(gray=True), roi)
        try:
            return sync.fit_sync_box(brightness, video.t_s, triggers, exposure_s=exposure_s)
        except sync.SyncError:
            pass  # an LED that is not in view: fall back to activity correlation
    e = float(np.median(exposure_s)) if exposure_s is not None else 0.0
    exposure_s = e if np.isfinite(e) and e > 0 else 1.0 / float(video.fps)
    energy = sync.frame_difference_energy(img for _, _, img in video.frames(gray=True))
    return sync.fit_activity(_event_times_sample(s), video.t_s, energy, exposure_s=exposure_s), exposure_s


def attach_video(session_dir, mp4_path, *, exposure_s: float | None = None, led_roi=None) -> str:
    """Copy a GoPro recording into the session and store its frame times on the event clock.

    Parameters
    ----------
    session_dir : path
        The session.
    mp4_path : path
        The MP4 (first chapter of a chaptered recording).
    exposure_s : float, optional
        Frame exposure time, s (an override). Default: the median of the per-frame exposure in
        the clip's GPMF metadata (``SHUT``) when it has some, else estimated by the sync fit.
    led_roi : tuple, optional
        Sync-box LED region ``(x0, y0, x1, y1)`` in frame pixels, half-open (default: found
        automatically as the most varying block of the frames).

    Returns
    -------
    str
        One line describing the fitted time map.
    """
    session_dir = Path(session_dir)
    dest = session_dir / "gopro"
    dest.mkdir(exist_ok=True)
    first = None
    for p in chapter_paths(mp4_path):
        target = dest / p.name
        if p.resolve() != target.resolve():
            shutil.copy2(p, target)
        first = first or target
    video = read_video(first)
    source, notes = ("given" if exposure_s is not None else "estimated"), []
    metas = [gpmf.frame_metadata(*samples) if (samples := gpmf_samples(p)) is not None else None
             for p in video.paths]
    meta = next((m for m in metas if m is not None), None)
    per_frame = None
    recorded = _recorded_exposures(video, metas, notes)
    if recorded is not None:
        lo, hi = np.percentile(recorded, [5, 95])
        if exposure_s is None:  # each frame's own exposure (auto-exposure), unless one is typed
            per_frame, source = recorded, "gpmf"
            notes.append(f"exposure {float(np.median(per_frame)) * 1e3:.3f} ms from the camera's metadata"
                         + (f" (varies {lo * 1e3:.3f}-{hi * 1e3:.3f} ms; each frame's is used)" if hi > 1.05 * lo else ""))
        elif hi > 1.05 * lo or not 0.95 * lo <= exposure_s <= 1.05 * hi:  # it varied, or the typed one is not it
            notes.append(f"the camera's metadata says the exposure was {lo * 1e3:.3f}-{hi * 1e3:.3f} ms; the "
                         f"typed {exposure_s * 1e3:.3f} ms is used for every frame (leave --exposure out to use each frame's)")
    skipped = sum(int(np.count_nonzero(m.frame_skips)) for m in metas if m is not None)
    if skipped:
        notes.append(f"{skipped} frames skipped or duplicated by the camera (GPMF MSKP)")
    tm, exposure_s = fit_time_map(session_dir, video, exposure_s=per_frame if per_frame is not None else exposure_s,
                                  led_roi=led_roi)
    writer = update_session(session_dir)
    store.attach_video(writer, session_dir, video, tm, exposure_s=per_frame if per_frame is not None else exposure_s)
    writer.set_attrs(frame_camera={"model": "GoPro", "width": video.width, "height": video.height,
                                   "fps_num": video.fps_num, "fps_den": video.fps_den,
                                   "n_frames": video.n_frames, "exposure_s": float(exposure_s),
                                   "exposure_source": source,
                                   "frame_skips": skipped if meta else None,
                                   "readout": meta.readout if meta else None})
    writer.close()
    sigma = float(np.sqrt(max(tm.cov[0, 0], 0.0)))
    return (f"{video.n_frames} frames at {float(video.fps):.2f} fps aligned by {tm.method}: "
            f"video t=0 at event t={float(tm.to_event_us(0.0)) / 1e6:.6f} s, drift {tm.drift_ppm:+.1f} ppm, "
            f"±{sigma:.0f} µs" + "".join(f"; {n}" for n in notes))


def _recorded_exposures(video, metas, notes: list[str]) -> np.ndarray | None:
    """Each frame's exposure (s) from the GPMF of its own chapter; frames without a usable value
    (a chapter without metadata; a zero, negative, non-finite or longer-than-two-frames value)
    get the median of the others, and ``notes`` says how many. None when no frame has one."""
    out = np.full(video.n_frames, np.nan)
    starts = [*map(int, video.chapter_start), video.n_frames]
    for k, m in enumerate(metas):
        if m is not None and len(m.exposure_s):
            i0, i1 = starts[k], starts[k + 1]
            out[i0:i1] = m.exposure_at(video.t_s[i0:i1] - video.t_s[i0])
    ok = np.isfinite(out) & (out > 0) & (out <= 2.0 / float(video.fps))
    if not ok.any():
        return None
    if not ok.all():
        notes.append(f"{int((~ok).sum())} of {len(out)} frames without a usable exposure in the camera's metadata "
                     "(missing, zero or not a number): the others' median is used for them")
        out[~ok] = np.median(out[ok])
    return out


def session_from_raw(raw_path, session_dir, mp4_path=None, *, progress: bool = True, led_roi=None,
                     exposure_s: float | None = None, ball: dict | None = None) -> tuple[Path, str | None]:
    """Convert a RAW file (and optionally its MP4, aligned to the event clock) into a new session,
    with the ``ball`` it records (see :func:`convert_raw`).

    Returns the session directory and the video's one-line alignment note (None without video).
    """
    convert_raw(raw_path, session_dir, progress=progress, ball=ball)
    note = None
    if mp4_path is not None:
        note = attach_video(session_dir, mp4_path, led_roi=led_roi, exposure_s=exposure_s)
    return Path(session_dir), note


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m capture.ingest",
                                     description="Get a RAW file or a frame-camera video into a session.")
    sub = parser.add_subparsers(dest="command", required=True)
    p_raw = sub.add_parser("raw", help="decode a RAW file (EVT 2.0 / 2.1 / 3.0) into a new session store")
    p_raw.add_argument("file")
    p_raw.add_argument("session_dir")
    p_raw.add_argument("--time-shift", action="store_true",
                       help="subtract Metavision's default time shift (default: sensor time)")
    p_raw.add_argument("--overwrite", action="store_true", help="replace an existing session store")
    p_raw.add_argument("--quiet", action="store_true", help="no progress bar")
    add_ball_args(p_raw)
    p_recover = sub.add_parser("recover", help="complete the store of a recording cut short (killed, "
                               "crashed) from its RAW file")
    p_recover.add_argument("session_dir")
    p_recover.add_argument("--quiet", action="store_true", help="no progress bar")
    p_video = sub.add_parser("video", help="attach a GoPro MP4 to a session, aligned to the event clock")
    p_video.add_argument("session_dir")
    p_video.add_argument("mp4")
    p_video.add_argument("--led-roi", type=box, metavar="X0,Y0,X1,Y1",
                         help="sync-box LED region in video pixels (default: found automatically)")
    p_video.add_argument("--exposure", type=float, metavar="S",
                         help="video shutter time in seconds when locked (default: estimated)")
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)

    def body():
        if args.command == "raw":
            print_fields(convert_raw(args.file, args.session_dir, time_shift=args.time_shift,
                                     overwrite=args.overwrite, progress=not args.quiet, ball=ball_attr(args)))
        elif args.command == "recover":
            print_fields(recover_session(args.session_dir, progress=not args.quiet))
        else:
            print(attach_video(args.session_dir, args.mp4, led_roi=args.led_roi, exposure_s=args.exposure))

    return run_command(parser.prog, body)


if __name__ == "__main__":
    raise SystemExit(main())
