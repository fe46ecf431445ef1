"""The session store under failure: a full disk, damaged stores, a kill during creation.

Nothing received is lost silently: a store either holds every event it was given, or it is
closed and says which are missing (``events.attrs["lost"]``); a damaged store is refused with
one line naming the damaged column and rows; out-of-order events are left out and placed.
"""

import errno
import json
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import zarr

from capture import session as S
from capture.events import in_order_mask, make_events, make_triggers
from capture.replay import main as replay_main


def _events(n, seed=0, t0=0, span_us=2_000_000):
    rng = np.random.default_rng(seed)
    t = t0 + np.sort(rng.integers(0, span_us, n))
    return make_events(t, rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n))


class SmallDisk:
    """A disk of ``capacity`` bytes under ``root``: a Zarr file write that would make the files
    under ``root`` larger than that fails with ENOSPC, as on a full file system (deleting files,
    such as the writer's reserve, makes room again)."""

    def __init__(self, monkeypatch, root, capacity):
        self.root, self.capacity, self.failures = root, capacity, 0
        real_put = zarr.storage._local._put

        def size(f, written):
            try:
                return f.stat().st_size if f.is_file() and f != written else 0
            except FileNotFoundError:  # a file being renamed by a writer beside this one
                return 0

        def put(path, value, exclusive=False):
            used = sum(size(f, path) for f in self.root.rglob("*"))
            if used + len(value.as_buffer_like()) > self.capacity:
                self.failures += 1
                raise OSError(errno.ENOSPC, "No space left on device", str(path))
            return real_put(path, value, exclusive=exclusive)

        monkeypatch.setattr(zarr.storage._local, "_put", put)


def _assert_prefix_or_marked(path, source):
    """The store's events are an exact prefix of ``source``, and every event after the prefix
    is accounted for as lost in the closed store."""
    s = S.open_session(path)
    assert s.attrs["closed"]
    got = s.events()
    assert np.array_equal(got, source[:len(got)])
    lost = s.root["events"].attrs.get("lost")
    if len(got) < len(source):
        assert lost is not None and lost[0] == len(got) and lost[2] == len(source) - len(got)
        assert lost[1] == int(source["t"][len(got)])
        assert "were not stored" in s.damage
    else:
        assert lost is None
    return s


@pytest.mark.parametrize("room", [30_000, 150_000, 400_000, 900_000, 3_000_000])
def test_disk_full_leaves_a_closed_exact_prefix_marked_with_what_is_missing(tmp_path, monkeypatch, room):
    """``room``: bytes free beside the writer's reserve (the last case never fills)."""
    monkeypatch.setattr(S, "EVENT_CHUNK", 1 << 14)
    src = _events(200_000)
    disk = SmallDisk(monkeypatch, tmp_path, S.RESERVE_BYTES + room)
    w = S.create_session(tmp_path / "s", width=640, height=480, flush_interval_s=0.0)
    errors = []
    for i in range(0, len(src), 5000):
        for append, rows in ((w.append_events, src[i:i + 5000]),
                             (w.append_triggers, make_triggers([int(src["t"][i])], [0], [1]))):
            try:
                append(rows)
            except S.SessionWriteError as exc:  # raised once; later batches are held
                errors.append(str(exc))
    assert len(errors) == (1 if disk.failures else 0)
    try:
        w.close()
        closed_ok = True
    except S.SessionWriteError as exc:
        closed_ok = False
        assert "could not be stored" in str(exc) and "\n" not in str(exc)
    assert disk.failures > 0 or closed_ok
    s = _assert_prefix_or_marked(tmp_path / "s", src)
    assert closed_ok == (s.n_events == len(src))
    n_trig = len(s.triggers())
    trig_lost = s.root["triggers"].attrs.get("lost")
    assert n_trig + (trig_lost[2] if trig_lost else 0) == len(range(0, len(src), 5000))
    assert not (tmp_path / "s" / S.RESERVE_NAME).exists()


def test_disk_full_at_creation_is_one_clean_error_and_the_directory_is_reusable(tmp_path, monkeypatch):
    SmallDisk(monkeypatch, tmp_path, S.RESERVE_BYTES + 2000)
    with pytest.raises(OSError, match="No space left"):
        S.create_session(tmp_path / "s", width=640, height=480)
    assert S.unfinished_session(tmp_path / "s")
    monkeypatch.undo()
    S.create_session(tmp_path / "s", width=640, height=480).close()
    assert S.open_session(tmp_path / "s").n_events == 0


