"""Live-capture throughput through the fake EVK (run on demand; prints numbers, asserts nothing).

    PYTHONPATH=. python bench/evk_bench.py [--mev 60] [--rate-mev-s 100]

Measures, on this machine, with a synthetic EVT3 stream (half the events in short horizontal
runs as from moving edges, half isolated; about 3 bytes/event):

1. pyusb's one-pending-read cost: the pyusb Python layer's time per ``dev.read`` call, and
   reader throughput versus read size, for large device packets and for short packets (one
   host read per device packet, as with the EVK4's ~7 KiB transfers in the shared recording);
2. raw recording (``capture.evk.record`` with no decoding) to disk: the writer's drain rate
   with the fake at max pace (peer: writing the same bytes from memory to disk), then drops,
   queue peak and CPU with the fake releasing data in real time at 1x, 2x, 4x the rate;
3. raw + live decoding into the session store, fed in real time (``pace="recorded"``): whether
   decoding keeps up, how far behind it gets (queue peak) and when it has caught up;
4. decoding the RAW file into a session after the recording (catch-up path);
5. loss on a finite device FIFO (``FakeEVK(fifo_bytes=, link_bytes_s=)``): a bursty scene
   (32.8 ms blocks alternating 1 and 100 Mev/s) over USB3 and a steady stream at the USB2
   limit, consumed by the live path of ``capture.run`` (decode, session store, live tracking
   and spin) or by a consumer that holds the GIL 12 ms per batch; bytes the device lost with
   one synchronous read at a time (the old path), 20 queued requests (the HAL's count) and the
   default; whether the RAW file is byte-identical to what the device sent; then the highest
   burst rate the default sustains with no loss (``--loss-only`` runs only this part).

CPU times are process CPU (all threads, the fake's emulation included).
"""

from __future__ import annotations

import argparse
import random
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import usb.core

from capture import evk, raw
from capture.evk.fake import EP_DATA, FakeEVK
from capture.evk.fake_data import (
    EVK_FIFO_BYTES,
    USB2_LINK_BYTES_S,
    USB3_LINK_BYTES_S,
    synthetic_stream,
)
from capture.pipeline.live import LiveAnalysis
from capture.evk.stream import Chunk
from capture.session import create_session

WIDTH, HEIGHT = 1280, 720
BLOCK_S = 8 * 4096e-6  # one synthetic block: 8 TIME_HIGH periods (32.8 ms)


def synth_stream(path: Path, n_mev: float, rate_ev_s: float) -> int:
    """A RAW file of ~n_mev Mev at a steady ``rate_ev_s``; returns the number of events."""
    reps = max(1, int(np.ceil(n_mev * 1e6 / (rate_ev_s * BLOCK_S))))
    return synthetic_stream(path, [rate_ev_s] * reps, width=WIDTH, height=HEIGHT)


def pyusb_call_overhead_us(n: int = 20000) -> float:
    """µs per ``dev.read`` spent in pyusb's Python layer (backend answers instantly)."""

    class Instant(FakeEVK):
        def bulk_read(self, dev_handle, ep, intf, buff, timeout):
            return len(buff) if ep == EP_DATA else super().bulk_read(dev_handle, ep, intf, buff, timeout)

    dev = usb.core.find(backend=Instant(None))
    import array

    buf = array.array("B", bytes(1 << 20))
    dev.read(EP_DATA, buf, 100)
    t = time.perf_counter()
    for _ in range(n):
        dev.read(EP_DATA, buf, 100)
    return (time.perf_counter() - t) / n * 1e6


def reader_throughput(src: Path, read_bytes: int, packet_bytes) -> tuple[float, float]:
    """(MB/s, µs per read) of the reader thread alone (consumer discards), fake at max pace."""
    fake = FakeEVK(src, packet_bytes=packet_bytes)
    with evk.open(backend=fake) as cam:
        cam.read_bytes = read_bytes
        cam.n_transfers = 1  # the one-read path this part measures
        cam.queue_bytes = 1 << 34
        t = time.perf_counter()
        cam.start()
        q = cam.reader.queue
        n = 0
        while (item := q.get(0.05)) is not q.EOF:
            if isinstance(item, Chunk):
                n += item.nbytes
                cam.reader.release(item)
        dt = time.perf_counter() - t - 0.1  # the final read waits one 100 ms timeout
        reads = cam.reader.n_reads
        cam.stop()
    return n / dt / 1e6, dt / max(reads, 1) * 1e6


