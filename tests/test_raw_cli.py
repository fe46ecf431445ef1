"""python -m capture.raw info and python -m capture.ingest raw on real files, into a real session store."""

import subprocess
import sys
from pathlib import Path

import numpy as np

import capture.raw as raw
from capture.ingest import main as ingest_main
from capture.raw.cli import main
from capture.session import Session

NAME = "ros_codecs_evt3_trigger_1280x720.raw"


def test_info_prints_header_counts_and_rate(shared_raw_dir, capsys):
    assert main(["info", str(shared_raw_dir / NAME)]) == 0
    out = capsys.readouterr().out
    assert "format: EVT3" in out and "width: 1280" in out and "height: 720" in out
    assert "events: 82469" in out and "triggers: 2" in out
    assert "duration_us: 1251317" in out
    assert f"rate_ev_s: {round(82469 / 1.251317)}" in out
    assert "geometry: 1280x720" in out


def test_ingest_raw_writes_session_with_events_triggers_and_header(shared_raw_dir, tmp_path):
    session_dir = tmp_path / "s1"
    assert ingest_main(["raw", str(shared_raw_dir / NAME), str(session_dir), "--quiet", "--ball", "tennis"]) == 0
    s = Session(session_dir)
    assert s.attrs["ball"] == {"type": "tennis", "diameter_m": 0.067}
    r = raw.read(shared_raw_dir / NAME)
    assert (s.width, s.height) == (1280, 720)
    np.testing.assert_array_equal(s.events(), r.events)
    np.testing.assert_array_equal(s.triggers(), r.triggers)
    assert s.attrs["sensor"]["format"] == "EVT3"
    assert s.attrs["sensor"]["raw_header"]["geometry"] == "1280x720"
    assert s.attrs["raw_source"]["stats"]["events"] == 82469
    assert s.attrs["raw_source"]["damage"] is None
    assert ingest_main(["raw", str(shared_raw_dir / NAME), str(tmp_path / "s3"), "--quiet",
                        "--ball-diameter", "-1"]) == 1  # a wrong diameter: one line, no session
    assert not (tmp_path / "s3").exists()


def test_ingest_raw_refuses_existing_session_and_bad_file(shared_raw_dir, tmp_path, capsys):
    session_dir = tmp_path / "s2"
    session_dir.mkdir()
    (session_dir / "keep.txt").write_text("x")
    assert ingest_main(["raw", str(shared_raw_dir / NAME), str(session_dir), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already exists" in err[0]
    empty = tmp_path / "empty.raw"
    empty.write_bytes(b"")
    assert main(["info", str(empty)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "empty.raw: empty file" in err[0]


def test_module_entry_point_runs(shared_raw_dir):
    out = subprocess.run([sys.executable, "-m", "capture.raw", "info",
                          str(shared_raw_dir / "expelliarmus_evt3_pedestrians_cut_1280x720.raw")],
                         capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert "events: 5000" in out.stdout
