"""The session store on a real directory: round trips, time windows, live readers, crash safety."""

import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import zarr

from capture import session as S
from capture.events import EVENT_DTYPE, TRACK_COLUMNS, first_at, make_events, make_triggers, time_slice


def _events(n, seed=0, t_max=3_000_000, width=640, height=480):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(10_000, t_max, n))
    return make_events(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.integers(0, 2, n))


def test_events_round_trip_across_chunks(tmp_path):
    ev = _events(S.EVENT_CHUNK + 12345)
    with S.create_session(tmp_path / "s", width=640, height=480, attrs={"sensor": {"model": "IMX636"}}) as w:
        for i in range(0, len(ev), 70_000):
            w.append_events(ev[i:i + 70_000])
    s = S.open_session(tmp_path / "s")
    assert s.n_events == len(ev)
    out = s.events()
    assert out.dtype == EVENT_DTYPE
    assert np.array_equal(out, ev)
    assert s.attrs["sensor"] == {"model": "IMX636"}
    assert s.attrs["schema_version"] == S.SCHEMA_VERSION
    assert (s.width, s.height) == (640, 480)
    # stored as separate compressed columns, t with a delta filter
    g = zarr.open_group(str(tmp_path / "s"), mode="r")
    assert sorted(g["events"].array_keys()) == ["p", "t", "x", "y"]
    assert g["events"]["t"].chunks == (S.EVENT_CHUNK,)
    assert any("delta" in type(f).__name__.lower() for f in g["events"]["t"].filters)


def test_time_window_reads_through_index(tmp_path):
    ev = _events(400_000, seed=1)
    with S.create_session(tmp_path / "s", width=640, height=480) as w:
        w.append_events(ev)
    s = S.open_session(tmp_path / "s")
    rng = np.random.default_rng(2)
    for _ in range(50):
        a, b = np.sort(rng.integers(0, 3_100_000, 2))
        assert np.array_equal(s.events(a, b), time_slice(ev, a, b))
    # exact boundaries and times outside the recording
    t_mid = int(ev["t"][200_000])
    assert np.array_equal(s.events(t_mid, t_mid + 1), ev[ev["t"] == t_mid])
    assert len(s.events(0, 5_000)) == 0
    assert len(s.events(10**9, 10**9 + 10)) == 0
    idx = zarr.open_group(str(tmp_path / "s"), mode="r")["index"]
    ms = idx["ms_to_idx"][:]
    t0_ms = idx.attrs["t0_ms"]
    k = np.arange(len(ms))
    assert np.array_equal(ms, np.searchsorted(ev["t"], (t0_ms + k) * 1000))


def test_tables_round_trip(tmp_path):
    tr = make_triggers([100, 2100, 4100], [0, 0, 1], [1, 0, 1])
    track = {"t_us": np.arange(5) * 1000, "cx": np.linspace(10, 50, 5), "cy": np.full(5, 20.0),
             "r": np.full(5, 30.0), "vx": np.full(5, 1e4), "vy": np.zeros(5),
             "score": np.ones(5), "flight": np.zeros(5, int)}
    spin = {"t_start_us": [0, 1000], "t_end_us": [1000, 2000], "axis": [[0, 0, 1], [0, 1, 0]],
            "omega_rad_s": [628.3, 1256.6], "rps": [100.0, 200.0],
            "velocity_px_s": [[1e4, 0], [1e4, 0]], "confidence": [0.9, 0.8]}
    with S.create_session(tmp_path / "s", width=64, height=48) as w:
        w.append_triggers(tr)
        w.write_track(track)
        w.write_spin(spin)
        w.append_frames([0, 16_667], images=np.full((2, 48, 64, 3), 7, np.uint8))
    s = S.open_session(tmp_path / "s")
    assert np.array_equal(s.triggers(), tr)
    got = s.track()
    for k, v in track.items():
        assert np.allclose(got[k], v), k
    sp = s.spin()
    assert sp["axis"].shape == (2, 3) and np.allclose(sp["axis"][1], [0, 1, 0])
    assert np.allclose(sp["rps"], [100, 200]) and sp["velocity_px_s"].shape == (2, 2)
    # uncertainties not given read back as NaN (not measured), one per row
    assert sp["rps_sigma_pct"].shape == (2,) and np.isnan(sp["rps_sigma_pct"]).all()
    fr = s.frames()
    assert list(fr["t_us"]) == [0, 16_667] and fr["image"].shape == (2, 48, 64, 3)
    # replay replaces the track in place
    w = S.update_session(tmp_path / "s")
    w.write_track({k: v[:2] for k, v in track.items()})
    w.close()
    assert len(S.open_session(tmp_path / "s").track()["t_us"]) == 2


