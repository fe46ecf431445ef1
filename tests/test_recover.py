"""A recording cut short (killed, crashed): its store completed from the RAW file the recorder
wrote beside it (``capture.ingest.recover_session``, ``python -m capture.ingest recover``), and the
one-writer lock that tells such a session from one still being written."""

import gc
import shutil

import numpy as np
import pytest

from capture import raw
from capture.ingest import main as ingest_main
from capture.ingest import recover_session
from capture.replay import main as replay_main
from capture.events import make_events
from capture.session import SessionError, create_session, open_session, update_session
from test_reliability_record import TRIGGER_FILE, _corrupt_time_low

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")  # damaged words, on purpose


def _killed_recording(src, out, stop_us):
    """What the recorder leaves when killed: ``src``'s bytes in ``out/events.raw`` (written as they
    arrive) and a store fed the decoded batches before ``stop_us``, committed, never closed."""
    reader = raw.RawReader(src, chunk_bytes=1 << 14)
    w = create_session(out, width=reader.width, height=reader.height, attrs={"raw_file": "events.raw"})
    shutil.copy(src, out / "events.raw")
    for events, triggers in reader:
        w.append_events(events[:np.searchsorted(events["t"], stop_us)])  # (damage: roughly sorted)
        w.append_triggers(triggers[triggers["t"] < stop_us])
        if len(events) and events["t"][-1] >= stop_us:
            break
    w.flush()
    del w  # killed: no close (the lock goes with the process; here with the writer)
    gc.collect()


def _delivered_in_store(store_events, stream, runs):
    """Every event delivered is in the store, in order, or in a placed out-of-order run."""
    keep = np.ones(len(stream), bool)
    removed = 0
    for index, _, k in runs:
        keep[index + removed:index + removed + k] = False
        removed += k
    return np.array_equal(store_events, stream[keep])


def test_recover_completes_the_store_with_every_event_and_trigger_after_the_kill(shared_raw_dir, tmp_path):
    bad = tmp_path / "bad.raw"
    _corrupt_time_low(shared_raw_dir / TRIGGER_FILE, bad, n_flips=8, seed=3)
    stream = raw.read(bad)
    cut_us = int(stream.triggers["t"][0]) + 1000  # between the two triggers
    out = tmp_path / "s"
    _killed_recording(bad, out, cut_us)
    s = open_session(out)
    n, attrs = s.n_events, s.root["events"].attrs
    assert 0 < n < len(stream.events) and len(s.triggers()) == 1
    assert attrs["n_out_of_order"] > 0  # damage before the kill...
    assert s.cut_short and "capture.ingest recover" in s.damage

    got = recover_session(out, progress=False)

    s = open_session(out)
    runs, n_out = s.root["events"].attrs["out_of_order"], s.root["events"].attrs["n_out_of_order"]
    assert n_out > attrs["n_out_of_order"]  # ...and after it, placed as the recorder places it
    assert _delivered_in_store(s.events(), stream.events, runs)
    assert np.array_equal(s.triggers(), stream.triggers)
    assert got["events_added"] == s.n_events - n and got["triggers_added"] == 1
    assert got["events"] == len(stream.events) - n_out
    assert s.attrs["closed"] and not s.cut_short
    assert s.attrs["recording"]["recovered_events"] == got["events_added"]
    assert "cut short" in s.attrs["recording"]["stop_reason"]
    assert s.damage is not None and "cut short" not in s.damage  # the out-of-order runs remain told
    # its ms index reaches the recovered events
    t0 = int(stream.events["t"][-1]) - 30_000
    assert np.array_equal(s.events(t0, t0 + 20_000), s.events()[(s.events()["t"] >= t0) & (s.events()["t"] < t0 + 20_000)])


def test_recover_with_nothing_committed_stores_the_whole_raw_file(shared_raw_dir, tmp_path):
    src = shared_raw_dir / TRIGGER_FILE
    out = tmp_path / "s"
    _killed_recording(src, out, stop_us=0)
    assert open_session(out).n_events == 0
    assert ingest_main(["recover", str(out), "--quiet"]) == 0
    ref = raw.read(src)
    s = open_session(out)
    assert np.array_equal(s.events(), ref.events) and np.array_equal(s.triggers(), ref.triggers)


