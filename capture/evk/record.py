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
    idle_risks : int
        Spells with no USB request on the data endpoint, long enough at the stream's rate to
        overflow the device's buffer (``Camera.device_buffer_bytes``): data may have been lost
        there without any trace in the stream (see :class:`capture.evk.stream.Reader`).
    time_base_monitored : bool
        Whether the stream's time base is checked for discontinuities (EVT3); an EVT 2.1
        stream is not, so data lost on the link would go unseen there.
    decoder_stats : dict
        The streaming decoder's own counters (damage, time jumps...).
    decode_backlog_bytes : int
        Bytes of the RAW file not decoded yet (kept current by the decoder thread while recording).
    n_transfers : int
        Bulk-IN requests kept in flight (1: synchronous reads, one at a time).
    n_reads, n_full_reads, n_timeouts : int
        Bulk requests that returned data, requests that filled their whole buffer (a hint
        that the device side may be overflowing), requests that timed out empty (idle).
    queue_peak_bytes : int
        Highest queue occupancy.
    read_gap_us, max_read_gap_us : float
        Mean and longest time from handling a completed request to submitting the next. With
        synchronous reads nothing is pending meanwhile and the device must buffer what it
        produces; with queued requests the others keep filling.
    stream_s : float
        Wall-clock time until streaming ended and every byte was on disk.
    duration_s, cpu_s : float
        Wall-clock and process CPU time until ``record`` returned (decoding caught up).
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
    idle_risks: int = 0
    time_base_monitored: bool = True
    decoder_stats: dict = field(default_factory=dict)
    n_transfers: int = 1
    n_reads: int = 0
    n_full_reads: int = 0
    n_timeouts: int = 0
    queue_peak_bytes: int = 0
    decode_backlog_bytes: int = 0
    read_gap_us: float = 0.0
    max_read_gap_us: float = 0.0
    stream_s: float = 0.0
    duration_s: float = 0.0
    cpu_s: float = 0.0
    stop_reason: str = ""
    error: str | None = None

    @property
    def lossless(self) -> bool:
        """No host-side drop, no spell without a USB request that could have overflowed the
        device, and no time-base discontinuity (the latter checked in EVT3 only: see
        :attr:`time_base_monitored`)."""
        return (self.dropped_bytes == 0 and self.idle_risks == 0 and self.time_jumps == 0
                and self.error is None)


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