def test_empty_session_reads_empty(tmp_path):
    S.create_session(tmp_path / "s", width=10, height=10).close()
    s = S.open_session(tmp_path / "s")
    assert s.n_events == 0 and len(s.events(0, 10)) == 0
    assert len(s.triggers()) == 0 and len(s.track()["t_us"]) == 0 and s.spin()["axis"].shape == (0, 3)


def test_chunk_cache_reads_the_same_events_and_follows_a_live_writer(tmp_path):
    ev = _events(2 * S.EVENT_CHUNK + 54_321, seed=4)
    w = S.create_session(tmp_path / "s", width=640, height=480)
    w.append_events(ev[:S.EVENT_CHUNK + 1000])  # the second chunk partly committed
    w.flush()
    cached = S.open_session(tmp_path / "s", cache_chunks=1)
    n = cached.n_events
    assert np.array_equal(cached.events_range(S.EVENT_CHUNK - 10, n), ev[S.EVENT_CHUNK - 10:n])
    w.append_events(ev[S.EVENT_CHUNK + 1000:])
    w.close()
    # the cached partial chunk is read again where rows were committed since
    assert np.array_equal(cached.events_range(S.EVENT_CHUNK + 500, S.EVENT_CHUNK + 5000),
                          ev[S.EVENT_CHUNK + 500:S.EVENT_CHUNK + 5000])
    rng = np.random.default_rng(5)
    for _ in range(30):
        a, b = np.sort(rng.integers(0, 3_100_000, 2))
        got = cached.events(a, b)
        assert np.array_equal(got, time_slice(ev, a, b))
        if len(got):
            got["x"] = 0  # a caller's copy: the cache is unchanged
    assert np.array_equal(cached.events(), ev) and len(cached._chunks) == 1


def test_reader_follows_live_writer(tmp_path):
    ev = _events(50_000, seed=3)
    w = S.create_session(tmp_path / "s", width=640, height=480)
    w.append_events(ev[:20_000])
    w.flush()
    r = S.open_session(tmp_path / "s")
    assert r.n_events == 20_000 and not r.attrs["closed"]
    w.append_events(ev[20_000:])
    w.flush()
    r.reload()
    assert r.n_events == 50_000
    assert np.array_equal(r.events(), ev)
    w.close()
    r.reload()
    assert r.attrs["closed"]


def test_reader_ignores_uncommitted_tail(tmp_path):
    """Data written past ``n_committed`` (an append cut short) is invisible to readers."""
    ev = _events(1000, seed=4)
    w = S.create_session(tmp_path / "s", width=640, height=480)
    w.append_events(ev)
    w.flush()
    g = zarr.open_group(str(tmp_path / "s"), mode="r+", use_consolidated=False)
    for name in "txyp":
        g["events"][name].resize((1500,))  # what a writer killed after resize leaves behind
    s = S.open_session(tmp_path / "s")
    assert s.n_events == 1000
    assert np.array_equal(s.events(), ev)
    assert np.array_equal(s.events(0, 10**12), ev)


WRITER = textwrap.dedent("""
    import sys, numpy as np
    from capture.session import create_session
    from capture.events import make_events
    w = create_session(sys.argv[1], width=640, height=480, flush_interval_s=0.0)
    rng = np.random.default_rng(5)
    t = 0
    for i in range(100000):
        n = 7919
        tt = t + np.sort(rng.integers(0, 1000, n)); t += 1000
        w.append_events(make_events(tt, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n)))
        print(w._events.n, flush=True)
""")


