"""Record a live EVK stream to a RAW file (exact bytes) while decoding it for live use."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from capture.raw import StreamDecoder, header_bytes

from .errors import EvkConnectionError, EvkError
from .stream import ByteQueue, Gap, TimeHighMonitor

log = logging.getLogger(__name__)

QUEUE_POLL_S = 0.05


@dataclass
class RecordStats:
    """Outcome of :func:`record`.

    Attributes
    ----------
    raw_path : Path
        The RAW file written (header + exact byte stream).
    header_bytes, payload_bytes : int
        Sizes of the RAW header and of the recorded event stream, bytes.
    n_events, n_triggers : int
        Decoded CD events / trigger events (0 when not decoding).
    t_first_us, t_last_us : int or None
        First and last decoded event time (µs), when decoding.
    dropped_bytes, overflows : int
        Bytes lost to host queue overflow, and how many chunks were dropped.
    gaps : list of (int, int)
        ``(payload offset, dropped bytes)`` for every overflow gap in the RAW file.
    time_jumps : int
        EVT3 TIME_HIGH discontinuities (lost data on the link, or idle periods [uncertain]).
    decoder_stats : dict
        The streaming decoder's own counters (damage, time jumps...).
    n_reads, n_full_reads, n_timeouts : int
        Bulk reads with data, reads that filled the whole buffer (a hint that the device
        side may be overflowing), reads that timed out (idle).
    queue_peak_bytes : int
        Highest queue occupancy.
    duration_s, cpu_s : float
        Wall-clock and process CPU time of the recording.
    stop_reason : str
        ``"stop"``, ``"duration"``, ``"end_of_stream"`` or ``"error"``.
    error : str or None
        The error that ended the recording, if any.
    """

    raw_path: Path
    header_bytes: int = 0
    payload_bytes: int = 0
    n_events: int = 0
    n_triggers: int = 0
    t_first_us: int | None = None
    t_last_us: int | None = None
    dropped_bytes: int = 0
    overflows: int = 0
    gaps: list = field(default_factory=list)
    time_jumps: int = 0
    decoder_stats: dict = field(default_factory=dict)
    n_reads: int = 0
    n_full_reads: int = 0
    n_timeouts: int = 0
    queue_peak_bytes: int = 0
    duration_s: float = 0.0
    cpu_s: float = 0.0
    stop_reason: str = ""
    error: str | None = None

    @property
    def lossless(self) -> bool:
        """No host-side drop and no time-base discontinuity detected."""
        return self.dropped_bytes == 0 and self.time_jumps == 0 and self.error is None


def _header(camera) -> bytes:
    i = camera.info
    return header_bytes(
        format=i.format, width=i.width, height=i.height, endianness=_endianness(camera),
        serial_number=i.serial, firmware_version=i.firmware,
        integrator_name="Prophesee", plugin_name=f"courtside_evk_{i.sensor.lower().replace('.', '')}",
        camera=f"{i.board}_{i.sensor}",
    )


def _endianness(camera) -> str:
    """EVT2.1 from the EVK's IMX636 uses the legacy word order (section 4.3)."""
    return "legacy" if camera.info.format == "EVT21" else "little"