def test_write_error_then_room_again_stores_everything(tmp_path, monkeypatch):
    """Events buffered before a failed write are retried: when the close finds room, the
    store is whole."""
    src = _events(50_000, seed=1)
    w = S.create_session(tmp_path / "s", width=640, height=480, flush_interval_s=0.0)
    w.append_events(src[:20_000])
    real_put = zarr.storage._local._put

    def full(path, value, exclusive=False):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(zarr.storage._local, "_put", full)
    with pytest.raises(S.SessionWriteError, match="No space left"):
        w.append_events(src[20_000:30_000])
    w.append_events(src[30_000:])  # held, no second error
    assert w.n_events == len(src)
    monkeypatch.setattr(zarr.storage._local, "_put", real_put)
    w.close()
    s = _assert_prefix_or_marked(tmp_path / "s", src)
    assert s.n_events == len(src) and s.damage is None


def test_out_of_order_events_are_left_out_counted_and_placed(tmp_path):
    src = _events(300_000, seed=2)
    bad = src.copy()
    bad["t"][100_000:100_003] += 2048  # a corrupted TIME_LOW bit: 3 events 2 ms ahead
    bad["t"][200_000:200_010] -= 1024  # 10 events 1 ms back
    with S.create_session(tmp_path / "s", width=640, height=480) as w:
        for i in range(0, len(bad), 7000):  # the damage falls inside and across batches
            w.append_events(bad[i:i + 7000])
    s = S.open_session(tmp_path / "s")
    got = s.events()
    assert np.all(np.diff(got["t"]) >= 0)
    runs = s.root["events"].attrs["out_of_order"]
    assert s.root["events"].attrs["n_out_of_order"] == 13 == sum(r[2] for r in runs)
    # placing: removing each run at its index from the stream gives exactly the store
    keep = np.ones(len(bad), bool)
    removed = 0
    for index, t_at, k in runs:
        keep[index + removed:index + removed + k] = False
        assert t_at == int(got["t"][index - 1])
        removed += k
    assert np.array_equal(got, bad[keep])
    assert not keep[100_000:100_003].any() and not keep[200_000:200_010].any()
    assert "13 events left out as out of time order" in s.damage


def test_in_order_mask_leaves_out_the_fewest_of_a_local_run():
    t = np.arange(1000, dtype=np.int64) * 3
    rng = np.random.default_rng(3)
    for _ in range(200):
        u = t.copy()
        i, k = rng.integers(0, 990), rng.integers(1, 8)
        u[i:i + k] += rng.choice([-1, 1]) * (1 << rng.integers(4, 12))
        keep = in_order_mask(u)
        assert np.all(np.diff(u[keep]) >= 0)
        assert (~keep).sum() <= k  # the damaged run, never the good events around it
    keep = in_order_mask(t, floor_us=30)
    assert (~keep).sum() == 10 and np.all(t[keep] >= 30)


# -- damaged stores: one line, exit 1, the column and rows named ----------------------------

def _edit_json(p, edit):
    d = json.loads(p.read_text())
    edit(d["attributes"])
    p.write_text(json.dumps(d))


def _flip(p, at=40):
    b = bytearray(p.read_bytes())
    b[at] ^= 4
    p.write_bytes(bytes(b))


DAMAGE = {
    "t chunk deleted": (lambda p: (p / "events/t/c/1").unlink(), "events/t chunk c/1 (rows 4096..8191) is missing"),
    "x chunks deleted": (lambda p: [q.unlink() for q in (p / "events/x/c").iterdir()], "events/x chunk c/0"),
    "chunk replaced by a directory": (lambda p: ((p / "events/y/c/2").unlink(), (p / "events/y/c/2").mkdir()),
                                      "events/y chunk c/2"),
    "events/ deleted": (lambda p: shutil.rmtree(p / "events"), "the events/ table is missing"),
    "triggers/ deleted": (lambda p: shutil.rmtree(p / "triggers"), "the triggers/ table is missing"),
    "n_committed = -5": (lambda p: _edit_json(p / "events/zarr.json", lambda a: a.update(n_committed=-5)),
                         "events/ n_committed = -5"),
    "n_committed past the data": (lambda p: _edit_json(p / "events/zarr.json", lambda a: a.update(n_committed=10**7)),
                                  "events/t holds 20000 rows, 10000000 are committed"),
    "n_committed missing": (lambda p: _edit_json(p / "events/zarr.json", lambda a: a.pop("n_committed")),
                            "events/ n_committed = None"),
    "truncated chunk": (lambda p: (p / "events/t/c/1").write_bytes((p / "events/t/c/1").read_bytes()[:30]),
                        "events/t rows 4096..8191 cannot be read"),
    "garbled chunk": (lambda p: (p / "events/x/c/3").write_bytes((p / "events/x/c/3").read_bytes()[::-1]),
                      "events/x rows 12288..16383 cannot be read"),
    "one flipped bit": (lambda p: _flip(p / "events/p/c/2"), "events/p rows 8192..12287 cannot be read"),
    "root zarr.json missing": (lambda p: (p / "zarr.json").unlink(), "root zarr.json is missing"),
    "column zarr.json missing": (lambda p: (p / "events/t/zarr.json").unlink(), "column events/t is missing"),
    "root attribute missing": (lambda p: _edit_json(p / "zarr.json", lambda a: a.pop("width")),
                               "root attribute width = None"),
    "column deleted": (lambda p: shutil.rmtree(p / "events/p"), "column events/p is missing"),
    "index deleted": (lambda p: shutil.rmtree(p / "index"), "the index/ table is missing"),
}