def disk_peer(payload: bytes, out: Path) -> float:
    """MB/s writing the same bytes from memory in 1 MiB chunks (the recorder's disk ceiling)."""
    t = time.perf_counter()
    with out.open("wb", buffering=0) as f:
        for i in range(0, len(payload), 1 << 20):
            f.write(payload[i:i + (1 << 20)])
    return len(payload) / (time.perf_counter() - t) / 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mev", type=float, default=60.0, help="stream size, millions of events")
    ap.add_argument("--rate-mev-s", type=float, default=100.0, help="stream's event rate (Mev/s)")
    ap.add_argument("--dir", default=None, help="scratch directory (default: a temp dir)")
    ap.add_argument("--loss-only", action="store_true", help="run only part 5 (finite-FIFO loss)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        tmp = Path(tmp)
        if args.loss_only:
            loss(tmp)
            return
        src = tmp / "stream.raw"
        n_ev = synth_stream(src, args.mev, args.rate_mev_s * 1e6)
        payload = src.read_bytes()
        _, hdr = raw.parse_header(payload)
        payload = payload[hdr:]
        mev = n_ev / 1e6
        print(f"stream: {mev:.1f} Mev, {len(payload) / 1e6:.0f} MB, {len(payload) / n_ev:.2f} B/ev, "
              f"{args.rate_mev_s:.0f} Mev/s sensor rate ({len(payload) / n_ev * args.rate_mev_s:.0f} MB/s)")

        print("\n1. pyusb one-pending-read cost")
        print(f"  pyusb Python layer per dev.read: {pyusb_call_overhead_us():.1f} us")
        for rb in (16 << 10, 128 << 10, 1 << 20, 4 << 20):
            mbs, us = reader_throughput(src, rb, 131072)
            print(f"  128 KiB device packets, read {rb >> 10:5d} KiB: {mbs:7.0f} MB/s  ({us:6.1f} us/read)")
        mbs, us = reader_throughput(src, 1 << 20, 7340)
        print(f"  ~7 KiB short device packets, read 1024 KiB: {mbs:7.0f} MB/s  ({us:6.1f} us/read; "
              f"one read per device packet)")

        print("\n2. raw recording -> disk (no decoding)")
        peer = disk_peer(payload, tmp / "peer.raw")
        (tmp / "peer.raw").unlink()
        with evk.open(backend=FakeEVK(src, packet_bytes=131072)) as cam:
            cam.queue_bytes = 2 * len(payload)  # measure the writer's drain rate, not drops
            st = evk.record(cam, tmp / "rec.raw")
        dur = st.stream_s - 0.1  # minus the final 100 ms end-of-stream timeout
        print(f"  fake at max pace: {mev / dur:7.1f} Mev/s  {st.payload_bytes / dur / 1e6:6.0f} MB/s  "
              f"CPU {st.cpu_s / mev * 1e3:.1f} ms/Mev  queue peak {st.queue_peak_bytes / 1e6:.0f} MB")
        print(f"  peer (same bytes memory -> disk): {peer:.0f} MB/s; recorder/peer = "
              f"{st.payload_bytes / dur / 1e6 / peer:.2f}")
        assert (tmp / "rec.raw").stat().st_size == st.header_bytes + len(payload)
        for speed in (1.0, 2.0, 4.0):
            with evk.open(backend=FakeEVK(src, packet_bytes=131072, pace="recorded", speed=speed)) as cam:
                st = evk.record(cam, tmp / "rec_paced.raw")  # default 256 MiB queue
            secs = st.stream_s - 0.1  # minus the final 100 ms end-of-stream timeout
            print(f"  fed at {args.rate_mev_s * speed:4.0f} Mev/s (achieved {mev / secs:4.0f} Mev/s, "
                  f"{st.payload_bytes / secs / 1e6:4.0f} MB/s): dropped {st.dropped_bytes} B, time jumps {st.time_jumps}, queue peak "
                  f"{st.queue_peak_bytes / 1e6:.1f} MB, CPU {st.cpu_s / mev * 1e3:.1f} ms/Mev, "
                  f"gap between reads {st.read_gap_us:.0f} us (max {st.max_read_gap_us / 1e3:.1f} ms), "
                  f"full reads {st.n_full_reads}/{st.n_reads}")
        (tmp / "rec_paced.raw").unlink()

        print(f"\n3. raw + live decode into the session store, fed in real time ({args.rate_mev_s:.0f} Mev/s)")
        stream_s = len(payload) / (len(payload) / n_ev * args.rate_mev_s * 1e6)
        with evk.open(backend=FakeEVK(src, packet_bytes=131072, pace="recorded")) as cam:
            cam.queue_bytes = 1 << 31
            with create_session(tmp / "live.zarr", width=WIDTH, height=HEIGHT) as sess:
                st = evk.record(cam, tmp / "rec2.raw", on_batch=lambda e, t: sess.append_events(e))
        print(f"  stream lasted {stream_s:.2f} s; all raw bytes on disk after {st.stream_s:.2f} s; "
              f"decoding caught up after {st.duration_s:.2f} s "
              f"-> decode+store {mev / st.duration_s:.1f} Mev/s, CPU {st.cpu_s / mev * 1e3:.1f} ms/Mev; "
              f"queue peak {st.queue_peak_bytes / 1e6:.0f} MB; dropped {st.dropped_bytes} B; "
              f"events {st.n_events / 1e6:.1f} M; gap between reads {st.read_gap_us:.0f} us "
              f"(max {st.max_read_gap_us / 1e3:.1f} ms)")
        print("\n4. catch-up: decode the recorded RAW (alone, then into a session) afterwards")
        t, c = time.perf_counter(), time.process_time()
        n = sum(len(events) for events, _ in raw.iter_chunks(tmp / "rec.raw", chunk_bytes=8 << 20))
        dt, dc = time.perf_counter() - t, time.process_time() - c
        print(f"  decode only: {n / 1e6 / dt:.1f} Mev/s, CPU {dc / (n / 1e6) * 1e3:.1f} ms/Mev")
        t, c = time.perf_counter(), time.process_time()
        with create_session(tmp / "after.zarr", width=WIDTH, height=HEIGHT) as sess:
            n = 0
            for events, _ in raw.iter_chunks(tmp / "rec.raw", chunk_bytes=8 << 20):
                sess.append_events(events)
                n += len(events)
        dt, dc = time.perf_counter() - t, time.process_time() - c
        print(f"  decode + session store: {n / 1e6 / dt:.1f} Mev/s, CPU {dc / (n / 1e6) * 1e3:.1f} ms/Mev "
              f"({n / 1e6:.1f} Mev)")

        loss(tmp)


def _gil_holder(ms: float):
    """on_batch that holds the GIL in one C call of about ``ms`` per batch (``sorted``)."""
    values = [random.random() for _ in range(20000)]
    t = time.perf_counter()
    sorted(values)
    values = values * max(1, int(ms / 1e3 / (time.perf_counter() - t)))
    return lambda events, triggers: sorted(values)


def _record_fifo(src: Path, out: Path, *, n_transfers: int, link_bytes_s: float, consumer: str,
                 n_events: int, speed: float = 1.0) -> dict:
    """One recording through the finite-FIFO fake of a stream of ``n_events``; the device's and
    the host's loss figures, and process CPU per Mev streamed (the fake's emulation included)."""
    shutil.rmtree(out.with_suffix(".zarr"), ignore_errors=True)
    fake = FakeEVK(src, pace="recorded", speed=speed, fifo_bytes=EVK_FIFO_BYTES, link_bytes_s=link_bytes_s)
    with evk.open(backend=fake) as cam:
        cam.n_transfers = n_transfers
        if consumer == "live":
            live = LiveAnalysis(WIDTH, HEIGHT)
            with create_session(out.with_suffix(".zarr"), width=WIDTH, height=HEIGHT) as sess:
                def on_batch(events, triggers):
                    sess.append_events(events)
                    live.offer(events)
                st = evk.record(cam, out, on_batch=on_batch)
            live.close()
        else:
            st = evk.record(cam, out, on_batch=_gil_holder(12.0))
    payload = out.read_bytes()[st.header_bytes:]
    return dict(lost=fake.dropped_bytes, sent=fake.bytes_served, jumps=st.time_jumps, host_drops=st.dropped_bytes,
                risks=st.idle_risks, lossless=st.lossless,
                identical=payload == fake.served_payload(), cpu_ms_mev=st.cpu_s * 1e3 / (n_events / 1e6),
                gap_ms=st.max_read_gap_us / 1e3)


def loss(tmp: Path) -> None:
    """Part 5: loss on a finite device FIFO, old path against queued requests."""
    bursty, usb2 = tmp / "bursty.raw", tmp / "usb2.raw"
    n_b = synthetic_stream(bursty, [1e6, 100e6] * 4, width=WIDTH, height=HEIGHT)
    b_bytes = bursty.stat().st_size
    n_u = synthetic_stream(usb2, [12e6] * 8, width=WIDTH, height=HEIGHT)
    u_rate = usb2.stat().st_size / (8 * BLOCK_S)
    print(f"\n5. loss on a finite device FIFO ({EVK_FIFO_BYTES >> 10} KiB): old one-read path vs queued requests")
    print(f"  bursty scene: {n_b / 1e6:.1f} Mev, {b_bytes / 1e6:.0f} MB, bursts of 100 Mev/s "
          f"({b_bytes / n_b * 100:.0f} MB/s) over USB3 ({USB3_LINK_BYTES_S / 1e6:.0f} MB/s); steady "
          f"{n_u / 1e6:.1f} Mev at 12 Mev/s ({u_rate / 1e6:.0f} MB/s) over USB2 ({USB2_LINK_BYTES_S / 1e6:.0f} MB/s)")
    print(f"  {'stream':8s} {'consumer':10s} {'requests':>8s} {'lost by device':>16s} {'host jumps':>10s} "
          f"{'idle risks':>10s} {'says lossless':>13s} {'file = sent':>11s} {'max gap':>8s} {'CPU ms/Mev':>10s}")
    for name, src, link, n_ev in (("bursty", bursty, USB3_LINK_BYTES_S, n_b), ("USB2", usb2, USB2_LINK_BYTES_S, n_u)):
        for consumer in ("live", "gil12ms"):
            for n in (1, 20, evk.Camera.n_transfers):
                r = _record_fifo(src, tmp / "loss.raw", n_transfers=n, link_bytes_s=link, consumer=consumer,
                                 n_events=n_ev)
                print(f"  {name:8s} {consumer:10s} {n:8d} {r['lost'] / 1e6:11.2f} MB "
                      f"({r['lost'] / (r['lost'] + r['sent']):4.0%}) {r['jumps']:10d} "
                      f"{r['risks']:10d} {str(r['lossless']):>13s} {str(r['identical']):>11s} "
                      f"{r['gap_ms']:6.1f}ms {r['cpu_ms_mev']:10.0f}")
    print(f"  highest burst rate with no loss, {evk.Camera.n_transfers} requests, live consumer:")
    for speed in (1.0, 1.05, 1.1):
        r = _record_fifo(bursty, tmp / "loss.raw", n_transfers=evk.Camera.n_transfers, link_bytes_s=USB3_LINK_BYTES_S,
                         consumer="live", n_events=n_b, speed=speed)
        print(f"    bursts at {100 * speed:5.0f} Mev/s ({b_bytes / n_b * 100 * speed:4.0f} MB/s): lost "
              f"{r['lost'] / 1e6:.2f} MB, says lossless {r['lossless']}, file = sent {r['identical']}")


if __name__ == "__main__":
    main()
