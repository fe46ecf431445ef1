"""Data path: the USB reader thread, its bounded byte queue and EVT3 time-base monitoring.

The reader thread keeps many bulk-IN requests queued on the data endpoint
(:mod:`capture.evk.transfers`, as the HAL's 20 asynchronous 128 KiB transfers), reaps them
in order and hands the bytes to a bounded queue; decoding and disk writes happen on the
consumer's threads (:func:`capture.evk.record`). Where the USB backend cannot queue requests
it falls back to back-to-back synchronous reads, one in flight. When the queue is full the
chunk is dropped, counted and marked by a :class:`Gap` so that the loss is reported, never
silent.
"""

from __future__ import annotations

import array
import errno
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import usb.core

from .errors import EvkError, usb_error
from .transfers import Done

DRAIN_TIMEOUT_MS = 10
DRAIN_MAX_READS = 256
CANCEL_WAIT_S = 2.0
"""How long cancelled requests may take to come back before the reader gives up on them."""
RATE_WINDOW_S = 0.1
"""The stream's recent byte rate is measured over this much wall time of completed requests."""
RATE_MARGIN = 2.0
"""The device may produce this many times the stream's recent byte rate (a burst, or a rate measured
on a stream already losing data), up to :data:`LINK_MAX_BYTES_S`."""
LINK_MAX_BYTES_S = 400e6
"""Fastest bulk-IN delivery of a SuperSpeed link, bytes/s (5 Gb/s less its coding and protocol):
a request of n bytes cannot complete sooner than n / this after it was submitted."""

_ABANDONED: list = []
"""Transfer queues whose requests never came back after a cancel: kept alive for good, so that
libusb never writes into freed memory."""

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Gap:
    """Marker in the queue: ``nbytes`` of data were dropped here (queue overflow)."""

    nbytes: int


class Chunk(NamedTuple):
    """``nbytes`` of stream data at the start of ``buffer`` (a pooled read buffer, or a
    ``bytes`` copy of a short read)."""

    buffer: array.array | bytes
    nbytes: int

    @property
    def data(self) -> memoryview:
        return memoryview(self.buffer)[: self.nbytes]


class ByteQueue:
    """FIFO of :class:`Chunk` items bounded by total bytes; never blocks the producer.

    Parameters
    ----------
    capacity_bytes : int
        Maximum bytes held; :meth:`put` refuses a chunk that would exceed it.
    """

    EOF = object()

    def __init__(self, capacity_bytes: int):
        self.capacity_bytes = int(capacity_bytes)
        self._items: deque = deque()
        self._bytes = 0
        self._cond = threading.Condition()
        self._closed = False
        self.peak_bytes = 0

    def put(self, chunk: Chunk) -> bool:
        """Append ``chunk``; return False (and keep nothing) if it does not fit."""
        with self._cond:
            if self._bytes + chunk.nbytes > self.capacity_bytes:
                return False
            self._items.append(chunk)
            self._bytes += chunk.nbytes
            self.peak_bytes = max(self.peak_bytes, self._bytes)
            self._cond.notify()
            return True

    def put_gap(self, nbytes: int) -> None:
        """Record that ``nbytes`` were dropped at this point (merged with a previous gap)."""
        with self._cond:
            if self._items and isinstance(self._items[-1], Gap):
                self._items[-1] = Gap(self._items[-1].nbytes + nbytes)
            else:
                self._items.append(Gap(nbytes))
            self._cond.notify()

    def close(self) -> None:
        """No more items will come; :meth:`get` returns :attr:`EOF` once empty."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def get(self, timeout_s: float):
        """Next :class:`Chunk` or :class:`Gap`; ``None`` after ``timeout_s`` without data; :attr:`EOF`
        when closed and empty."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout_s)
            if self._items:
                item = self._items.popleft()
                if not isinstance(item, Gap):
                    self._bytes -= item.nbytes
                return item
            return self.EOF if self._closed else None


