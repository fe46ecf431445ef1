"""GPMF metadata: KLV reading and writing, the MP4 metadata track, per-frame exposure."""

import struct

import numpy as np
import pytest

from capture.gopro import gpmf, read_video, video_timing, write_video
from capture.gopro.mp4 import MP4Error, add_gpmf_track, gpmf_samples


def test_klv_round_trip_nested_scaled_and_padded():
    data = gpmf.build("DEVC", "\0", gpmf.build("DVNM", "c", b"Cam") + gpmf.build(
        "STRM", "\0", gpmf.build("SCAL", "S", [1000]) + gpmf.build("SHUT", "S", [1, 2, 3])))
    assert len(data) % 4 == 0
    (devc,) = gpmf.parse(data)
    assert devc.key == "DEVC" and devc.type == "\0"
    name, strm = devc.value
    assert name.value == b"Cam"
    assert [i.key for i in strm.value] == ["SCAL", "SHUT"] and list(strm.value[1].value) == [1, 2, 3]
    meta = gpmf.frame_metadata([data], np.array([0.0]), np.array([0.03]))
    np.testing.assert_allclose(meta.exposure_s, [0.001, 0.002, 0.003])  # SCAL divides
    np.testing.assert_allclose(meta.t_s, [0.0, 0.01, 0.02])


def test_malformed_payload_is_named():
    bad = struct.pack(">4scBH", b"SHUT", b"f", 4, 100) + b"\0" * 8
    with pytest.raises(gpmf.GPMFError, match=r"'SHUT'|b'SHUT'"):
        gpmf.parse(bad)


def test_metadata_track_in_an_mp4_leaves_the_video_untouched(tmp_path):
    frames = [np.full((32, 48), 10 * i, np.uint8) for i in range(20)]
    path = write_video(tmp_path / "clip.mp4", frames, fps=240)
    before = video_timing(path)
    exposure = np.linspace(0.5e-3, 2.0e-3, 20)  # auto-exposure ramping over the clip
    skips = np.zeros(20, np.uint16)
    skips[7] = 1
    payloads = [gpmf.camera_payload(exposure[i:i + 10], iso=np.full(10, 200), frame_skips=skips[i:i + 10],
                                    readout=4.5) for i in (0, 10)]
    add_gpmf_track(path, payloads, 10 / 240)
    assert np.array_equal(video_timing(path).pts, before.pts)
    assert read_video(path).n_frames == 20
    got, start, dur = gpmf_samples(path)
    assert got == payloads
    np.testing.assert_allclose(start, [0, 10 / 240], atol=1e-4)
    meta = gpmf.frame_metadata(got, start, dur)
    np.testing.assert_allclose(meta.exposure_at(np.arange(20) / 240), exposure, rtol=1e-6)
    assert list(np.nonzero(meta.frame_skips)[0]) == [7] and meta.iso[0] == 200
    assert meta.readout == pytest.approx(4.5)
    with open(path, "ab") as f:
        f.write(struct.pack(">I4s", 8, b"free"))
    with pytest.raises(MP4Error, match="'moov' is not the last box"):
        add_gpmf_track(path, payloads, 10 / 240)


def test_a_clips_last_payload_is_shorter_and_its_frames_keep_their_exposure(tmp_path):
    """A clip of 25 frames with payloads of 10 frames: the last covers 5 frames' time (as a camera
    ends a clip); each frame's exposure is read back at its own time."""
    frames = [np.full((32, 48), 10 * i, np.uint8) for i in range(25)]
    path = write_video(tmp_path / "clip.mp4", frames, fps=240)
    exposure = np.linspace(0.5e-3, 2.0e-3, 25)
    payloads = [gpmf.camera_payload(exposure[i:i + 10], iso=np.full(len(exposure[i:i + 10]), 200),
                                    frame_skips=np.zeros(len(exposure[i:i + 10]), np.uint16)) for i in (0, 10, 20)]
    add_gpmf_track(path, payloads, [10 / 240, 10 / 240, 5 / 240])
    got, start, dur = gpmf_samples(path)
    np.testing.assert_allclose(dur, [10 / 240, 10 / 240, 5 / 240], atol=1e-4)
    meta = gpmf.frame_metadata(got, start, dur)
    np.testing.assert_allclose(meta.exposure_at(np.arange(25) / 240), exposure, rtol=1e-6)


def test_each_chapters_frames_take_their_own_chapters_exposures_and_unusable_values_are_said():
    from types import SimpleNamespace

    from capture.ingest import _recorded_exposures

    video = SimpleNamespace(n_frames=12, chapter_start=np.array([0, 4, 8]), t_s=np.arange(12) / 240.0, fps=240.0)
    ms = 1e-3
    first = gpmf.FrameMetadata(np.arange(4) / 240.0, np.array([1.0, 0.0, np.nan, 2.0]) * ms, np.zeros(0), np.zeros(0), None)
    second = gpmf.FrameMetadata(np.arange(4) / 240.0, np.array([3.0, 3.5, 3.0, 3.5]) * ms, np.zeros(0), np.zeros(0), None)
    notes = []
    got = _recorded_exposures(video, [first, second, None], notes)  # the third chapter has no metadata
    median = np.median([1.0, 2.0, 3.0, 3.5, 3.0, 3.5]) * ms
    np.testing.assert_allclose(got, [1 * ms, median, median, 2 * ms, 3 * ms, 3.5 * ms, 3 * ms, 3.5 * ms] + [median] * 4)
    assert len(notes) == 1 and notes[0].startswith("6 of 12 frames without a usable exposure")
    assert _recorded_exposures(video, [None, None, None], []) is None