class _FileDecoder(threading.Thread):
    """Decodes the RAW file while it is being written (tailing it), calling ``on_batch``.

    Decoding never holds up the USB path: the writer only appends bytes, this thread reads
    them back (page cache) at its own pace and catches up after the stream ends.
    """

    READ_BYTES = 1 << 20  # small batches: the GIL is held for a few ms at most per decode
    WAIT_S = 0.05  # a batch waits this long for READ_BYTES to be written (a consumer's cost per batch
    # counts: decoding as soon as bytes arrive made a batch of every USB transfer)

    def __init__(self, path: Path, offset: int, decoder: StreamDecoder, on_batch, stats: RecordStats):
        super().__init__(name="evk-decoder", daemon=True)
        self._file = path.open("rb")
        self._file.seek(offset)
        self._decoder = decoder
        self._on_batch = on_batch
        self._stats = stats
        self._cond = threading.Condition()
        self._available = 0
        self._closed = False
        self.error: BaseException | None = None

    def written(self, payload_bytes: int) -> None:
        """The writer has appended up to ``payload_bytes`` of payload."""
        with self._cond:
            self._available = payload_bytes
            self._cond.notify()

    def close_input(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()

    def run(self) -> None:
        pos = 0
        try:
            while True:
                with self._cond:
                    due = time.monotonic() + self.WAIT_S
                    while not self._closed and (self._available - pos < self.READ_BYTES
                                                and (pos >= self._available or time.monotonic() < due)):
                        self._cond.wait(max(0.0, min(0.1, due - time.monotonic())) or 0.1)
                    if pos >= self._available and self._closed:
                        break
                    end = self._available
                data = self._file.read(min(end - pos, self.READ_BYTES))
                pos += len(data)
                self._stats.decode_backlog_bytes = end - pos
                events, triggers = self._decoder.decode(data)
                if len(events) or len(triggers):
                    _count(self._stats, events, triggers)
                    self._on_batch(events, triggers)
            self._decoder.finish()
        except BaseException as exc:  # noqa: BLE001 - re-raised by record()
            self.error = exc
        finally:
            self._file.close()


def record(camera, raw_path, *, on_batch=None, stop: threading.Event | None = None,
           max_duration_s: float | None = None, stats: RecordStats | None = None) -> RecordStats:
    """Stream from ``camera`` into a RAW file until stopped; decode it on the fly if asked.

    Three threads: the camera's reader thread (started here if the camera is not streaming
    yet) only queues USB bytes; this thread writes every byte, unmodified, after a RAW
    header; when ``on_batch`` is given a decoder thread reads the file back as it grows,
    decodes it with :class:`capture.raw.StreamDecoder` and calls ``on_batch(events,
    triggers)`` (EVENT_DTYPE / TRIGGER_DTYPE arrays, from that thread) for each non-empty
    batch. A slow decoder or ``on_batch`` therefore never causes USB drops: it lags and
    catches up after the stream ends, and ``record`` returns once it has. Streaming is
    stopped when this returns.

    Parameters
    ----------
    camera : capture.evk.Camera
        An opened camera.
    raw_path : str or Path
        Output RAW file (overwritten).
    on_batch : callable, optional
        ``on_batch(events, triggers)``; ``None`` records raw bytes only (decode later with
        ``capture.raw``), the cheapest mode. An exception from it stops the recording and
        is re-raised (the RAW file is kept).
    stop : threading.Event, optional
        Set it (from any thread) to end the recording.
    max_duration_s : float, optional
        Wall-clock limit on streaming, seconds.
    stats : RecordStats, optional
        Filled in as the recording goes, for a caller that watches it from another thread
        (``decode_backlog_bytes``, ``overflows``, ``dropped_bytes``, ``time_jumps``,
        ``idle_risks``); a new one
        otherwise.

    Returns
    -------
    RecordStats
        Also when the device has no more data (file-backed fake: ``stop_reason ==
        "end_of_stream"``).

    Raises
    ------
    EvkConnectionError
        Stall, unplug or USB error mid-stream. Everything received before it is in the RAW
        file (closed properly) and decoded; the exception's ``stats`` holds the
        :class:`RecordStats`.
    """
    raw_path = Path(raw_path)
    if stats is None:
        stats = RecordStats(raw_path=raw_path)
    stats.raw_path = raw_path
    monitor = TimeHighMonitor() if camera.info.format == "EVT3" else None
    stats.time_base_monitored = monitor is not None
    header = _header(camera)
    t0, c0 = time.monotonic(), time.process_time()
    decode = None
    with raw_path.open("wb", buffering=0) as f:
        f.write(header)
        stats.header_bytes = len(header)
        if on_batch is not None:
            i = camera.info
            decoder = StreamDecoder(i.format, endianness=_endianness(camera), width=i.width, height=i.height)
            decode = _FileDecoder(raw_path, len(header), decoder, on_batch, stats)
            decode.start()
        try:
            camera.start()
            reader = camera.reader
            queue = reader.queue
            while True:
                item = queue.get(QUEUE_POLL_S)
                if item is ByteQueue.EOF:
                    break
                if isinstance(item, Gap):
                    stats.gaps.append((stats.payload_bytes, item.nbytes))
                    stats.overflows += 1  # kept current for a caller watching (the reader's totals at the end)
                    stats.dropped_bytes += item.nbytes
                    if monitor is not None:
                        monitor.reset()
                elif item is not None:
                    data = item.data
                    _write_all(f, data)
                    stats.payload_bytes += item.nbytes
                    if monitor is not None:
                        monitor.feed(data)
                        stats.time_jumps = monitor.jumps
                    reader.release(item)
                    stats.idle_risks = reader.n_idle_risks  # kept current for a caller watching
                    if decode is not None:
                        decode.written(stats.payload_bytes)
                if not stats.stop_reason:
                    if stop is not None and stop.is_set():
                        stats.stop_reason = "stop"
                    elif max_duration_s is not None and time.monotonic() - t0 >= max_duration_s:
                        stats.stop_reason = "duration"
                    elif decode is not None and decode.error is not None:
                        stats.stop_reason = "error"
                    if stats.stop_reason:
                        camera.stop()  # stop sequence, then the reader ends; keep draining
        finally:
            try:
                camera.stop()
            except EvkError as exc:
                log.warning("stopping the camera after recording failed: %s", exc)
            stats.stream_s = time.monotonic() - t0
            if decode is not None:
                decode.close_input()
                decode.join()
                stats.decoder_stats = decoder.stats
            stats.duration_s = time.monotonic() - t0
            stats.cpu_s = time.process_time() - c0
            reader = camera.reader
            if reader is not None:
                stats.n_transfers = reader.n_transfers
                stats.n_reads, stats.n_full_reads = reader.n_reads, reader.n_full_reads
                stats.n_timeouts = reader.n_timeouts
                stats.dropped_bytes, stats.overflows = reader.dropped_bytes, reader.n_overflows
                stats.queue_peak_bytes = reader.queue.peak_bytes
                stats.read_gap_us = reader.gap_s / max(reader.n_reads, 1) * 1e6
                stats.max_read_gap_us = reader.max_gap_s * 1e6
                stats.idle_risks = reader.n_idle_risks
            if monitor is not None:
                stats.time_jumps = monitor.jumps
    if decode is not None and decode.error is not None:
        stats.error = f"on_batch/decoding failed: {decode.error!r}"
        raise decode.error
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
    if stats.dropped_bytes or stats.time_jumps or stats.idle_risks:
        log.warning("recording %s: %d bytes dropped (queue overflow), %d time-base jumps, %d spells without "
                    "a USB request long enough to overflow the device (possible unseen losses)",
                    raw_path, stats.dropped_bytes, stats.time_jumps, stats.idle_risks)
    return stats


def _write_all(f, data: memoryview) -> None:
    """Unbuffered writes may be partial: loop until every byte is in the file."""
    while len(data):
        data = data[f.write(data):]


def _count(stats: RecordStats, events, triggers) -> None:
    stats.n_events += len(events)
    stats.n_triggers += len(triggers)
    if len(events):
        if stats.t_first_us is None:
            stats.t_first_us = int(events["t"][0])
        stats.t_last_us = int(events["t"][-1])
