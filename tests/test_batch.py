"""Batch replay on Dask distributed: a real LocalCluster of two worker processes on loopback."""

import os
import shutil

import numpy as np
import pandas as pd
import pytest

distributed = pytest.importorskip("distributed")

from capture import batch as batch_cli  # noqa: E402
from capture.events import Track  # noqa: E402
from capture.pipeline.batch import OneThreadPerWorker, local_cluster, run_batch  # noqa: E402
from capture.pipeline.replay import ReplayOptions, replay  # noqa: E402
from capture.results import session_results  # noqa: E402
from capture.session import create_session, open_session  # noqa: E402
from sim.esim import merge  # noqa: E402

W, H = 480, 320
OPTIONS = ReplayOptions(window_us=2000, max_window_us=8000, step_us=4000, min_events=300, windows_per_unit=3,
                        workers=1)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, two_crossings):
    """Four small sessions: each crossing alone, both, and both mirrored left-right."""
    a, b = two_crossings
    both = merge(a.events, b.events)
    mirrored = both.copy()
    mirrored["x"] = W - 1 - mirrored["x"]
    root = tmp_path_factory.mktemp("season")
    paths = []
    for name, ev in (("a", a.events), ("b", b.events), ("both", both), ("mirrored", mirrored)):
        with create_session(root / name, width=W, height=H) as w:
            w.append_events(ev)
        paths.append(root / name)
    return paths


@pytest.fixture(scope="module")
def replayed(sessions, tmp_path_factory):
    """Each session replayed alone (``capture.pipeline.replay.replay``): its stored track and spin."""
    root = tmp_path_factory.mktemp("alone")
    out = {}
    for p in sessions:
        copy = shutil.copytree(p, root / p.name)
        replay(copy, options=OPTIONS, progress=False)
        s = open_session(copy)
        out[p.name] = (s.track(), s.spin(), session_results(copy))
    out["paths"] = [root / p.name for p in sessions]
    return out


@pytest.fixture(scope="module")
def client():
    with local_cluster(2) as cluster, distributed.Client(cluster) as c:
        c.register_plugin(OneThreadPerWorker())
        yield c


def _copies(sessions, root):
    return [shutil.copytree(p, root / p.name) for p in sessions]


def _assert_as_replayed(paths, result, replayed):
    """Every session's store and season rows are those of replaying it alone."""
    n_windows = 0
    for p in paths:
        track, spin, (flights, windows) = replayed[p.name]
        s = open_session(p)
        for stored, ref in ((s.track(), track), (s.spin(), spin)):
            assert stored.keys() == ref.keys()
            for k in ref:
                np.testing.assert_array_equal(stored[k], ref[k], err_msg=f"{p.name}: {k}")
        for season, own in ((result.flights, flights), (result.windows, windows)):
            rows = season["session"] == str(p.resolve())
            assert rows.sum() == len(own["flight"])
            for k, v in own.items():
                np.testing.assert_array_equal(season[k][rows], v, err_msg=f"{p.name}: {k}")
        n_windows += len(spin["t_start_us"])
    assert n_windows >= 8 * len(paths)


def test_batch_equals_replay_of_each_session_alone_and_a_second_run_skips_all(sessions, replayed, client,
                                                                               tmp_path):
    paths = _copies(sessions, tmp_path)
    result = run_batch(paths, client, OPTIONS, progress=False)
    assert result.analysed == [str(p.resolve()) for p in paths] and not result.skipped and not result.failed
    assert len(Track.from_columns(open_session(paths[2]).track()).flight_ids()) == 2
    _assert_as_replayed(paths, result, replayed)

    stamps = {p: (p / "spin" / "t_start_us" / "zarr.json").stat().st_mtime_ns for p in paths}
    again = run_batch(paths, client, OPTIONS, progress=False)
    assert again.skipped == result.analysed and not again.analysed and not again.failed
    assert {p: (p / "spin" / "t_start_us" / "zarr.json").stat().st_mtime_ns for p in paths} == stamps
    for k in result.flights:
        np.testing.assert_array_equal(again.flights[k], result.flights[k], err_msg=k)

    # sessions that capture.replay analysed with these settings are skipped too
    alone = run_batch(replayed["paths"], client, OPTIONS, progress=False)
    assert len(alone.skipped) == len(paths) and not alone.analysed

    # other settings, or --force: analysed again
    other = ReplayOptions(**{**OPTIONS.__dict__, "step_us": 6000})
    assert run_batch(paths[:1], client, other, progress=False).analysed == result.analysed[:1]
    assert run_batch(paths[:1], client, other, force=True, progress=False).analysed == result.analysed[:1]
    assert run_batch(paths[:1], client, other, progress=False).skipped == result.analysed[:1]