def test_sigkill_mid_recording_keeps_committed_events(tmp_path):
    path = tmp_path / "s"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    committed = 0
    for line in proc.stdout:
        committed = int(line)
        if committed > 3 * S.EVENT_CHUNK // 2:  # past one whole chunk and into the next
            break
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    s = S.open_session(path)
    assert s.n_events >= committed
    # regenerate the writer's deterministic stream and compare everything committed
    rng = np.random.default_rng(5)
    parts, t, total = [], 0, 0
    while total < s.n_events:
        n = 7919
        tt = t + np.sort(rng.integers(0, 1000, n)); t += 1000
        parts.append(make_events(tt, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n)))
        total += n
    expected = np.concatenate(parts)[:s.n_events]
    got = s.events()
    assert len(got) == s.n_events
    assert np.array_equal(got, expected)
    assert np.all(np.diff(got["t"]) >= 0)


def test_not_a_session_and_newer_schema(tmp_path):
    with pytest.raises(S.SessionError, match="no such session"):
        S.open_session(tmp_path / "missing")
    (tmp_path / "plain").mkdir()
    with pytest.raises(S.SessionError, match="not a session"):
        S.open_session(tmp_path / "plain")
    zarr.open_group(str(tmp_path / "other"), mode="w", zarr_format=3).attrs["foo"] = 1
    with pytest.raises(S.SessionError, match="not a session"):
        S.open_session(tmp_path / "other")
    S.create_session(tmp_path / "new", width=1, height=1).close()
    meta = json.loads((tmp_path / "new" / "zarr.json").read_text())
    meta["attributes"]["schema_version"] = S.SCHEMA_VERSION + 1
    (tmp_path / "new" / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(S.SessionError, match="newer"):
        S.open_session(tmp_path / "new")


def test_writer_rejects_bad_input(tmp_path):
    w = S.create_session(tmp_path / "s", width=10, height=10)
    with pytest.raises(TypeError, match="EVENT_DTYPE"):
        w.append_events(np.zeros(3, dtype=[("t", "<f8")]))
    w.append_events(make_events([5, 6], [1, 1], [1, 1], [1, 0]))
    w.append_events(make_events([4, 7], [1, 2], [1, 2], [1, 1]))  # t=4 goes back: left out, recorded
    w.close()
    s = S.open_session(tmp_path / "s")
    assert list(s.events()["t"]) == [5, 6, 7]
    assert s.root["events"].attrs["out_of_order"] == [[2, 6, 1]]
    assert "1 events left out as out of time order" in s.damage
    with pytest.raises(S.SessionError, match="already exists"):
        S.create_session(tmp_path / "s", width=10, height=10)


def test_overwrite_replaces_the_store_and_keeps_other_files(tmp_path):
    with S.create_session(tmp_path / "s", width=10, height=10) as w:
        w.append_events(make_events([1, 2], [1, 1], [1, 1], [1, 0]))
    (tmp_path / "s" / "events.raw").write_bytes(b"raw bytes")
    (tmp_path / "s" / "gopro").mkdir()
    (tmp_path / "s" / "gopro" / "GX010001.MP4").write_bytes(b"video")
    S.create_session(tmp_path / "s", width=20, height=20, overwrite=True).close()
    s = S.open_session(tmp_path / "s")
    assert s.n_events == 0 and s.width == 20
    assert (tmp_path / "s" / "events.raw").read_bytes() == b"raw bytes"
    assert (tmp_path / "s" / "gopro" / "GX010001.MP4").read_bytes() == b"video"


def test_reader_of_a_closed_session_sees_later_updates(tmp_path):
    track = {k: np.arange(5) for k in TRACK_COLUMNS}
    with S.create_session(tmp_path / "s", width=10, height=10) as w:
        w.write_track(track)
    r = S.open_session(tmp_path / "s")
    assert len(r.track()["t_us"]) == 5
    w = S.update_session(tmp_path / "s")
    assert len(S.open_session(tmp_path / "s").track()["t_us"]) == 5  # readable while reopened
    w.write_track({k: v[:2] + 100 for k, v in track.items()})
    w.close()
    assert list(r.track()["t_us"]) == [100, 101]


def test_spin_table_of_an_older_session_reads_missing_columns_as_not_known(tmp_path):
    spin = {"t_start_us": [0, 1000, 2000], "t_end_us": [1000, 2000, 3000], "axis": [[0, 0, 1]] * 3,
            "omega_rad_s": [628.3] * 3, "rps": [100.0] * 3, "velocity_px_s": [[0, 0]] * 3,
            "confidence": [0.9] * 3, "axis_sigma_deg": [0.5] * 3, "rps_sigma_pct": [0.7] * 3}
    with S.create_session(tmp_path / "s", width=64, height=48) as w:
        w.write_spin(spin)
    # a session written before the uncertainty columns existed has no such arrays
    root = zarr.open_group(str(tmp_path / "s"), mode="r+", use_consolidated=False)
    del root["spin"]["axis_sigma_deg"]
    del root["spin"]["flight"]
    sp = S.open_session(tmp_path / "s").spin()
    assert sp["axis_sigma_deg"].shape == (3,) and np.isnan(sp["axis_sigma_deg"]).all()
    assert np.allclose(sp["rps_sigma_pct"], 0.7) and np.allclose(sp["rps"], 100.0)
    assert list(sp["flight"]) == [-1, -1, -1]  # not known (not flight 0)
    # estimates appended to it by this version: the columns come back, the older rows stay unknown
    with S.update_session(tmp_path / "s") as w:
        w.append_spin({**{k: v[:1] for k, v in spin.items()}, "flight": [4]})
    sp = S.open_session(tmp_path / "s").spin()
    assert list(sp["flight"]) == [-1, -1, -1, 4]
    assert np.isnan(sp["axis_sigma_deg"][:3]).all() and sp["axis_sigma_deg"][3] == 0.5


def test_track_sigma_is_stored_and_reads_as_not_measured_where_an_older_version_wrote_none(tmp_path):
    track = {k: np.arange(3) for k in TRACK_COLUMNS if k != "sigma_px"}
    with S.create_session(tmp_path / "s", width=64, height=48) as w:
        w.write_track(track)  # a mapping without the column (a caller of an older version)
    assert np.isnan(S.open_session(tmp_path / "s").track()["sigma_px"]).all()
    with S.update_session(tmp_path / "s") as w:
        w.write_track({**track, "sigma_px": [0.5, 0.25, 2.0]})
    assert list(S.open_session(tmp_path / "s").track()["sigma_px"]) == [0.5, 0.25, 2.0]
    # a session written before the column existed has no such array
    root = zarr.open_group(str(tmp_path / "s"), mode="r+", use_consolidated=False)
    del root["track"]["sigma_px"]
    tr = S.open_session(tmp_path / "s").track()
    assert tr["sigma_px"].shape == (3,) and np.isnan(tr["sigma_px"]).all() and list(tr["cx"]) == [0.0, 1.0, 2.0]


@pytest.mark.parametrize("n_old", [3, S.TABLE_CHUNK + 5])
def test_rows_appended_to_an_older_table_leave_its_rows_not_measured_in_the_new_column(tmp_path, n_old):
    """A table of an older version lacks a column: appending creates it, and the rows already there
    (over a whole chunk too) read as not measured, the store still opening."""
    with S.create_session(tmp_path / "s", width=64, height=48) as w:
        w.append_track({k: np.arange(n_old) for k in TRACK_COLUMNS})
    root = zarr.open_group(str(tmp_path / "s"), mode="r+", use_consolidated=False)
    del root["track"]["sigma_px"]
    with S.update_session(tmp_path / "s") as w:
        w.append_track({k: np.arange(100, 104) for k in TRACK_COLUMNS})
    tr = S.open_session(tmp_path / "s").track()
    assert len(tr["t_us"]) == n_old + 4 and list(tr["t_us"][-5:]) == [n_old - 1, 100, 101, 102, 103]
    assert np.isnan(tr["sigma_px"][:n_old]).all() and list(tr["sigma_px"][n_old:]) == [100, 101, 102, 103]


def test_chunks_encoded_by_the_store_are_the_chunks_zarr_writes(tmp_path, monkeypatch):
    """The store's own chunk encoder and Zarr's write path give stores Zarr reads the same."""
    ev = _events(2 * S.EVENT_CHUNK + 777, seed=11)
    cuts = [0, 5, 70_000, S.EVENT_CHUNK - 3, S.EVENT_CHUNK + 9, 2 * S.EVENT_CHUNK + 700, len(ev)]
    stores = {}
    for name, ours in (("ours", True), ("zarr", False)):
        if not ours:
            monkeypatch.setattr(S._ChunkCodec, "fits", staticmethod(lambda arr: False))
        with S.create_session(tmp_path / name, width=640, height=480) as w:
            assert bool(w._events._encoders) == ours
            for a, b in zip(cuts, cuts[1:]):  # partly filled chunks, completed by later appends
                w.append_events(ev[a:b])
                w.flush()
            for k in range(3):  # a small table appended through a new table writer each time
                w.append_track({c: np.arange(k * 4, k * 4 + 4) for c in TRACK_COLUMNS})
        stores[name] = zarr.open_group(str(tmp_path / name), mode="r")
    for c in "txyp":
        mine, theirs = stores["ours"]["events"][c], stores["zarr"]["events"][c]
        assert mine.shape == theirs.shape == (len(ev),)
        np.testing.assert_array_equal(mine[:], ev[c])  # also checks each chunk's CRC-32C
        np.testing.assert_array_equal(mine[:], theirs[:])
    np.testing.assert_array_equal(stores["ours"]["index"]["ms_to_idx"][:], stores["zarr"]["index"]["ms_to_idx"][:])
    np.testing.assert_array_equal(S.open_session(tmp_path / "ours").track()["t_us"], np.arange(12))
    chunk = tmp_path / "ours" / "events" / "t" / "c" / "0"
    data = bytearray(chunk.read_bytes())
    data[40] ^= 1
    chunk.write_bytes(bytes(data))
    with pytest.raises(S.SessionError, match="events/t"):
        S.open_session(tmp_path / "ours").events()


def test_the_readers_chunk_decoder_reads_what_zarr_reads_and_follows_a_growing_store(tmp_path, monkeypatch):
    """Reads decode the store's chunks themselves (delta, Blosc, CRC-32C) with the same rows as
    Zarr's read path, and a reader that opened the arrays follows a writer that grew them since."""
    monkeypatch.setattr(S, "EVENT_CHUNK", 1 << 12)
    ev = _events(5 * S.EVENT_GROW_CHUNKS * (1 << 12) // 2, seed=21)  # 2.5 growth steps
    first = 3 * (1 << 12) + 17
    w = S.create_session(tmp_path / "s", width=640, height=480)
    w.append_events(ev[:first])
    w.flush()
    r = S.open_session(tmp_path / "s")
    assert np.array_equal(r.events(), ev[:first])
    assert r._arrays[("events", "t")][1] is not None  # decoded by the store, not by Zarr
    zarr_path = S.open_session(tmp_path / "s")
    monkeypatch.setattr(S._ChunkCodec, "fits", staticmethod(lambda arr: False))  # its arrays read by Zarr
    assert np.array_equal(zarr_path.events(), ev[:first]) and zarr_path._arrays[("events", "t")][1] is None
    w.append_events(ev[first:])  # beyond the shape the readers' arrays had
    w.flush()
    assert np.array_equal(zarr_path.events(), ev)  # no reload: the reader reopens the arrays it needs
    assert np.array_equal(r.events(), ev)
    w.close()
    g = zarr.open_group(str(tmp_path / "s"), mode="r", use_consolidated=False)
    rng = np.random.default_rng(2)
    cuts = [(0, 1), (4095, 4097), (4096, 8192), (len(ev) - 3, len(ev)), (0, len(ev)),
            (len(ev) - 1, len(ev) + 5), (-3, len(ev)), (7, 7), (9, 2)]  # sliced as Zarr slices
    for a, b in cuts + [tuple(np.sort(rng.integers(0, len(ev), 2))) for _ in range(40)]:
        for c in "txyp":
            np.testing.assert_array_equal(r.read_column("events", c, a, b), g["events"][c][a:b])
    monkeypatch.undo()
    later = S.open_session(tmp_path / "s")
    assert np.array_equal(later.events(), ev)
    (tmp_path / "s" / "events" / "y" / "c" / "5").unlink()  # a chunk gone after opening: its rows named
    with pytest.raises(S.SessionError, match=r"events/y rows 20480\.\.24575 cannot be read \(FileNotFoundError"):
        later.read_column("events", "y", 0, len(ev))


def test_first_at_is_searchsorted_on_a_strided_time_column():
    """``first_at`` (a bisection that copies nothing) finds what ``np.searchsorted(side="left")``
    finds: runs of equal times, values before, inside and after, on the ``t`` view of events."""
    ev = _events(5000, seed=8, t_max=20_000)  # many equal times
    t = ev["t"]
    assert not t.flags.c_contiguous
    values = np.concatenate([[0, t[0], t[-1], t[-1] + 1, t[2500]], t[::97] + 1, t[::89] - 1])
    for v in values:
        assert first_at(t, int(v)) == np.searchsorted(t, v, side="left"), v
    assert first_at(t[:0], 5) == 0


def test_event_arrays_grow_in_steps_while_recording_and_fit_at_close(tmp_path):
    ev = _events(300_000, seed=12)
    w = S.create_session(tmp_path / "s", width=640, height=480)
    w.append_events(ev)
    w.flush()
    g = zarr.open_group(str(tmp_path / "s"), mode="r", use_consolidated=False)
    assert g["events"]["t"].shape == (S.EVENT_GROW_CHUNKS * S.EVENT_CHUNK,)  # one resize, not one per commit
    assert np.array_equal(S.open_session(tmp_path / "s").events(), ev)  # readers stop at n_committed
    w.close()
    g = zarr.open_group(str(tmp_path / "s"), mode="r", use_consolidated=False)
    assert g["events"]["t"].shape == (len(ev),)


def test_store_behind_stores_every_batch_in_order_and_reports_errors(tmp_path, monkeypatch):
    ev = _events(50_000, seed=13)
    tr = make_triggers([100, 200], [0, 1], [1, 0])
    with S.create_session(tmp_path / "s", width=640, height=480) as w:
        store = S.StoreBehind(w)
        for k in range(0, len(ev), 7_000):
            store(ev[k:k + 7_000], tr[:0] if k else tr)
        store.close()
    s = S.open_session(tmp_path / "s")
    assert np.array_equal(s.events(), ev) and np.array_equal(s.triggers(), tr)

    def full(events):
        raise OSError(28, "No space left on device")
    with S.create_session(tmp_path / "f", width=640, height=480) as w:
        monkeypatch.setattr(w, "append_events", full)
        store = S.StoreBehind(w)
        store(ev, tr)
        with pytest.raises(OSError, match="No space"):
            store.close()
        errors = []
        store = S.StoreBehind(w, on_error=errors.append)
        store(ev, tr)
        store.close()
        assert len(errors) == 1 and errors[0].errno == 28


def test_events_committed_ahead_of_the_ms_index_are_found_by_time(tmp_path):
    """Whole chunks are committed as they fill; the ms index follows at each flush. A reader in
    between finds the events past the index's last entry by their times."""
    ev = _events(2 * S.EVENT_CHUNK + 5, seed=14)
    w = S.create_session(tmp_path / "s", width=640, height=480, flush_interval_s=3600)
    w.append_events(ev[:1000])
    w.flush()  # the index now covers the first 1000 events only
    w.append_events(ev[1000:])  # two whole chunks committed, their index entries pending
    s = S.open_session(tmp_path / "s")
    assert s.n_events == 2 * S.EVENT_CHUNK and s._n("index") < int(ev["t"][-1] // 1000) - int(ev["t"][0] // 1000)
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = np.sort(rng.integers(0, int(ev["t"][-1]), 2))
        assert np.array_equal(s.events(a, b), time_slice(ev[:s.n_events], a, b))
    w.close()
    s = S.open_session(tmp_path / "s")
    ms = s.root["index"]["ms_to_idx"][:]
    k = np.arange(len(ms))
    assert np.array_equal(ms, np.searchsorted(ev["t"], (s.root["index"].attrs["t0_ms"] + k) * 1000))


def test_store_behind_holds_at_most_depth_batches(tmp_path, monkeypatch):
    import threading

    release = threading.Event()
    stored = []
    with S.create_session(tmp_path / "s", width=640, height=480) as w:
        def slow(events):
            release.wait(10)
            stored.append(len(events))
        monkeypatch.setattr(w, "append_events", slow)
        store = S.StoreBehind(w, depth=2)
        ev = _events(10, seed=15)
        calls = threading.Thread(target=lambda: [store(ev, make_triggers([], [], [])) for _ in range(4)])
        calls.start()
        calls.join(0.5)
        assert calls.is_alive()  # the third batch waits: two in flight (one being stored), no more
        release.set()
        calls.join(10)
        store.close()
    assert stored == [10] * 4


def test_a_reopened_session_indexes_what_was_committed_after_the_last_flush(tmp_path):
    """A writer killed between a chunk's commit and the next flush leaves events the ms index
    lacks; the writer of the reopened session adds their entries before its own."""
    ev = _events(2 * S.EVENT_CHUNK + 10, seed=16, t_max=3_000_000)
    w = S.create_session(tmp_path / "s", width=640, height=480, flush_interval_s=3600)
    w.append_events(ev[:S.EVENT_CHUNK + 5])
    w.flush()
    w.append_events(ev[S.EVENT_CHUNK + 5:])  # a second chunk committed, its index entries not written
    del w  # killed: no flush, no close
    n = S.open_session(tmp_path / "s").n_events
    later = make_events(np.arange(3_000_000, 3_500_000, 10), np.zeros(50_000, int), np.zeros(50_000, int),
                        np.zeros(50_000, int))
    with S.update_session(tmp_path / "s") as w:
        w.append_events(later)
    s = S.open_session(tmp_path / "s")
    every = np.concatenate([ev[:n], later])
    assert np.array_equal(s.events(), every)
    for a in range(0, 3_500_000, 70_001):
        assert np.array_equal(s.events(a, a + 20_000), time_slice(every, a, a + 20_000))


def test_scheduled_commits_write_the_partly_filled_chunk_only_when_no_chunk_was_committed_lately(tmp_path, monkeypatch):
    """At a high rate whole chunks commit within the interval and the partly filled last one is not
    written again at each scheduled commit; once none has been committed for an interval, the
    buffered events are; the ms index is written on schedule either way."""
    clock = [1000.0]
    monkeypatch.setattr(S.time, "monotonic", lambda: clock[0])
    ev = _events(S.EVENT_CHUNK + 10, seed=21)
    w = S.create_session(tmp_path / "s", width=640, height=480, flush_interval_s=0.2)
    clock[0] += 0.15
    w.append_events(ev)  # a whole chunk committed now, 10 events buffered
    n_index = lambda: int(S.open_session(tmp_path / "s").root["index"].attrs["n_committed"])  # noqa: E731
    assert S.open_session(tmp_path / "s").n_events == S.EVENT_CHUNK and n_index() == 0
    clock[0] += 0.1  # 0.25 s since the last scheduled commit, 0.1 s since the chunk's
    w.flush_if_due()
    assert S.open_session(tmp_path / "s").n_events == S.EVENT_CHUNK  # the 10 wait for the next chunk
    assert n_index() > 0  # the index is on schedule
    clock[0] += 0.1  # 0.2 s without an event commit
    w.flush_if_due()
    s = S.open_session(tmp_path / "s")
    assert s.n_events == len(ev) and np.array_equal(s.events(), ev)
    w.close()