def record(camera, raw_path, *, on_batch=None, stop: threading.Event | None = None,
           max_duration_s: float | None = None) -> RecordStats:
    """Stream from ``camera`` into a RAW file until stopped; decode on the fly if asked.

    The reader thread (started here if the camera is not streaming yet) only queues bytes;
    this thread writes every byte, unmodified, after a RAW header, and, when ``on_batch``
    is given, decodes them with :class:`capture.raw.StreamDecoder` and calls
    ``on_batch(events, triggers)`` (EVENT_DTYPE / TRIGGER_DTYPE arrays) for each non-empty
    batch. Streaming is stopped when this returns.

    Parameters
    ----------
    camera : capture.evk.Camera
        An opened camera.
    raw_path : str or Path
        Output RAW file (overwritten).
    on_batch : callable, optional
        ``on_batch(events, triggers)``; ``None`` records raw bytes only (decode later with
        ``capture.raw``), which is the cheapest mode.
    stop : threading.Event, optional
        Set it (from any thread) to end the recording.
    max_duration_s : float, optional
        Wall-clock limit, seconds.

    Returns
    -------
    RecordStats
        Also when the device has no more data (file-backed fake: ``stop_reason ==
        "end_of_stream"``).

    Raises
    ------
    EvkConnectionError
        Stall, unplug or USB error mid-stream. Everything received before it is in the RAW
        file (closed properly); the exception's ``stats`` holds the :class:`RecordStats`.
    """
    raw_path = Path(raw_path)
    stats = RecordStats(raw_path=raw_path)
    decoder = None
    if on_batch is not None:
        i = camera.info
        decoder = StreamDecoder(i.format, endianness=_endianness(camera), width=i.width, height=i.height)
    monitor = TimeHighMonitor() if camera.info.format == "EVT3" else None
    header = _header(camera)
    t0, c0 = time.monotonic(), time.process_time()
    with raw_path.open("wb", buffering=0) as f:
        f.write(header)
        stats.header_bytes = len(header)
        camera.start()
        reader = camera.reader
        queue = reader.queue
        try:
            while True:
                item = queue.get(QUEUE_POLL_S)
                if item is ByteQueue.EOF:
                    break
                if isinstance(item, Gap):
                    stats.gaps.append((stats.payload_bytes, item.nbytes))
                    if monitor is not None:
                        monitor.reset()
                elif item is not None:
                    f.write(item)
                    stats.payload_bytes += len(item)
                    if monitor is not None:
                        monitor.feed(item)
                    if decoder is not None:
                        events, triggers = decoder.decode(item)
                        if len(events) or len(triggers):
                            _count(stats, events, triggers)
                            on_batch(events, triggers)
                if not stats.stop_reason:
                    if stop is not None and stop.is_set():
                        stats.stop_reason = "stop"
                    elif max_duration_s is not None and time.monotonic() - t0 >= max_duration_s:
                        stats.stop_reason = "duration"
                    if stats.stop_reason:
                        camera.stop()  # stop sequence, then the reader ends; keep draining
        finally:
            try:
                camera.stop()
            except EvkError as exc:
                log.warning("stopping the camera after recording failed: %s", exc)
            stats.duration_s = time.monotonic() - t0
            stats.cpu_s = time.process_time() - c0
            stats.n_reads, stats.n_full_reads = reader.n_reads, reader.n_full_reads
            stats.n_timeouts = reader.n_timeouts
            stats.dropped_bytes, stats.overflows = reader.dropped_bytes, reader.n_overflows
            stats.queue_peak_bytes = queue.peak_bytes
            if monitor is not None:
                stats.time_jumps = monitor.jumps
            if decoder is not None:
                decoder.finish()
                stats.decoder_stats = decoder.stats
    if reader.error is not None:
        stats.stop_reason = "error"
        stats.error = str(reader.error)
        err = type(reader.error)(
            f"{reader.error}; the {stats.payload_bytes} bytes received before it are kept in {raw_path}"
            + (f" (last event t={stats.t_last_us} us)" if stats.t_last_us is not None else "")
        )
        if isinstance(err, EvkConnectionError):
            err.stats = stats
        raise err
    if not stats.stop_reason:
        stats.stop_reason = "end_of_stream" if reader.end_of_stream else "stop"
    if stats.dropped_bytes or stats.time_jumps:
        log.warning("recording %s: %d bytes dropped (queue overflow), %d time-base jumps",
                    raw_path, stats.dropped_bytes, stats.time_jumps)
    return stats


def _count(stats: RecordStats, events, triggers) -> None:
    stats.n_events += len(events)
    stats.n_triggers += len(triggers)
    if len(events):
        if stats.t_first_us is None:
            stats.t_first_us = int(events["t"][0])
        stats.t_last_us = int(events["t"][-1])
