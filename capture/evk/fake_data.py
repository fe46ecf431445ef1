"""The fake EVK's data side: the sensor producing bytes, a finite device FIFO, the USB link and
the host's pending bulk-IN requests.

Real hardware keeps running while Python does not: the sensor produces events, the device
buffers them, and the host controller fills every request the driver has queued, GIL or no
GIL. This model is therefore lazy and keyed to wall-clock time: each call from the driver
first brings the device up to *now*, with the set of requests that was pending since the
previous call (only the driver's own calls change that set), in steps that end at each
request's deadline. In each step (within it, arrivals are counted before deliveries):

1. the sensor adds the bytes its stream produced meanwhile (``pace="recorded"``: the RAW
   file's TIME_HIGH words set when each byte exists, linearly between two of them;
   ``pace="max"``: everything exists from the start);
2. the link moves bytes from the FIFO into the pending requests, oldest first, at most
   ``link_bytes_s`` × the time elapsed; a request completes when full, at a device packet
   that ends in a short USB packet, or when its timeout passes (with whatever it holds);
3. whatever the FIFO cannot hold (``fifo_bytes``) is lost: the newest bytes, and then
   everything up to the next TIME_HIGH word, so that the stream resumes on a time base
   (what the host sees is a TIME_HIGH discontinuity once a whole 4096 µs period is gone).

Faults (stall, unplug, pause after N bytes served) act at exact byte counts.
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path

import numpy as np

from capture import raw
from capture.events import EVENT_DTYPE

USB3_LINK_BYTES_S = 350e6
"""Sustained bulk-IN throughput of a SuperSpeed link through the EVK4's Cypress bridge, bytes/s
[uncertain: ~350–400 MB/s is what FX3/CX3 designs report; no EVK figure is published]."""

USB2_LINK_BYTES_S = 40e6
"""Sustained bulk-IN throughput of a High-Speed (USB 2) link, bytes/s (480 Mb/s raw)."""

EVK_FIFO_BYTES = 256 << 10
"""Device-side buffer between sensor and USB, bytes [uncertain: the FX3/CX3 bridge has 512 KiB
of SRAM shared with its firmware; its DMA buffers are a few hundred KiB]."""

STALL, GONE = "stall", "no_device"


def time_high_marks(payload: bytes, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    """(byte offsets, stream times in µs from the first) of the payload's TIME_HIGH words, the
    times unwrapped; repeated values keep their first word. A last mark at the payload's end,
    one TIME_HIGH period after the last word, paces the bytes that follow it."""
    if fmt == "EVT3":
        w = np.frombuffer(payload[: len(payload) // 2 * 2], dtype="<u2")
        pos = np.flatnonzero((w >> 12) == 0x8)
        th = (w[pos] & 0xFFF).astype(np.int64)
        loops = np.cumsum(np.diff(th, prepend=th[:1]) <= -2048)
        t, word = (th + loops * 4096) << 12, 2
    else:  # EVT2: u32 words; EVT2.1 legacy: u64 words whose low u32 holds the type
        word = 4 if fmt == "EVT2" else 8
        w = np.frombuffer(payload[: len(payload) // word * word], dtype="<u4")
        w = w if fmt == "EVT2" else w[0::2]
        pos = np.flatnonzero((w >> 28) == 0x8)
        t = (w[pos] & 0x0FFFFFFF).astype(np.int64) << 6
    if t.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    keep = np.concatenate([[True], np.diff(t) != 0])
    off, t = pos[keep] * word, t[keep] - t[0]
    # the bytes after the last TIME_HIGH take one more period, as the ones before did
    step = int(np.median(np.diff(t))) if len(t) > 1 else (4096 if fmt == "EVT3" else 64)
    return np.append(off, len(payload) - len(payload) % word), np.append(t, t[-1] + step)


def synthetic_stream(path, rates_ev_s, *, width: int = 1280, height: int = 720,
                     block_periods: int = 8, seed: int = 0) -> int:
    """Write an EVT3 RAW file for the fake: one block of ``block_periods`` TIME_HIGH periods
    (4096 µs each) per entry of ``rates_ev_s`` (events/s), in that order, with a continuous
    time base; alternate rates make a bursty scene. Half the events come in runs of 8 along
    a row (moving edges, which EVT3 packs into vectors), half alone: about 3 bytes/event.
    Each distinct rate is encoded once and its block repeated with TIME_HIGH advanced.

    Returns
    -------
    int
        Events written.
    """
    span_us, run = block_periods * 4096, 8
    blocks: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    rng = np.random.default_rng(seed)
    n_total = 0
    with Path(path).open("wb") as f:
        f.write(raw.header_bytes("EVT3", width=width, height=height))
        for k, rate in enumerate(rates_ev_s):
            if rate not in blocks:
                n = int(rate * span_us / 1e6)
                n_runs = n // (2 * run)
                n_iso = n - n_runs * run
                ev = np.empty(n, EVENT_DTYPE)
                t_runs = rng.integers(0, span_us, n_runs)
                x0 = rng.integers(0, width - run, n_runs)
                ev["t"] = np.concatenate([np.repeat(t_runs, run), rng.integers(0, span_us, n_iso)])
                ev["x"] = np.concatenate([(x0[:, None] + np.arange(run)).ravel(), rng.integers(0, width, n_iso)])
                ev["y"] = np.concatenate([np.repeat(rng.integers(0, height, n_runs), run),
                                          rng.integers(0, height, n_iso)])
                ev["p"] = rng.integers(0, 2, n)
                ev = ev[np.argsort(ev["t"], kind="stable")]
                ev["t"] += 4096 * 256  # start on a TIME_HIGH boundary
                words = np.frombuffer(raw.encode(ev, width=width, height=height), "<u2").copy()
                blocks[rate] = (words, (words >> 12) == 0x8)
            words, is_th = blocks[rate]
            w = words.copy()
            w[is_th] = 0x8000 | ((w[is_th] & 0xFFF) + k * block_periods) % 4096
            f.write(w.tobytes())
            n_total += int(rate * span_us / 1e6)
    return n_total


class Request:
    """A pending bulk-IN request: ``got`` bytes written into ``out`` so far; ``status`` is
    ``None`` until it completes."""

    __slots__ = ("out", "size", "got", "deadline", "status")

    def __init__(self, out: memoryview, deadline: float):
        self.out, self.size, self.got, self.deadline, self.status = out, len(out), 0, deadline, None


class DataSide:
    """Sensor, FIFO and link of one fake EVK (see the module docstring).

    Parameters
    ----------
    payload : bytes
        Event words the sensor produces.
    fmt : str
        ``"EVT3"``, ``"EVT2"`` or ``"EVT21"``.
    packet_ends : ndarray of int
        Byte offsets where device packets end; ``short[i]`` marks one ending in a short USB
        packet (which completes the request it lands in).
    short : ndarray of bool
    pace : {"max", "recorded"}
    speed : float
        Playback speed for ``pace="recorded"``.
    fifo_bytes : int or None
        Device FIFO; ``None`` never drops.
    link_bytes_s : float or None
        USB throughput; ``None`` is unlimited.
    stall_at, gone_at : int or None
        Served-byte counts at which the endpoint stalls / the device vanishes.
    pause : (int, float) or None
        After that many bytes served, the link is silent for that many seconds.
    """

    def __init__(self, payload: bytes, fmt: str, packet_ends: np.ndarray, short: np.ndarray, *,
                 pace: str, speed: float, fifo_bytes: int | None, link_bytes_s: float | None,
                 stall_at: int | None, gone_at: int | None, pause: tuple[int, float] | None):
        if pace == "max" and fifo_bytes is not None:
            raise ValueError("a finite FIFO needs pace='recorded' (at pace 'max' the whole file exists at once)")
        self.payload = payload
        self.word = 2 if fmt == "EVT3" else 4 if fmt == "EVT2" else 8
        self._ends, self._short = packet_ends, short
        self.pace, self.speed = pace, float(speed)
        self.fifo_bytes, self.link_bytes_s = fifo_bytes, link_bytes_s
        self._th_off, th_t = time_high_marks(payload, fmt) if payload else (np.zeros(0, np.int64),) * 2
        self._th_s = th_t / 1e6 / self.speed
        self._stall_at, self._gone_at, self._pause = stall_at, gone_at, pause
        self._pause_until: float | None = None
        self.stalled = self.gone = False
        self.served = 0  # bytes delivered to the host
        self.served_ranges: list[list[int]] = []  # [start, end) payload ranges delivered, in order
        self.dropped_bytes = 0  # bytes the FIFO could not hold
        self.produced = 0  # payload offset the sensor has reached
        self._fifo: deque = deque()  # [start, end) payload ranges waiting in the device
        self._level = 0
        self._drop_until = 0  # arrivals before this payload offset are lost (resync)
        self._t0: float | None = None  # wall time of stream time 0 while running
        self._t_last: float | None = None
        self._credit = 0.0  # link bytes allowed but not yet used (fractions)
        self.requests: deque[Request] = deque()

    # ---- public -----------------------------------------------------------------------
    @property
    def exhausted(self) -> bool:
        """Every byte has been produced and served or lost."""
        return self.produced >= len(self.payload) and self._level == 0

    def submit(self, out: memoryview, timeout_ms: int, now: float, running: bool) -> Request:
        self.advance(now, running)
        req = Request(out, now + (timeout_ms / 1000 if timeout_ms else 3600.0))
        if self.gone or self.stalled:
            req.status = GONE if self.gone else STALL
        self.requests.append(req)
        return req

    def advance(self, now: float, running: bool) -> None:
        """Bring the device up to wall time ``now`` (seconds, ``time.monotonic``): step to each
        pending request's deadline in turn, so that none gets bytes produced after it."""
        while True:
            due = [r.deadline for r in self.requests if r.status is None and r.deadline <= now]
            t = min(due) if due else now
            self._step(t, running)
            for req in self.requests:
                if req.status is None and req.deadline <= t:
                    req.status = "timed_out"
            if t >= now:
                break
        if self.gone or self.stalled:
            for req in self.requests:
                if req.status is None:
                    req.status = GONE if self.gone else STALL

    def _step(self, now: float, running: bool) -> None:
        dt = 0.0 if self._t_last is None else max(now - self._t_last, 0.0)
        self._t_last = now if self._t_last is None else max(now, self._t_last)
        if running:
            if self._t0 is None:
                self._t0 = now - self._stream_time(self.produced)
            end = self._produced_end(now)
            if end > self.produced:
                self._arrive(self.produced, end)
                self.produced = end
        else:
            self._t0 = None
        self._deliver(now, dt)
        if self.fifo_bytes is not None and self._level > self.fifo_bytes:
            self._overflow(self._level - self.fifo_bytes)

    def next_wake(self, now: float) -> float:
        """Seconds until something can change for a waiting request (at most 2 ms)."""
        wake = 0.002
        if self.pace == "recorded" and self._t0 is not None and self.produced < len(self.payload):
            k = int(np.searchsorted(self._th_off, self.produced, side="right"))
            if k < len(self._th_s):
                wake = min(wake, max(self._t0 + self._th_s[k] - now, 0.0002))
        return wake

    # ---- sensor -----------------------------------------------------------------------
    def _stream_time(self, offset: int) -> float:
        if self.pace == "max" or not len(self._th_s):
            return 0.0
        return float(np.interp(offset, self._th_off, self._th_s))

    def _produced_end(self, now: float) -> int:
        if self.pace == "max" or len(self._th_s) < 2:
            return len(self.payload)
        t = now - self._t0
        if t >= self._th_s[-1]:
            return len(self.payload)
        end = int(np.interp(t, self._th_s, self._th_off))
        return end - end % self.word

    def _arrive(self, start: int, end: int) -> None:
        if start < self._drop_until:
            lost = min(end, self._drop_until) - start
            self.dropped_bytes += lost
            start += lost
        if start >= end:
            return
        if self._fifo and self._fifo[-1][1] == start:
            self._fifo[-1][1] = end
        else:
            self._fifo.append([start, end])
        self._level += end - start

    def _overflow(self, excess: int) -> None:
        """Lose the newest ``excess`` bytes (rounded up to a word), then up to the next
        TIME_HIGH word."""
        excess = -(-excess // self.word) * self.word
        while excess > 0 and self._fifo:
            rng = self._fifo[-1]
            n = min(excess, rng[1] - rng[0])
            rng[1] -= n
            excess -= n
            self._level -= n
            self.dropped_bytes += n
            if rng[1] == rng[0]:
                self._fifo.pop()
        k = int(np.searchsorted(self._th_off, self.produced, side="left"))
        self._drop_until = int(self._th_off[k]) if k < len(self._th_off) else len(self.payload)

    # ---- link -------------------------------------------------------------------------
    def _deliver(self, now: float, dt: float) -> None:
        if self.link_bytes_s is None:
            budget = float("inf")
        else:
            budget = self._credit + self.link_bytes_s * dt
        if self._pause_until is not None:
            if now < self._pause_until:
                self._credit = 0.0
                return
            self._pause_until = None
        if self._fault(now):  # a fault at the count already served (e.g. at byte 0)
            self._credit = 0.0
            return
        ends, short, payload = self._ends, self._short, self.payload
        pending = [r for r in self.requests if r.status is None]
        i = 0
        while budget >= 1 and self._fifo and i < len(pending):  # (a fault breaks out)
            req = pending[i]
            rng = self._fifo[0]
            s = rng[0]
            n = int(min(rng[1] - s, req.size - req.got, budget))
            k = int(np.searchsorted(ends, s, side="right"))
            if k < len(ends):
                n = min(n, int(ends[k]) - s)
            for at in (self._stall_at, self._gone_at, self._pause[0] if self._pause else None):
                if at is not None:
                    n = min(n, at - self.served)
            req.out[req.got:req.got + n] = payload[s:s + n]
            if self.served_ranges and self.served_ranges[-1][1] == s:
                self.served_ranges[-1][1] = s + n
            else:
                self.served_ranges.append([s, s + n])
            req.got += n
            rng[0] += n
            self._level -= n
            self.served += n
            budget -= n
            if rng[0] == rng[1]:
                self._fifo.popleft()
            if req.got == req.size or (k < len(ends) and s + n == ends[k] and short[k]):
                req.status = "completed"
                i += 1
            if self._fault(now):
                if req.status is None and req.got:
                    req.status = "completed"
                break
        self._credit = min(budget, float(self.link_bytes_s or 0) * 0.001) if budget != float("inf") else 0.0

    def _fault(self, now: float) -> bool:
        """Apply a fault reached at the current served count; True if delivery must stop (for
        a pause, while it lasts)."""
        if self._gone_at is not None and self.served >= self._gone_at:
            self._gone_at, self.gone = None, True
            return True
        if self._stall_at is not None and self.served >= self._stall_at:
            self._stall_at, self.stalled = None, True
            return True
        if self._pause is not None and self.served >= self._pause[0]:
            self._pause_until = now + self._pause[1]
            self._pause = None
            return True
        return self.stalled or self.gone


def wait_for(side: DataSide, req: Request, running, lock, deadline: float | None = None) -> bool:
    """Block (releasing the GIL, as a thread inside libusb) until ``req`` completes, or until
    ``deadline`` (``time.monotonic`` seconds) passes; True if it completed."""
    while True:
        with lock:
            now = time.monotonic()
            side.advance(now, running())
            if req.status is not None:
                return True
            wake = side.next_wake(now)
        if deadline is not None:
            if now >= deadline:
                return False
            wake = min(wake, max(deadline - now, 0.0))
        time.sleep(wake)