class Reader(threading.Thread):
    """Reader thread: bulk-IN requests on the data endpoint into a :class:`ByteQueue`.

    With a transfer queue (``transfers``), ``n_transfers`` requests of ``read_bytes`` stay
    in flight: each one reaped is replaced at once, so the host controller keeps filling the
    others while Python is busy (the HAL's scheme, first timeouts staggered as the HAL does).
    Without one, back-to-back synchronous reads leave the endpoint without a request between
    two reads. :attr:`gap_s` totals the time from handling one completed request to
    submitting the next.

    Requests fill pooled buffers (no copy; short results, under half the buffer, are
    copied out so that small chunks do not pin big buffers); the consumer hands each chunk
    back with :meth:`release` once written.

    Timeouts without data are normal (idle sensor) and only counted. Any other USB error
    (stall, unplug, I/O) ends the thread with :attr:`error` set; everything read before it
    stays in the queue.

    Parameters
    ----------
    dev : usb.core.Device
        Claimed device.
    ep : int
        Data endpoint address (0x81 on EVK4).
    read_bytes : int
        Size of each bulk read, a multiple of wMaxPacketSize.
    timeout_ms : int
        Per-read timeout.
    capacity_bytes : int
        Queue capacity.
    end_of_stream : callable, optional
        Backend hook (file-backed fakes): returns True when no more data will ever come.
    name : str
        Camera name for messages.
    transfers : object, optional
        A transfer queue from :func:`capture.evk.transfers.open_queue`; ``None`` reads
        synchronously.
    n_transfers : int
        Requests kept in flight with ``transfers``.
    device_buffer_bytes : int, optional
        The device's own buffer between sensor and USB, bytes; with it, spells without a
        request on the endpoint long enough to overflow it are counted (:attr:`n_idle_risks`).

    Attributes
    ----------
    n_idle_risks : int
        Runs in which the endpoint may have lacked request space for longer than the device's
        buffer covers: data may have been lost there without a trace in the stream (a loss within
        one EVT3 time-base period that resumes on a TIME_HIGH word leaves it well-formed). When a
        request completed is not observable from Python (a thread may wait for the GIL), so the
        bounds err on the safe side: queued requests through :class:`_SpaceLedger`; a synchronous
        read may have completed as soon as its bytes could cross the link, and the spell until the
        next counts at :data:`RATE_MARGIN` times the stream's recent rate.
    """

    def __init__(self, dev, ep: int, *, read_bytes: int, timeout_ms: int, capacity_bytes: int,
                 end_of_stream=None, name: str = "EVK", transfers=None, n_transfers: int = 64,
                 device_buffer_bytes: int | None = None):
        super().__init__(name=f"evk-reader-{name}", daemon=True)
        self.dev = dev
        self.ep = ep
        self.read_bytes = int(read_bytes)
        self.timeout_ms = int(timeout_ms)
        self.queue = ByteQueue(capacity_bytes)
        self.camera_name = name
        self._eos = end_of_stream
        self._stop_event = threading.Event()
        self.bytes_read = 0
        self.n_reads = 0
        self.n_full_reads = 0
        self.n_timeouts = 0
        self.dropped_bytes = 0
        self.n_overflows = 0
        self.error: EvkError | None = None
        self.end_of_stream = False
        self.gap_s = 0.0
        self.max_gap_s = 0.0
        self.device_buffer_bytes = device_buffer_bytes
        self._sync_risks = 0
        self._ledger: _SpaceLedger | None = None
        self._recent: deque = deque()  # (clock s, bytes_read) at recent synchronous reads with data
        self._at_risk = False
        self.transfers = transfers
        self.n_transfers = int(n_transfers) if transfers is not None else 1
        self.abandoned = False
        """Requests never came back after a cancel: the device handle must stay open."""
        self._free: deque = deque()
        self._n_buffers = 0
        # queued chunks hold at least half a buffer each (smaller ones are copied out)
        self._max_buffers = 2 * self.queue.capacity_bytes // self.read_bytes + self.n_transfers + 1

    def _buffer(self) -> array.array | None:
        try:
            return self._free.pop()
        except IndexError:
            if self._n_buffers >= self._max_buffers:
                return None
            self._n_buffers += 1
            return array.array("B", bytes(self.read_bytes))

    def release(self, chunk: Chunk) -> None:
        """Give a consumed chunk's buffer back to the pool (any thread)."""
        if isinstance(chunk.buffer, array.array):
            self._free.append(chunk.buffer)

    @staticmethod
    def drain(dev, ep: int, max_packet: int) -> int:
        """Discard what is left in the data endpoint (read until a timeout); return bytes."""
        n = 0
        buf = array.array("B", bytes(max(max_packet, 1) * 64))
        for _ in range(DRAIN_MAX_READS):
            try:
                got = dev.read(ep, buf, DRAIN_TIMEOUT_MS)
            except usb.core.USBTimeoutError:
                return n
            except usb.core.USBError as exc:
                raise usb_error(exc, "draining the data endpoint") from exc
            if got == 0:
                return n
            n += got
        return n

    def run(self) -> None:
        if self.transfers is not None:
            self._run_queued()
        else:
            self._run_sync()

    @property
    def n_idle_risks(self) -> int:
        """See the class's attributes."""
        return self._sync_risks + (self._ledger.n_risks if self._ledger is not None else 0)

    def _arrived(self, t_s: float) -> None:
        """(Synchronous reads) note a read with data returned at clock time ``t_s`` (after
        :meth:`_hand_over`): the stream's recent rate, for :meth:`_space_ran_out`."""
        recent = self._recent
        recent.append((t_s, self.bytes_read))
        while len(recent) > 2 and recent[1][0] < t_s - RATE_WINDOW_S:
            recent.popleft()

    def _space_ran_out(self, t_from_s: float, t_to_s: float) -> None:
        """(Synchronous reads) no request was on the endpoint from ``t_from_s`` to ``t_to_s``
        (clock s): count a possible loss if, at :data:`RATE_MARGIN` times the stream's recent rate
        (at most :data:`LINK_MAX_BYTES_S`), the device could have filled its buffer meanwhile
        (one count per run of such spells)."""
        recent = self._recent
        if self.device_buffer_bytes is None or len(recent) < 2:
            return
        (t0, b0), (t1, b1) = recent[0], recent[-1]
        rate_bytes_s = min(RATE_MARGIN * (b1 - b0) / (t1 - t0), LINK_MAX_BYTES_S) if t1 > t0 else 0.0
        risky = rate_bytes_s * (t_to_s - t_from_s) > self.device_buffer_bytes
        self._sync_risks += risky and not self._at_risk
        self._at_risk = risky

    def _hand_over(self, buf, n: int, *, by_reference: bool = True) -> bool:
        """Queue ``n`` bytes read into ``buf``; True if the queue now owns ``buf`` (the caller
        then needs another buffer). A result under half the buffer is copied out (so that a
        buffer lent to the queue always carries at least half its size); a long one in a buffer
        that may not be lent (``by_reference=False``), or a full queue, loses the bytes."""
        self.bytes_read += n
        if n == self.read_bytes:
            self.n_full_reads += 1
        if n * 2 < self.read_bytes:
            if self.queue.put(Chunk(memoryview(buf)[:n].tobytes(), n)):
                return False
        elif by_reference and self.queue.put(Chunk(buf, n)):
            return True
        self.dropped_bytes += n
        self.n_overflows += 1
        self.queue.put_gap(n)
        return False

    def _run_queued(self) -> None:
        q, queue, eos, clock = self.transfers, self.queue, self._eos, time.perf_counter
        where = f"reading the data endpoint of {self.camera_name}"
        cancel_by = None  # clock time by which every cancelled request must be back
        try:
            for i in range(self.n_transfers):  # HAL: first timeouts staggered over one period
                buf = self._buffer()
                try:
                    q.submit(buf, self.timeout_ms + i * self.timeout_ms // self.n_transfers)
                except usb.core.USBError as exc:
                    self._free.append(buf)
                    if i and exc.errno == errno.ENOMEM:
                        log.warning("%s: only %d of %d USB requests could be queued (%s; Linux shares 16 MiB "
                                    "of usbfs memory between all devices)", self.camera_name, i, self.n_transfers, exc)
                        self.n_transfers = i
                    else:  # (unplugged): stop, but reap what the requests already queued hold
                        self.error = usb_error(exc, where)
                        self._stop_event.set()
                    break
            ledger = self._ledger = None if self.device_buffer_bytes is None else _SpaceLedger(
                self.read_bytes, self.device_buffer_bytes, clock(), q.pending)
            while q.pending:
                if self._stop_event.is_set() and cancel_by is None:
                    q.cancel()
                    cancel_by = clock() + CANCEL_WAIT_S
                if cancel_by is not None and clock() > cancel_by:
                    raise EvkError(f"{q.pending} USB requests of {self.camera_name} still pending "
                                   f"{CANCEL_WAIT_S:.0f} s after they were cancelled")
                try:
                    # a request incomplete when reap returns was incomplete when it was called: the
                    # requests are counted as of then (this thread may wait for the GIL in between)
                    t_call = clock()
                    done: Done | None = q.reap(0)
                    if done is None:  # the oldest is incomplete
                        if ledger is not None and cancel_by is None:
                            ledger.counted(t_call, q.incomplete)
                        t_call = clock()
                        done = q.reap(0.05)
                except usb.core.USBError as exc:  # no more completions can be had
                    if self.error is None:
                        self.error = usb_error(exc, where)
                    break
                if done is None:
                    continue
                buf, n, status = done
                t_done = clock()
                if n or status == "completed":
                    self.n_reads += 1
                if ledger is not None and cancel_by is None:
                    ledger.counted(t_call, q.incomplete)
                spare = buf
                if n:  # whatever the status, the first n bytes arrived (libusb): keep them
                    spare = self._buffer()
                    if spare is None:  # every pooled buffer is queued: keep buf for the next request
                        self._hand_over(buf, n, by_reference=False)
                        spare = buf
                    elif not self._hand_over(buf, n):
                        self._free.append(spare)
                        spare = buf
                if status == "timed_out" and not n:
                    self.n_timeouts += 1
                    if eos is not None and eos():
                        self.end_of_stream = True
                        self._stop_event.set()
                elif status not in ("completed", "timed_out") and not (cancel_by is not None and status == "cancelled"):
                    if self.error is None:
                        self.error = usb_error(_status_error(status), where)
                    self._stop_event.set()
                if not self._stop_event.is_set():
                    try:
                        q.submit(spare, self.timeout_ms)
                    except usb.core.USBError as exc:  # (unplugged): stop, but reap what is in hand
                        if self.error is None:
                            self.error = usb_error(exc, where)
                        self._stop_event.set()
                        self._free.append(spare)
                        continue
                    t_submitted = clock()
                    gap = t_submitted - t_done
                    self.gap_s += gap
                    self.max_gap_s = max(self.max_gap_s, gap)
                    if ledger is not None:
                        ledger.submitted(t_submitted)
                else:
                    self._free.append(spare)
        except usb.core.USBError as exc:
            if self.error is None:
                self.error = usb_error(exc, where)
        except EvkError as exc:
            if self.error is None:
                self.error = exc
        except Exception as exc:  # noqa: BLE001 - reported to the consumer, never lost
            self.error = EvkError(f"reader thread of {self.camera_name} failed: {exc!r}")
        finally:
            try:
                q.close()
            except Exception as exc:  # noqa: BLE001 - requests still pending: never free their memory
                _ABANDONED.append(q)
                self.abandoned = True
                if self.error is None:
                    self.error = EvkError(f"closing the USB requests of {self.camera_name} failed: {exc!r}")
            queue.close()

    def _run_sync(self) -> None:
        read, ep, timeout, size = self.dev.read, self.ep, self.timeout_ms, self.read_bytes
        queue, eos, clock = self.queue, self._eos, time.perf_counter
        scratch = array.array("B", bytes(size))  # used only when every pooled buffer is queued
        t_done = None  # the last read's return, and the earliest it can have completed
        t_free = None
        try:
            buf = None
            while not self._stop_event.is_set():
                if buf is None:
                    buf = self._buffer()
                target = buf if buf is not None else scratch
                t_call = clock()
                if t_done is not None:
                    self.gap_s += t_call - t_done
                    self.max_gap_s = max(self.max_gap_s, t_call - t_done)
                    # no request on the endpoint since the last one completed: when that was is
                    # unknown (its thread may have waited for the GIL), at the earliest t_free
                    self._space_ran_out(t_free, t_call)
                try:
                    n = read(ep, target, timeout)
                except usb.core.USBTimeoutError:
                    t_done = None
                    self.n_timeouts += 1
                    if eos is not None and eos():
                        self.end_of_stream = True
                        break
                    continue
                except usb.core.USBError as exc:
                    self.error = usb_error(exc, f"reading the data endpoint of {self.camera_name}")
                    break
                t_done = clock()
                t_free = t_call + n / LINK_MAX_BYTES_S
                self.n_reads += 1
                if not n:
                    continue
                if buf is None:  # read into the scratch buffer: every pooled one is queued
                    self._hand_over(scratch, n, by_reference=False)
                elif self._hand_over(buf, n):
                    buf = None  # now owned by the queue; take another from the pool
                self._arrived(t_done)
        except Exception as exc:  # noqa: BLE001 - reported to the consumer, never lost
            self.error = EvkError(f"reader thread of {self.camera_name} failed: {exc!r}")
        finally:
            queue.close()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Ask the thread to end after its current read and wait for it."""
        self._stop_event.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)


def _status_error(status: str) -> usb.core.USBError:
    """The pyusb error matching a failed transfer's libusb status."""
    code = {"stall": errno.EPIPE, "no_device": errno.ENODEV}.get(status, errno.EIO)
    return usb.core.USBError(f"bulk transfer ended with status {status}", None, code)


class _SpaceLedger:
    """Whether queued requests may have left the device without space for longer than its buffer
    covers, from what the reader can see (not when a request completed: the reaping thread may wait
    for the GIL).

    The requests are counted as of just before each reap (one incomplete after the reap was
    incomplete before it). Where one submitted before the previous count is still incomplete, the
    endpoint had space all along and the ledger starts afresh. Otherwise the run of such counts goes
    on, and so does the bound: from its start the device may have produced at the link's top speed
    (:data:`LINK_MAX_BYTES_S`, the rate being unknown) into the space it had then (the oldest
    incomplete request taken as full) and the requests submitted since, each from its submission
    on; beyond its buffer, it may have lost data.

    Attributes
    ----------
    n_risks : int
        Runs in which the bound exceeded the buffer.
    """

    def __init__(self, read_bytes: int, buffer_bytes: int, t_s: float, n_incomplete: int):
        self.read_bytes, self.buffer_bytes = read_bytes, buffer_bytes
        self.n_risks = 0
        self._at_risk = False
        self._restart(t_s, n_incomplete)

    def _restart(self, t_s: float, n_incomplete: int) -> None:
        self._t0, self._space = t_s, max(n_incomplete - 1, 0) * self.read_bytes
        self._excess, self._fresh = -math.inf, 0

    def submitted(self, t_s: float) -> None:
        """A request was submitted at ``t_s`` (clock s)."""
        self._excess = max(self._excess, LINK_MAX_BYTES_S * (t_s - self._t0) - self._space)
        self._space += self.read_bytes
        self._fresh += 1

    def counted(self, t_s: float, n_incomplete: int) -> None:
        """``n_incomplete`` requests were incomplete at ``t_s`` (clock s)."""
        if n_incomplete > self._fresh:
            self._restart(t_s, n_incomplete)
            self._at_risk = False
            return
        self._fresh = 0
        excess = max(self._excess, LINK_MAX_BYTES_S * (t_s - self._t0) - self._space)
        if excess > self.buffer_bytes and not self._at_risk:
            self.n_risks += 1
            self._at_risk = True


class TimeHighMonitor:
    """Detects EVT3 time-base discontinuities: consecutive TIME_HIGH words must step by 0 or
    1 (mod 4096, so the 24-bit wrap is fine); any other step means lost data (or an idle
    sensor that emitted no TIME_HIGH, [uncertain] on real hardware).

    Attributes
    ----------
    jumps : int
        Discontinuities seen.
    jump_offsets : list of int
        Payload byte offsets (of the chunk) where the first 100 jumps were seen.
    last_time_high : int or None
        Last TIME_HIGH value (t >> 12, 12 bits).
    """

    def __init__(self):
        self.jumps = 0
        self.jump_offsets: list[int] = []
        self.last_time_high: int | None = None
        self._odd = b""
        self._offset = 0

    def reset(self) -> None:
        """Forget the time base (after a known gap, which is counted separately)."""
        self.last_time_high = None

    def feed(self, chunk: bytes) -> None:
        """Scan ``chunk`` (payload bytes, any length) for TIME_HIGH steps."""
        data = self._odd + chunk if self._odd else chunk
        n = len(data) // 2
        self._odd = bytes(data[2 * n:])
        w = np.frombuffer(data, dtype="<u2", count=n)
        th = w[(w >> 12) == 0x8] & 0xFFF
        if th.size:
            if self.last_time_high is not None:
                steps = np.diff(th, prepend=np.uint16(self.last_time_high)).astype(np.int32) % 4096
            else:
                steps = np.diff(th).astype(np.int32) % 4096
            bad = int(np.count_nonzero(steps > 1))
            if bad:
                self.jumps += bad
                if len(self.jump_offsets) < 100:
                    self.jump_offsets.append(self._offset)
            self.last_time_high = int(th[-1])
        self._offset += len(chunk)

