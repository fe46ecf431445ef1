"""Streaming real RAW recordings through the fake EVK: byte-identical RAW output, identical
decoded events, pacing, stop conditions, and faults (idle timeouts, stall, unplug, queue
overflow, lost data) with everything received before a fault kept on disk."""

import json
import threading

import numpy as np
import pytest

from capture import evk, raw
from capture.evk.fake import FakeEVK

ROS = "ros_codecs_evt3_trigger_1280x720.raw"
SAMPLE = "expelliarmus_evt3_sample_1280x720.raw"


def payload_of(path) -> bytes:
    data = open(path, "rb").read()
    _, size = raw.parse_header(data)
    return data[size:]


def record_fake(tmp_path, src, *, decode=True, camera_attrs=None, **fake_kw):
    fake = FakeEVK(src, **fake_kw)
    batches = []
    out = tmp_path / "rec.raw"
    with evk.open(backend=fake) as cam:
        for k, v in (camera_attrs or {}).items():
            setattr(cam, k, v)
        stats = evk.record(cam, out, on_batch=(lambda e, t: batches.append((e, t))) if decode else None)
    return fake, stats, out, batches


@pytest.fixture(scope="module")
def ros_chunks(shared_raw_dir):
    return json.loads((shared_raw_dir / "expected.json").read_text())["files"][ROS]["chunk_sizes_bytes"]


def test_recorded_packets_give_identical_bytes_and_events(tmp_path, shared_raw_dir, ros_chunks):
    src = shared_raw_dir / ROS
    fake, stats, out, batches = record_fake(tmp_path, src, packet_bytes=ros_chunks)
    assert payload_of(out) == payload_of(src)
    assert stats.payload_bytes == len(payload_of(src)) and stats.stop_reason == "end_of_stream"
    ref = raw.read(src)
    rec = raw.read(out)
    assert (rec.width, rec.height, rec.format) == (1280, 720, "EVT3")
    assert rec.header["fields"]["serial_number"] == "a1b2c3d4"
    live_events = np.concatenate([e for e, _ in batches])
    live_triggers = np.concatenate([t for _, t in batches])
    assert np.array_equal(rec.events, ref.events) and np.array_equal(live_events, ref.events)
    assert np.array_equal(live_triggers, ref.triggers) and len(ref.triggers) == 2
    assert stats.n_events == len(ref.events) == 82469
    assert stats.lossless and stats.dropped_bytes == 0 and stats.time_jumps == 0
    # Packets that are not a multiple of 1024 bytes end in a short USB packet: one per read.
    assert stats.n_reads == sum(1 for c in ros_chunks if c % 1024)


def test_large_fixed_packets_raw_only(tmp_path, shared_raw_dir):
    src = shared_raw_dir / SAMPLE
    _, stats, out, batches = record_fake(tmp_path, src, decode=False, packet_bytes=16384)
    assert payload_of(out) == payload_of(src) and not batches and stats.n_events == 0
    assert np.array_equal(raw.read(out).events, raw.read(src).events)
    assert stats.n_reads < len(payload_of(src)) // 16384  # 16 KiB packets end in full USB packets: reads merge them


def test_recorded_pace_follows_event_time(tmp_path, shared_raw_dir, ros_chunks):
    src = shared_raw_dir / ROS
    _, stats, out, _ = record_fake(tmp_path, src, decode=False, pace="recorded", speed=10.0,
                                   packet_bytes=ros_chunks)
    span_s = (15476187 - 14224870) / 1e6
    assert stats.duration_s >= 0.8 * span_s / 10.0
    assert payload_of(out) == payload_of(src)


def test_max_duration_and_stop_event_keep_a_decodable_prefix(tmp_path, shared_raw_dir, ros_chunks):
    src = shared_raw_dir / ROS
    ref = raw.read(src)
    with evk.open(backend=FakeEVK(src, pace="recorded", speed=1.0, packet_bytes=ros_chunks)) as cam:
        stats = evk.record(cam, tmp_path / "a.raw", max_duration_s=0.3)
    assert stats.stop_reason == "duration" and 0 < stats.payload_bytes < len(payload_of(src))
    assert payload_of(tmp_path / "a.raw") == payload_of(src)[: stats.payload_bytes]
    part = raw.read(tmp_path / "a.raw").events
    assert len(part) and np.array_equal(part, ref.events[: len(part)])

    stop = threading.Event()
    timer = threading.Timer(0.2, stop.set)
    timer.start()
    with evk.open(backend=FakeEVK(src, pace="recorded", speed=1.0, packet_bytes=ros_chunks)) as cam:
        stats = evk.record(cam, tmp_path / "b.raw", stop=stop, on_batch=lambda e, t: None)
    timer.join()
    assert stats.stop_reason == "stop" and 0 < stats.payload_bytes < len(payload_of(src))
    assert payload_of(tmp_path / "b.raw") == payload_of(src)[: stats.payload_bytes]