def test_a_worker_killed_mid_batch_loses_only_its_task(sessions, replayed, client, tmp_path):
    marker = tmp_path / "killed"

    class KillOnFirstSpin(distributed.WorkerPlugin):
        """The first worker to start a spin task dies at once (as if killed), once in the test."""

        name = "kill-on-first-spin"

        def transition(self, key, start, finish, **kwargs):
            if finish == "executing" and str(key).startswith("spin_unit") and not marker.exists():
                marker.write_text(str(os.getpid()))
                os._exit(1)

    paths = _copies(sessions, tmp_path)
    client.register_plugin(KillOnFirstSpin())
    try:
        result = run_batch(paths, client, OPTIONS, progress=False)
    finally:
        client.unregister_worker_plugin(KillOnFirstSpin.name)
    assert marker.exists()  # a worker did die mid-batch
    assert int(marker.read_text()) not in client.run(os.getpid).values()
    assert len(result.analysed) == len(paths) and not result.failed
    _assert_as_replayed(paths, result, replayed)
    client.wait_for_workers(2)


def test_a_corrupt_session_is_reported_in_one_line_and_the_others_finish(sessions, replayed, client, tmp_path):
    good = _copies(sessions[:2], tmp_path)
    damaged = shutil.copytree(sessions[2], tmp_path / "damaged")
    (damaged / "events" / "x" / "c" / "0").unlink()
    not_a_session = tmp_path / "empty"
    not_a_session.mkdir()
    notes = []
    result = run_batch([good[0], damaged, not_a_session, good[1]], client, OPTIONS, progress=False,
                       note=notes.append)
    assert result.analysed == [str(p.resolve()) for p in good]
    assert set(result.failed) == {str(damaged.resolve()), str(not_a_session.resolve())}
    assert "events/x chunk c/0" in result.failed[str(damaged.resolve())]
    assert "not a session" in result.failed[str(not_a_session.resolve())]
    assert len(notes) == 2 and all("\n" not in n and n.startswith("batch: ") for n in notes)
    _assert_as_replayed(good, result, replayed)


def test_a_recording_cut_short_is_completed_from_its_raw_file_then_analysed(sessions, replayed, client, tmp_path):
    from capture import raw

    full = open_session(sessions[2]).events()  # "both"
    cut = tmp_path / "both"
    w = create_session(cut, width=W, height=H, attrs={"raw_file": "events.raw"})
    (cut / "events.raw").write_bytes(raw.header_bytes("EVT3", width=W, height=H) + raw.encode(full, width=W, height=H))
    w.append_events(full[:len(full) // 3])
    w.flush()
    del w  # killed: a third of what it received is in the store
    import gc
    gc.collect()
    assert open_session(cut).cut_short
    result = run_batch([cut], client, OPTIONS, progress=False)
    s = open_session(cut)
    assert result.analysed == [str(cut.resolve())] and not s.cut_short
    assert np.array_equal(s.events(), full)
    _assert_as_replayed([cut], result, replayed)  # as the whole session, replayed alone


def test_command_writes_the_season_tables_and_says_what_it_did(sessions, replayed, tmp_path, capsys):
    paths = _copies(sessions[:2], tmp_path)
    out = tmp_path / "season.parquet"
    argv = [*map(str, paths), "--out", str(out), "--workers", "2", "--quiet", "--window-us", "2000",
            "--max-window-us", "8000", "--step-us", "4000"]
    assert batch_cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "2 worker(s)" in printed and "2 analysed, 0 skipped" in printed
    flights = pd.read_parquet(out)
    windows = pd.read_parquet(tmp_path / "season_windows.parquet")
    assert list(flights.columns[:2]) == ["session", "flight"]
    for p in paths:
        own_flights, own_windows = session_results(p)
        assert (flights["session"] == str(p.resolve())).sum() == len(own_flights["flight"]) > 0
        assert (windows["session"] == str(p.resolve())).sum() == len(own_windows["flight"])
    assert batch_cli.main(argv) == 0
    assert "0 analysed, 2 skipped" in capsys.readouterr().out
    assert batch_cli.main([str(tmp_path / "missing"), "--out", str(out)]) == 1
    assert "missing: no such session directory" in capsys.readouterr().err


def test_session_events_read_as_dask_arrays(sessions):
    s = open_session(sessions[2])
    columns = s.events_dask()
    events = s.events()
    assert set(columns) == {"t", "x", "y", "p"}
    for k, col in columns.items():
        assert col.shape == (s.n_events,) and col.dtype == events[k].dtype
        np.testing.assert_array_equal(col.compute(), events[k])
    assert int(columns["x"].sum().compute()) == int(events["x"].astype(np.int64).sum())
