"""Command line: ``python -m capture.raw info FILE`` and ``python -m capture.raw convert FILE SESSION_DIR``."""

from __future__ import annotations

import argparse
import sys

import numpy as np
from tqdm import tqdm

from capture.raw.errors import RawFormatError
from capture.raw.stream import DEFAULT_CHUNK_BYTES, RawReader
from capture.session import SessionError, create_session


def _scan(reader: RawReader, on_batch=None, progress: bool = False) -> dict:
    """Decode every batch; returns counts and the time range. ``on_batch(events, triggers)`` sees each."""
    n_ev = n_tr = n_on = 0
    t_first = t_last = None
    bar = tqdm(total=reader.size_bytes, unit="B", unit_scale=True, disable=not progress,
               desc="decoding", file=sys.stderr)
    done = 0
    for events, triggers in reader:
        if len(events):
            n_ev += len(events)
            n_on += int(np.count_nonzero(events["p"]))
            t_first = int(events["t"][0]) if t_first is None else t_first
            t_last = int(events["t"][-1])
        n_tr += len(triggers)
        if on_batch is not None:
            on_batch(events, triggers)
        now = reader.decoder.bytes_in + reader.header_size
        bar.update(now - done)
        done = now
    bar.close()
    duration_us = (t_last - t_first) if t_first is not None else 0
    return {"events": n_ev, "events_on": n_on, "triggers": n_tr, "t_first_us": t_first, "t_last_us": t_last,
            "duration_us": duration_us,
            "rate_ev_s": n_ev / (duration_us * 1e-6) if duration_us > 0 else None}


def info(path, *, chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> dict:
    """Header, format, geometry, counts, duration (µs) and mean event rate (ev/s) of a RAW file."""
    reader = RawReader(path, chunk_bytes=chunk_bytes)
    summary = _scan(reader)
    return {"file": str(path), "format": reader.format, "width": reader.width, "height": reader.height,
            "header_style": reader.header["style"], "header": reader.header["fields"],
            "header_bytes": reader.header_size, "size_bytes": reader.size_bytes, **summary,
            "damage": reader.damage_message(), "stats": reader.decoder.stats}


def convert(path, session_dir, *, time_shift: bool = False, overwrite: bool = False,
            chunk_bytes: int = DEFAULT_CHUNK_BYTES, progress: bool = True) -> dict:
    """Decode a RAW file into a new session store (events, triggers; header in the root attrs).

    Root attrs written: ``sensor`` (format, geometry, serial, plugin, header fields),
    ``raw_source`` (file name, size, header style, time shift, decoder counters).
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
                            attrs={"sensor": sensor}, overwrite=overwrite)
    try:
        def store(events, triggers):
            writer.append_events(events)
            if len(triggers):
                writer.append_triggers(triggers)
        summary = _scan(reader, store, progress=progress)
        writer.set_attrs(raw_source={
            "file": str(path), "size_bytes": reader.size_bytes, "header_style": reader.header["style"],
            "time_shift_us": reader.decoder.time_shift_us, "stats": reader.decoder.stats,
            "damage": reader.damage_message()})
    finally:
        writer.close()
    return {"session": str(session_dir), **summary, "damage": reader.damage_message()}


def _print(d: dict) -> None:
    for key, value in d.items():
        if isinstance(value, dict):
            print(f"{key}:")
            for k, v in value.items():
                print(f"  {k}: {v}")
        elif value is not None:
            print(f"{key}: {round(value) if isinstance(value, float) else value}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m capture.raw",
                                     description="Prophesee RAW files (EVT 2.0 / 2.1 / 3.0)")
    sub = parser.add_subparsers(dest="command", required=True)
    p_info = sub.add_parser("info", help="header, format, geometry, event counts, duration, rate")
    p_info.add_argument("file")
    p_conv = sub.add_parser("convert", help="decode into a session store (Zarr)")
    p_conv.add_argument("file")
    p_conv.add_argument("session_dir")
    p_conv.add_argument("--time-shift", action="store_true",
                        help="subtract Metavision's default time shift (default: sensor time)")
    p_conv.add_argument("--overwrite", action="store_true", help="replace an existing session")
    p_conv.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    try:
        if args.command == "info":
            _print(info(args.file))
        else:
            _print(convert(args.file, args.session_dir, time_shift=args.time_shift,
                           overwrite=args.overwrite, progress=not args.no_progress))
    except (RawFormatError, SessionError, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0