def test_a_raw_file_that_is_not_the_sessions_is_refused_and_nothing_is_written(shared_raw_dir, tmp_path, capsys):
    src = shared_raw_dir / TRIGGER_FILE
    out = tmp_path / "s"
    _killed_recording(src, out, stop_us=int(raw.read(src).events["t"][40_000]))
    n = open_session(out).n_events
    ev = raw.read(src).events.copy()
    ev["x"] = (ev["x"] + 1) % 1280  # the same times, other pixels
    (out / "events.raw").write_bytes(raw.header_bytes("EVT3", width=1280, height=720)
                                     + raw.encode(ev, width=1280, height=720))
    assert ingest_main(["recover", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "does not match the store" in err
    s = open_session(out)
    assert s.n_events == n and s.cut_short  # untouched, still to recover
    assert replay_main([str(out), "--quiet", "--workers", "1"]) == 0  # replay analyses the stored part
    err = capsys.readouterr().err
    assert "could not be completed" in err and "analysing the stored part" in err
    assert open_session(out).n_events == n


def test_recovery_drops_the_stamp_of_an_analysis_of_the_shorter_store(shared_raw_dir, tmp_path):
    src = shared_raw_dir / TRIGGER_FILE
    out = tmp_path / "s"
    _killed_recording(src, out, stop_us=int(raw.read(src).events["t"][20_000]))
    with update_session(out) as w:  # a batch analysed the stored part
        w.set_attrs(analysis={"version": "x"})
    recover_session(out, progress=False)
    assert open_session(out).attrs.get("analysis") is None  # a batch analyses it again


def test_a_session_being_written_is_not_cut_short_and_has_one_writer(shared_raw_dir, tmp_path, capsys):
    src = shared_raw_dir / TRIGGER_FILE
    out = tmp_path / "s"
    w = create_session(out, width=1280, height=720, attrs={"raw_file": "events.raw"})
    shutil.copy(src, out / "events.raw")
    w.append_events(raw.read(src).events[:1000])
    w.flush()
    assert not open_session(out).cut_short  # a live recording: its writer holds the lock
    with pytest.raises(SessionError, match="being written by another program"):
        update_session(out)
    assert ingest_main(["recover", str(out), "--quiet"]) == 1
    assert "nothing to recover" in capsys.readouterr().err
    w.close(recording={"stop_reason": "stop"})  # as the recorder closes it
    with update_session(out) as again:  # closed: free to write again
        again.set_attrs(note="x")
    assert not open_session(out).cut_short


def test_a_corrupted_event_at_the_stores_last_time_does_not_misplace_the_recovery(tmp_path):
    """A time word corrupted upward puts one early event exactly at the time of the store's last
    event, on the same pixel; the recorder left it out. Recovery resumes after the real one."""
    t = np.concatenate([np.arange(0, 500), [1200], np.arange(500, 2000)])
    rng = np.random.default_rng(5)
    ev = make_events(t, rng.integers(0, 1280, len(t)), rng.integers(0, 720, len(t)), rng.integers(0, 2, len(t)))
    spike, real = np.flatnonzero(t == 1200)
    ev[["x", "y", "p"]][spike] = ev[["x", "y", "p"]][real]
    body = raw.encode(ev[:spike + 1], width=1280, height=720) + raw.encode(ev[spike + 1:], width=1280, height=720)
    src = tmp_path / "spike.raw"
    src.write_bytes(raw.header_bytes("EVT3", width=1280, height=720) + body)
    out = tmp_path / "s"
    _killed_recording(src, out, stop_us=1201)
    s = open_session(out)
    assert s.n_events == 1201 and s.events()["t"][-1] == 1200  # the spike left out, the real one stored
    assert s.root["events"].attrs["n_out_of_order"] == 1
    recover_session(out, progress=False, chunk_bytes=256)
    got = open_session(out).events()
    assert np.array_equal(got, np.delete(ev, spike))  # each event once, in order


def test_a_writer_is_not_refused_because_a_reader_looked_at_that_instant(tmp_path):
    """``being_written`` probes with a shared lock for an instant; a writer opening meanwhile waits
    for it rather than saying that the session is being written."""
    import threading

    from capture import session as S

    with create_session(tmp_path / "s", width=64, height=48):
        pass
    probe = S._lock_writer(tmp_path / "s", shared=True)
    threading.Timer(0.1, S._unlock, args=(probe,)).start()
    with update_session(tmp_path / "s") as w:  # opened once the probe let go
        w.set_attrs(note="x")
    assert open_session(tmp_path / "s").attrs["note"] == "x"
    assert not S.being_written(tmp_path / "s")


def test_a_file_system_without_flock_still_records_unlocked(tmp_path, monkeypatch):
    """Some network mounts answer flock with ENOLCK: sessions are written there, without the lock."""
    import errno

    from capture import session as S

    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(S.fcntl, "flock", no_locks)
    with create_session(tmp_path / "s", width=64, height=48) as w:
        w.set_attrs(note="x")
        assert not S.being_written(tmp_path / "s")  # nothing to tell it by
    assert open_session(tmp_path / "s").attrs["note"] == "x"
