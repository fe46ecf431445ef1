"""The recorder under failure, end to end through the fake EVK: a full disk (a real small
tmpfs when the machine allows, else a disk model on the store's writes), corrupted words on
the link, bad ``--out``."""

import os
import subprocess

import numpy as np
import pytest

from capture import raw
from capture.evk.fake import FakeEVK
from capture.pipeline.record import RecordSettings, record_session
from capture.replay import main as replay_main
from capture.run import main as run_main
from capture.session import RESERVE_NAME, open_session
from test_reliability_store import SmallDisk

TRIGGER_FILE = "ros_codecs_evt3_trigger_1280x720.raw"
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")  # a RAW file cut short by the full disk


def _check_store(out, source):
    """Closed, an exact prefix of ``source``; what is missing after it is marked as lost when the
    recorder received it (a stop on a RAW write error receives no more)."""
    s = open_session(out)
    assert s.attrs["closed"]
    got = s.events()
    assert np.array_equal(got, source[:len(got)])
    lost = s.root["events"].attrs.get("lost")
    if lost is not None:
        assert lost[0] == len(got) and lost[1] == int(source["t"][len(got)])
        assert len(got) + lost[2] <= len(source)
    assert not (out / RESERVE_NAME).exists()
    return s, lost


def test_disk_full_mid_recording_one_line_exit_1_store_closed_and_marked(shared_raw_dir, tmp_path, monkeypatch,
                                                                        capfd):
    src = shared_raw_dir / TRIGGER_FILE
    ref = raw.read(src).events
    out = tmp_path / "s"
    # room for the RAW file, the reserve and about a third of the store
    disk = SmallDisk(monkeypatch, tmp_path, (1 << 20) + 758_529 + 130_000)
    rc = run_main(["--fake", str(src), "--out", str(out), "--viewer", "none", "--no-analysis", "--quiet"])
    captured = capfd.readouterr()
    assert disk.failures > 0
    assert rc == 1
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("capture.run: error: "), captured.err
    assert "No space left" in err[0] and "Traceback" not in captured.err and "Exception in thread" not in captured.err
    received = raw.read(out / "events.raw").events  # the recording stops on the error
    assert np.array_equal(received, ref[:len(received)])
    s, lost = _check_store(out, received)
    assert lost is not None and s.n_events + lost[2] == len(received)  # every event received: stored or marked
    assert s.attrs["recording"]["stop_reason"].startswith("write error")


@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a tmpfs needs root")
@pytest.mark.parametrize("size_kib", [1200, 1700, 1900, 2100])
def test_disk_full_on_a_real_small_filesystem(shared_raw_dir, tmp_path, size_kib):
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kib}k", "tmpfs", str(mnt)],
                      capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        src = shared_raw_dir / TRIGGER_FILE
        ref = raw.read(src).events
        settings = RecordSettings(out=mnt / "s", backend=FakeEVK(src, pace="recorded"), min_free_bytes=0,
                                  quiet=True)
        result = record_session(settings)
        assert result.error and "No space left" in result.error and "\n" not in result.error
        s, lost = _check_store(mnt / "s", ref)
        received = raw.read(mnt / "s" / "events.raw").events
        if s.n_events + (lost[2] if lost else 0) < len(received):  # the RAW write failed first
            assert "RAW file may hold events after the store's last one" in s.damage
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


def _corrupt_time_low(src, dst, n_flips=6, bit=11, seed=0):
    """Copy an EVT3 RAW file with one bit flipped in ``n_flips`` TIME_LOW words (the time jumps
    2^bit µs forward or back until the next one)."""
    data = src.read_bytes()
    _, size = raw.parse_header(data)
    words = np.frombuffer(data[size:], "<u2").copy()
    time_low = np.flatnonzero(words >> 12 == 0x6)
    rng = np.random.default_rng(seed)
    picks = np.sort(rng.choice(time_low[len(time_low) // 10:], n_flips, replace=False))
    words[picks] ^= np.uint16(1 << bit)
    dst.write_bytes(data[:size] + words.tobytes())
    return data[:size], words.tobytes()


def test_corrupted_words_do_not_stop_the_recording(shared_raw_dir, tmp_path, capsys):
    bad = tmp_path / "bad.raw"
    _, payload = _corrupt_time_low(shared_raw_dir / TRIGGER_FILE, bad)
    stream = raw.read(bad).events  # what the link delivered, decoded
    assert np.any(np.diff(stream["t"]) < 0)  # the damage does put times out of order
    out = tmp_path / "s"
    rc = run_main(["--fake", str(bad), "--speed", "max", "--out", str(out), "--viewer", "none",
                   "--no-analysis", "--quiet"])
    printed = capsys.readouterr().out
    assert rc == 0
    s = open_session(out)
    assert s.attrs["closed"] and s.attrs["recording"]["stop_reason"] == "end_of_stream"
    runs = s.root["events"].attrs["out_of_order"]
    n_left_out = s.root["events"].attrs["n_out_of_order"]
    assert 0 < n_left_out < len(stream) // 100 and n_left_out == sum(r[2] for r in runs)
    assert f"{n_left_out} events with times out of order" in printed
    # every event delivered is either in the store, in order, or in a placed run
    keep = np.ones(len(stream), bool)
    removed = 0
    for index, _, k in runs:
        keep[index + removed:index + removed + k] = False
        removed += k
    assert np.array_equal(s.events(), stream[keep])
    # the RAW file keeps every byte, damaged words included
    header_size = raw.parse_header((out / "events.raw").read_bytes())[1]
    assert (out / "events.raw").read_bytes()[header_size:] == payload
    # replay says what the store lacks
    assert replay_main([str(out), "--quiet", "--workers", "1"]) == 0
    assert f"{n_left_out} events left out as out of time order" in capsys.readouterr().err


def test_empty_out_is_a_usage_error(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        run_main(["--demo", "--out", "", "--viewer", "none"])
    assert exit_info.value.code == 2
    assert "--out: the session directory must not be empty" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
