"""The courtside recorder and offline replay, end to end through the fake EVK."""

import os
import signal
import subprocess
import sys
import time
import warnings

import numpy as np

from capture import raw
from capture.replay import main as replay_main
from capture.run import main as run_main
from capture.session import open_session

TRIGGER_FILE = "ros_codecs_evt3_trigger_1280x720.raw"


def test_fake_recording_keeps_every_event_and_byte(shared_raw_dir, tmp_path):
    src = shared_raw_dir / TRIGGER_FILE
    out = tmp_path / "session"
    rc = run_main(["--fake", str(src), "--speed", "max", "--out", str(out), "--viewer", "none",
                   "--no-analysis", "--quiet", "--ball", "tennis", "--crop", "0,0,1280,720"])
    assert rc == 0
    ref = raw.read(src)
    s = open_session(out)
    assert s.attrs["sensor"]["crop"] == [0, 0, 1280, 720]  # the settings the sensor recorded with
    assert s.attrs["closed"] and s.attrs["recording"]["stop_reason"] == "end_of_stream"
    assert s.attrs["ball"] == {"type": "tennis", "diameter_m": 0.067}  # for the report's distances and speeds
    assert np.array_equal(s.events(), ref.events)
    assert np.array_equal(s.triggers(), ref.triggers)
    # the session keeps the exact byte stream behind a RAW header
    header, size = raw.parse_header((out / "events.raw").read_bytes())
    payload = (out / "events.raw").read_bytes()[size:]
    src_bytes = src.read_bytes()
    assert payload == src_bytes[raw.parse_header(src_bytes)[1]:]
    assert np.array_equal(raw.read(out / "events.raw").events, ref.events)
    assert s.attrs["sensor"]["width"] == 1280 and s.attrs["sensor"]["height"] == 720
    # the fake IMX636's die temperature (38 °C) at the start and at the end, from its ADC
    assert abs(s.attrs["sensor"]["temperature_c"] - 38.0) <= 0.1
    assert abs(s.attrs["recording"]["temperature_c"] - 38.0) <= 0.1
    assert abs(s.attrs["sensor"]["illuminance_lux"] - 800.0) <= 2  # and the fake's light level