def test_idle_timeouts_are_not_errors(tmp_path, shared_raw_dir):
    src = shared_raw_dir / SAMPLE
    _, stats, out, _ = record_fake(tmp_path, src, decode=False, packet_bytes=8192,
                                   pause_after_bytes=(200_000, 0.35))
    assert stats.n_timeouts >= 2 and stats.stop_reason == "end_of_stream"
    assert payload_of(out) == payload_of(src)


@pytest.mark.parametrize("fault, exc, message", [
    ("stall_after_bytes", evk.EvkStallError, "endpoint stalled"),
    ("disconnect_after_bytes", evk.EvkDisconnectedError, "camera disconnected"),
])
def test_faults_mid_stream_keep_received_data(tmp_path, shared_raw_dir, ros_chunks, fault, exc, message):
    src = shared_raw_dir / ROS
    at = 300_004
    fake = FakeEVK(src, packet_bytes=ros_chunks, **{fault: at})
    got = []
    cam = evk.open(backend=fake)
    with pytest.raises(exc, match=message + r".*the 300004 bytes received before it are kept in .*rec\.raw") as err:
        evk.record(cam, tmp_path / "rec.raw", on_batch=lambda e, t: got.append(e))
    cam.close()  # after an unplug the destroy sequence fails: logged, not raised
    stats = err.value.stats
    assert stats.payload_bytes == at and stats.stop_reason == "error"
    assert payload_of(tmp_path / "rec.raw") == payload_of(src)[:at]
    on_disk = raw.read(tmp_path / "rec.raw").events
    assert np.array_equal(np.concatenate(got), on_disk)
    assert np.array_equal(on_disk, raw.read(src).events[: len(on_disk)]) and len(on_disk) > 30000


def test_queue_overflow_is_counted_and_located(tmp_path, shared_raw_dir):
    src = shared_raw_dir / SAMPLE
    original = payload_of(src)
    fake = FakeEVK(src, packet_bytes=8192)
    with evk.open(backend=fake) as cam:
        cam.queue_bytes = 100_000
        cam.start()
        cam.reader.join(10)  # the reader reads the whole file before anyone consumes
        stats = evk.record(cam, tmp_path / "rec.raw")
    assert stats.dropped_bytes > 0 and stats.overflows > 0 and not stats.lossless
    assert stats.payload_bytes <= 100_000 and stats.queue_peak_bytes <= 100_000
    assert sum(n for _, n in stats.gaps) == stats.dropped_bytes
    assert stats.payload_bytes + stats.dropped_bytes == len(original)
    written = payload_of(tmp_path / "rec.raw")
    rebuilt, pos, src_pos = [], 0, 0
    for offset, n in stats.gaps:  # the file is the original minus the reported gaps
        rebuilt.append(original[src_pos:src_pos + offset - pos])
        src_pos += offset - pos + n
        pos = offset
    rebuilt.append(original[src_pos:])
    assert b"".join(rebuilt) == written


def test_slow_consumer_lags_but_loses_nothing(tmp_path, shared_raw_dir, ros_chunks):
    src = shared_raw_dir / ROS
    got = []

    def slow(events, triggers):
        threading.Event().wait(0.1)  # 105 packets x 100 ms: far slower than the 0.6 s stream
        got.append(events)

    with evk.open(backend=FakeEVK(src, pace="recorded", speed=2.0, packet_bytes=ros_chunks)) as cam:
        cam.queue_bytes = 262144  # 0.2 s of this stream: decoding must not hold up the USB path
        stats = evk.record(cam, tmp_path / "rec.raw", on_batch=slow)
    assert stats.dropped_bytes == 0 and stats.lossless
    assert np.array_equal(np.concatenate(got), raw.read(src).events)
    assert stats.duration_s >= stats.stream_s


def test_on_batch_error_stops_and_keeps_the_file(tmp_path, shared_raw_dir, ros_chunks):
    src = shared_raw_dir / ROS

    def boom(events, triggers):
        raise RuntimeError("analysis failed")

    with evk.open(backend=FakeEVK(src, pace="recorded", speed=0.5, packet_bytes=ros_chunks)) as cam:
        with pytest.raises(RuntimeError, match="analysis failed"):
            evk.record(cam, tmp_path / "rec.raw", on_batch=boom, max_duration_s=5)
        assert not cam.is_streaming
    kept = payload_of(tmp_path / "rec.raw")
    assert 0 < len(kept) < len(payload_of(src)) and kept == payload_of(src)[: len(kept)]