@pytest.fixture
def small_session(tmp_path, monkeypatch):
    monkeypatch.setattr(S, "EVENT_CHUNK", 1 << 12)
    path = tmp_path / "s"
    with S.create_session(path, width=640, height=480) as w:
        w.append_events(_events(20_000, seed=4))
        w.append_triggers(make_triggers([1000, 2000], [0, 0], [1, 0]))
    return path


@pytest.mark.parametrize("case", list(DAMAGE))
def test_replay_of_a_damaged_store_is_one_line_and_exit_1(small_session, case, capsys):
    damage, expected = DAMAGE[case]
    damage(small_session)
    rc = replay_main([str(small_session), "--quiet", "--workers", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1 and err[0].startswith("capture.replay: error: "), err
    assert expected in err[0]
    assert "Traceback" not in err[0]


def test_replay_of_the_undamaged_store_succeeds(small_session, capsys):
    assert replay_main([str(small_session), "--quiet", "--workers", "1"]) == 0


def test_a_store_without_checksums_still_opens(tmp_path, monkeypatch):
    """Stores written before the checksums (and skipping all-zero chunks) read as before."""
    from zarr.codecs import BloscCodec

    monkeypatch.setattr(S, "_codecs", lambda name, dtype: (None, BloscCodec(cname="zstd")))
    ev = _events(5000, seed=5)
    ev["p"] = 0  # all-zero chunks are not written by the older writer
    with zarr.config.set({"array.write_empty_chunks": False}):
        with S.create_session(tmp_path / "s", width=640, height=480) as w:
            w.append_events(ev)
    assert not (tmp_path / "s/events/p/c").exists()
    s = S.open_session(tmp_path / "s")
    assert np.array_equal(s.events(), ev)


# -- a kill while the session is being created ----------------------------------------------

CREATE_AND_DIE = textwrap.dedent("""
    import os, sys, zarr
    from capture import session as S
    real = zarr.create_group
    def create_group(store, **kw):
        if str(store) == sys.argv[1]:
            os._exit(9)  # killed just before the root's metadata is written
        return real(store, **kw)
    zarr.create_group = create_group
    S.create_session(sys.argv[1], width=640, height=480)
""")


def test_kill_during_creation_leaves_a_directory_named_and_reusable(tmp_path):
    path = tmp_path / "s"
    rc = subprocess.run([sys.executable, "-c", CREATE_AND_DIE, str(path)]).returncode
    assert rc == 9 and (path / "events").is_dir() and not (path / "zarr.json").exists()
    with pytest.raises(S.SessionError, match="unfinished session .* record into it again"):
        S.open_session(path)
    assert S.unfinished_session(path)
    with S.create_session(path, width=640, height=480) as w:  # reused without --overwrite
        w.append_events(_events(10, seed=6))
    assert S.open_session(path).n_events == 10


def test_a_commit_that_reaches_the_disk_and_still_fails_keeps_its_rows(tmp_path, monkeypatch):
    """A count written and then reported as failed (the disk filled up meanwhile, and only
    metadata that shrinks a column still fits): the rows it counts are never trimmed away, so
    the store still opens with an exact prefix."""
    src = _events(50_000, seed=2)
    w = S.create_session(tmp_path / "s", width=640, height=480, flush_interval_s=0.0)
    w.append_events(src[:20_000])
    real_put = zarr.storage._local._put
    full = []

    def put(path, value, exclusive=False):
        shrinking = path.name == "zarr.json" and path.parent.parent.name == "index"  # an index column resized
        if full and not shrinking:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        if path.name == "zarr.json" and path.parent.name == "index" and b"n_committed" in bytes(value.as_buffer_like()):
            real_put(path, value, exclusive=exclusive)  # on disk, and then the disk is full
            full.append(path)
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real_put(path, value, exclusive=exclusive)

    monkeypatch.setattr(zarr.storage._local, "_put", put)
    with pytest.raises(S.SessionWriteError, match="No space left"):
        w.append_events(src[20_000:])
    with pytest.raises(OSError, match="No space left"):
        w.close()
    assert full
    monkeypatch.setattr(zarr.storage._local, "_put", real_put)
    s = S.open_session(tmp_path / "s")  # not "damaged: index/... holds fewer rows than committed"
    got = s.events()
    assert len(got) >= 20_000 and np.array_equal(got, src[:len(got)])