def test_bad_arguments_give_one_line_errors(tmp_path, capsys):
    assert run_main(["--fake", str(tmp_path / "missing.raw"), "--out", str(tmp_path / "s"),
                     "--viewer", "none"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.raw" in err[0]
    assert replay_main([str(tmp_path / "nothing")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nothing" in err[0]
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x").write_text("keep me")
    assert run_main(["--fake", str(tmp_path / "missing.raw"), "--out", str(tmp_path / "busy"),
                     "--viewer", "none"]) == 1
    assert (tmp_path / "busy" / "x").read_text() == "keep me"


def test_a_crop_past_the_sensor_is_one_line_and_records_nothing(shared_raw_dir, tmp_path, capsys):
    out = tmp_path / "s"
    assert run_main(["--fake", str(shared_raw_dir / TRIGGER_FILE), "--speed", "max", "--out", str(out),
                     "--viewer", "none", "--no-analysis", "--quiet", "--crop", "1200,0,200,100"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "1280" in err[0]
    assert not (out / "events.raw").exists()


def _recorder_with_first_commit(src, out, **popen_kw) -> subprocess.Popen:
    """``python -m capture.run --fake SRC`` at the recorded pace, returned once the store holds events."""
    proc = subprocess.Popen([sys.executable, "-m", "capture.run", "--fake", str(src), "--out", str(out),
                             "--viewer", "none", "--no-analysis", "--quiet"],
                            env=dict(os.environ, PYTHONUNBUFFERED="1"), **popen_kw)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if open_session(out).n_events > 0:
                break
        except Exception:
            pass
        time.sleep(0.01)
    return proc


def test_killed_recorder_leaves_a_replayable_session(shared_raw_dir, tmp_path):
    src = shared_raw_dir / TRIGGER_FILE
    out = tmp_path / "session"
    # the file lasts 1.25 s at its recorded pace: kill in the middle
    proc = _recorder_with_first_commit(src, out, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    s = open_session(out)
    ref = raw.read(src).events
    n = s.n_events
    assert 0 < n < len(ref)
    assert np.array_equal(s.events(), ref[:n])
    assert s.cut_short and "capture.ingest recover" in s.damage
    again = subprocess.run([sys.executable, "-m", "capture.run", "--fake", str(src), "--out", str(out), "--viewer", "none",
                            "--quiet"], capture_output=True, text=True)  # recording into it again: refused, and told why
    assert again.returncode == 1 and "capture.ingest recover" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    with warnings.catch_warnings():  # the kill may cut the RAW file's last word short
        warnings.simplefilter("ignore")
        received = raw.read(out / "events.raw")
    assert replay_main([str(out), "--quiet"]) == 0  # completes the store from the RAW file first
    s = open_session(out)
    assert s.attrs["closed"] and not s.cut_short and s.damage is None
    assert "cut short" in s.attrs["recording"]["stop_reason"]
    assert s.attrs["recording"]["recovered_events"] == len(received.events) - n
    assert np.array_equal(s.events(), received.events)  # every event received, none twice
    assert np.array_equal(s.triggers(), received.triggers)


def test_camera_unplugged_mid_recording_finalises_everything(shared_raw_dir, tmp_path, capsys):
    from capture.evk.fake import FakeEVK
    from capture.gopro import FakeGoPro, GoPro, write_video
    from capture.pipeline.record import RecordSettings, record_session
    from capture.run import print_summary

    src = shared_raw_dir / TRIGGER_FILE
    mp4 = write_video(tmp_path / "clip.mp4", [np.full((48, 64), v, np.uint8) for v in range(0, 200, 20)], 30)
    with FakeGoPro(mp4) as fake:
        settings = RecordSettings(out=tmp_path / "s", backend=FakeEVK(src, disconnect_after_bytes=300_000),
                                  gopro=GoPro(host=fake.host, port=fake.port), quiet=True)
        result = record_session(settings)
        assert not fake.encoding  # the GoPro was stopped
    assert result.error and "Disconnected" in result.error
    s = open_session(tmp_path / "s")
    assert s.attrs["closed"] and s.attrs["recording"]["stop_reason"] == "device error"
    ref = raw.read(src).events
    assert 0 < s.n_events < len(ref) and np.array_equal(s.events(), ref[:s.n_events])
    assert len(list((tmp_path / "s" / "gopro").glob("*.MP4"))) == 1  # the video was downloaded
    print_summary(result)
    assert "failed mid-recording" in capsys.readouterr().out


def test_replay_rejects_bad_options_on_one_line(shared_raw_dir, tmp_path, capsys):
    out = tmp_path / "session"
    assert run_main(["--fake", str(shared_raw_dir / TRIGGER_FILE), "--speed", "max", "--out", str(out),
                     "--viewer", "none", "--no-analysis", "--quiet"]) == 0
    for args in (["--rrd", str(tmp_path)], ["--step-us", "0"]):
        capsys.readouterr()
        assert replay_main([str(out), "--quiet", *args]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("capture.replay: error:")


def test_ctrl_c_stops_cleanly(shared_raw_dir, tmp_path):
    src = shared_raw_dir / TRIGGER_FILE
    out = tmp_path / "session"
    proc = _recorder_with_first_commit(src, out, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    s = open_session(out)
    assert s.attrs["closed"] and s.attrs["recording"]["stop_reason"] == "stop"
    ref = raw.read(src).events
    assert 0 < s.n_events < len(ref)
    assert np.array_equal(s.events(), ref[:s.n_events])
    # the RAW file holds at least every byte the store's events came from
    assert np.array_equal(raw.read(out / "events.raw").events[:s.n_events], s.events())
    assert "stopped: stop" in stdout


def test_live_analysis_gives_way_when_decoding_falls_behind(shared_raw_dir, tmp_path, monkeypatch):
    """While the RAW file waits to be decoded, live batches are skipped (counted), never stored ones."""
    from capture.evk.fake import FakeEVK
    from capture.pipeline import record as rec

    src = shared_raw_dir / TRIGGER_FILE
    ref = raw.read(src).events
    for limit, out in ((-1, "behind"), (1 << 40, "never")):
        monkeypatch.setattr(rec, "LIVE_MAX_BACKLOG_BYTES", limit)
        result = rec.record_session(rec.RecordSettings(out=tmp_path / out, backend=FakeEVK(src), quiet=True))
        assert np.array_equal(open_session(tmp_path / out).events(), ref)
        if limit < 0:
            assert result.skipped_live_events == len(ref)
        else:  # offered to the live analysis (which may still skip a batch when its own queue is full)
            assert result.skipped_live_events < len(ref)


def test_the_status_line_shows_drops_and_time_jumps_as_they_happen(tmp_path, capsys):
    import threading
    from types import SimpleNamespace

    from capture import evk
    from capture.pipeline.live import LiveState
    from capture.pipeline.record import RecordSettings, _Status

    progress = evk.RecordStats(raw_path=tmp_path / "events.raw", overflows=3, dropped_bytes=1_200_000, time_jumps=2,
                               idle_risks=4)
    live = SimpleNamespace(state=LiveState())
    status = _Status(RecordSettings(out=tmp_path), {"events": 0}, live, threading.Event(), period_s=0.01,
                     tick_s=0.005, progress=progress)
    status.start()
    time.sleep(0.1)
    status.done.set()
    status.join()
    err = capsys.readouterr().err
    assert "drops 3 (1.2 MB lost)" in err and "time jumps 2" in err and "possible USB losses 4" in err