def test_lost_data_shows_as_time_base_jump(tmp_path, shared_raw_dir):
    src = shared_raw_dir / ROS
    data = open(src, "rb").read()
    _, size = raw.parse_header(data)
    cut = data[:size] + data[size:size + 200_000] + data[size + 400_000:]  # 200 kB lost on the "link"
    damaged = tmp_path / "damaged.raw"
    damaged.write_bytes(cut)
    _, stats, _, _ = record_fake(tmp_path, damaged, decode=False)
    assert stats.time_jumps >= 1 and not stats.lossless
    _, clean, _, _ = record_fake(tmp_path, src, decode=False)
    assert clean.time_jumps == 0


def test_cli_records_through_the_fake(tmp_path, shared_raw_dir, capsys):
    from capture.evk.cli import main

    src = shared_raw_dir / ROS
    out = tmp_path / "cli.raw"
    assert main(["record", str(out), "--fake", str(src), "--speed", "max", "--bias", "fo=5", "--erc", "2e7",
                 "--roi", "100,50,200,100", "--trigger"]) == 0
    assert payload_of(out) == payload_of(src)
    capsys.readouterr()
    assert main(["record", str(out), "--fake", str(src), "--bias", "fo=99"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("capture.evk: error: bias_fo offset 99 is outside") and err.count("\n") == 1


@pytest.mark.parametrize("option", [["--roi", "1,2,3"], ["--roi", "1 2 3 4"], ["--bias", "fo"], ["--bias", "fo=x"],
                                    ["--speed", "fast"]])
def test_cli_usage_errors_exit_2(tmp_path, option, capsys):
    from capture.evk.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["record", str(tmp_path / "x.raw"), *option])
    assert exc.value.code == 2 and "python -m capture.evk record: error:" in capsys.readouterr().err


def test_drops_are_counted_while_recording_for_a_watcher(tmp_path, shared_raw_dir):
    """``RecordStats`` passed in is kept current: a watcher (the recorder's status line) sees the
    drops while the stream is still being written, not only in the totals set at its end."""
    src = shared_raw_dir / SAMPLE
    progress = evk.RecordStats(raw_path=tmp_path / "rec.raw")
    seen = []
    fake = FakeEVK(src, packet_bytes=8192)
    with evk.open(backend=fake) as cam:
        cam.queue_bytes = 100_000
        cam.start()
        cam.reader.join(10)  # the reader reads the whole file before anyone consumes: drops
        queue = cam.reader.queue
        get = queue.get

        def get_and_look(*args):  # the recorder's loop asks for its next item: still streaming
            seen.append(progress.dropped_bytes)
            return get(*args)

        queue.get = get_and_look
        stats = evk.record(cam, tmp_path / "rec.raw", stats=progress)
    assert stats is progress and stats.dropped_bytes > 0
    assert max(seen) > 0  # seen while streaming


def test_the_live_decoder_gathers_small_writes_into_batches(tmp_path, shared_raw_dir):
    # bytes written in 64 small pieces: one batch for the consumer, not one per piece (a consumer's
    # cost per batch counts: a batch per USB transfer held the GIL most of the time); the batch waits
    # for 1 MiB (more than this recording holds) or the end of the input
    import time

    from capture.evk.record import RecordStats, _FileDecoder

    src = raw.RawReader(shared_raw_dir / "expelliarmus_evt3_sample_1280x720.raw")
    src.close()
    data = (shared_raw_dir / "expelliarmus_evt3_sample_1280x720.raw").read_bytes()
    header, payload = data[:src.header_size], data[src.header_size:]
    path = tmp_path / "live.raw"
    batches = []
    with path.open("wb", buffering=0) as f:
        f.write(header)
        dec = _FileDecoder(path, len(header), raw.StreamDecoder("EVT3", width=1280, height=720),
                           lambda ev, tr: batches.append(ev), RecordStats(raw_path=path))
        dec.WAIT_S = 10.0  # (not the 50 ms of a recording: no timing in this test)
        dec.start()
        piece = -(-len(payload) // 64)
        for i in range(0, len(payload), piece):
            f.write(payload[i:i + piece])
            dec.written(min(i + piece, len(payload)))
            time.sleep(0.0005)
        dec.close_input()
        t_closed = time.monotonic()
        dec.join(10)
    assert time.monotonic() - t_closed < 5 and not dec.is_alive()  # the end of the input ends the wait
    assert dec.error is None and len(batches) == 1
    np.testing.assert_array_equal(np.concatenate(batches), raw.read(shared_raw_dir / "expelliarmus_evt3_sample_1280x720.raw").events)
