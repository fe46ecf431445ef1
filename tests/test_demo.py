"""The built-in demo end to end (small size): simulate, record through the fakes, analyse, review."""

import contextlib
import io

import numpy as np
import pytest
from rerun.chunk import RrdReader

import capture.pipeline.demo as demo_inputs
from capture.pipeline.demo import spin_summary
from capture.run import main as run_main
from capture.session import open_session


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """``python -m capture.run --demo`` on a shortened rally: exit code, session, printed output."""
    out = tmp_path_factory.mktemp("demo") / "session"
    stdout = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(stdout):
        mp.setattr(demo_inputs, "DEMO_DURATION_S", 0.25)
        rc = run_main(["--demo", "--out", str(out), "--viewer", "none", "--speed", "max", "--quiet"])
    return rc, out, stdout.getvalue()


def test_demo_records_analyses_and_reviews(demo):
    rc, out, printed = demo
    assert rc == 0
    assert "True spin:" in printed and "Error:" in printed and "review.rrd" in printed
    s = open_session(out)
    assert s.attrs["closed"] and s.n_events > 100_000
    assert len(s.triggers()) >= 2  # the sync box's edges reached the trigger input
    assert (out / "events.raw").stat().st_size > 0
    # the GoPro video was downloaded from the fake camera and aligned by the sync box
    frames = s.frames()
    assert frames["video"] is not None and len(frames["t_us"]) > 5
    assert s.attrs["time_sync"]["method"] == "sync_box"
    cam = s.attrs["frame_camera"]  # exposure read from the video's GPMF, not typed in
    assert cam["exposure_source"] == "gpmf" and abs(cam["exposure_s"] - 1 / 240) < 1e-6 and cam["frame_skips"] == 0
    truth_t = np.asarray(s.attrs["demo"]["truth_frame_t_us"])
    assert len(frames["t_us"]) == len(truth_t)
    assert np.max(np.abs(frames["t_us"] - truth_t)) <= 500  # sync-box goal: 0.5 ms
    # ball found and spin estimated against the simulator's truth
    track = s.track()
    assert len(track["t_us"]) > 10
    truth = s.attrs["demo"]
    summary = spin_summary(s.spin(), {"rps": truth["truth_rps"], "axis": truth["truth_axis"]})
    assert summary["n_confident"] >= 3
    assert summary["rps_error_pct"] < 3.0
    assert summary["axis_error_deg"] < 3.0  # a flipped axis would be 180 deg off
    # the flight's image repeats once a turn: stored with the analysis, and the printed table's rate
    period_s, peak, span_s = s.attrs["flight_periods"]["0"]
    assert period_s * truth["truth_rps"] == pytest.approx(1.0, abs=0.01) and span_s > 0.2
    assert s.attrs["flight_spins"] == {}  # its windows give its spin: no whole-flight spin is needed
    header, row = printed.splitlines()[[i for i, line in enumerate(printed.splitlines()) if "period rpm" in line][0]:][:2]
    assert float(row.split()[-3]) == pytest.approx(60 * truth["truth_rps"], rel=0.01)
    # the Rerun recording reads back with the ball and spin entities
    paths, truth_rpm, ball_images = set(), [], []
    for chunk in RrdReader(out / "review.rrd").stream():
        paths.add(str(chunk.entity_path))
        rb = chunk.to_record_batch()
        if str(chunk.entity_path) == "/plots/rpm/truth" and "Scalars:scalars" in rb.schema.names:
            truth_rpm += [v[0] for v in rb.column("Scalars:scalars").to_pylist()]
        if str(chunk.entity_path) == "/ball/image" and "Image:format" in rb.schema.names:
            ball_images += rb.column("Image:format").to_pylist()
    assert any(p.startswith("/events") for p in paths)
    assert any("rps" in p for p in paths)
    assert any("ball3d" in p for p in paths)
    # the simulated truth drawn across the flight; a ball close-up per spin window (recorded | spin removed)
    assert truth_rpm[:2] == [1800.0, 1800.0]
    assert 0 < len(ball_images) <= len(s.spin()["rps"]) and ball_images[0][0]["width"] > 2 * ball_images[0][0]["height"]
    assert "/frames/note" in paths  # the demo has no camera calibration: the GoPro view says why it has no circle


def test_replay_of_the_bare_raw_and_video_reproduces_the_session(demo, tmp_path, capsys):
    from capture.replay import main as replay_main

    _, out, _ = demo
    s = open_session(out)
    video = next((out / "gopro").glob("*.MP4"))
    new = tmp_path / "from_raw"
    rc = replay_main([str(out / "events.raw"), "--mp4", str(video), "--out", str(new), "--quiet",
                      "--led-roi", "8,8,24,24", "--exposure", str(1 / 240), "--rrd", str(tmp_path / "r.rrd"),
                      "--ball", "soccer"])
    assert rc == 0
    r = open_session(new)
    assert r.attrs["ball"] == {"type": "soccer", "diameter_m": 0.22}  # recorded with the new session
    table = capsys.readouterr().out.splitlines()
    head = next(i for i, line in enumerate(table) if line.split()[:2] == ["ball", "flight"])
    assert table[head + 1].split()[0] == "soccer"
    assert np.array_equal(r.events(), s.events()) and np.array_equal(r.triggers(), s.triggers())
    assert np.array_equal(r.frames()["t_us"], s.frames()["t_us"])
    assert np.array_equal(r.spin()["rps"], s.spin()["rps"])  # same inputs, same results
    assert (tmp_path / "r.rrd").stat().st_size > 0
