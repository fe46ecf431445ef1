"""The MP4 box reader on hand-built files: B-frame reordering (ctts), edit lists, 64-bit boxes."""

import struct
from fractions import Fraction

import numpy as np
import pytest

from capture.gopro import MP4Error, video_timing


def box(kind: bytes, payload: bytes) -> bytes:
    return struct.pack(">I4s", 8 + len(payload), kind) + payload


def full(kind: bytes, payload: bytes, version: int = 0) -> bytes:
    return box(kind, struct.pack(">I", version << 24) + payload)


def table(kind, rows, version=0, signed=False):
    fmt = ">Ii" if signed else ">II"
    return full(kind, struct.pack(">I", len(rows)) + b"".join(struct.pack(fmt, *r) for r in rows), version)


def build_mp4(stts, ctts=None, ctts_version=0, elst_media_time=None, timescale=240000, big_mdat=False,
              width=1920, height=1080):
    tkhd = full(b"tkhd", b"\x00" * 72 + struct.pack(">II", width << 16, height << 16))
    mdhd = full(b"mdhd", struct.pack(">IIIIHH", 0, 0, timescale, sum(c * d for c, d in stts), 0, 0))
    hdlr = full(b"hdlr", b"\x00" * 4 + b"vide" + b"\x00" * 12 + b"video\x00")
    stbl = table(b"stts", stts)
    if ctts is not None:
        stbl += table(b"ctts", ctts, version=ctts_version, signed=ctts_version == 1)
    mdia = box(b"mdia", mdhd + hdlr + box(b"minf", box(b"stbl", stbl)))
    trak_parts = tkhd
    if elst_media_time is not None:
        trak_parts += box(b"edts", full(b"elst", struct.pack(">IIiI", 1, 0, elst_media_time, 1 << 16)))
    sound = box(b"trak", box(b"mdia", full(b"hdlr", b"\x00" * 4 + b"soun" + b"\x00" * 13)))
    moov = box(b"moov", sound + box(b"trak", trak_parts + mdia))
    payload = b"\x00" * 64
    mdat = (struct.pack(">I4sQ", 1, b"mdat", 16 + len(payload)) + payload) if big_mdat else box(b"mdat", payload)
    return box(b"ftyp", b"isom\x00\x00\x02\x00") + mdat + moov


def test_b_frames_reordered_and_edit_list_applied(tmp_path):
    # decode order I P B B P: display order 0, 3, 1, 2, 4 (frame units of 1001 ticks)
    d = 1001
    ctts = [(1, 2 * d), (1, 4 * d), (1, 1 * d), (1, 1 * d), (1, 2 * d)]
    p = tmp_path / "b.mp4"
    p.write_bytes(build_mp4([(5, d)], ctts=ctts, elst_media_time=2 * d, big_mdat=True))
    v = video_timing(p)
    np.testing.assert_array_equal(v.pts, np.arange(5) * d)
    assert v.fps == Fraction(240000, 1001) and v.timescale == 240000 and v.duration == 5 * d
    assert (v.width, v.height) == (1920, 1080)


def test_negative_ctts_version_1(tmp_path):
    d = 512
    ctts = [(1, 0), (1, 2 * d), (1, -d), (1, -d)]
    p = tmp_path / "n.mp4"
    p.write_bytes(build_mp4([(4, d)], ctts=ctts, ctts_version=1, timescale=15360))
    np.testing.assert_array_equal(video_timing(p).pts, np.arange(4) * d)
    assert video_timing(p).fps == 30


def test_variable_frame_durations_kept(tmp_path):
    p = tmp_path / "vfr.mp4"
    p.write_bytes(build_mp4([(3, 1000), (1, 1500), (2, 1000)], timescale=60000))
    np.testing.assert_array_equal(video_timing(p).pts, [0, 1000, 2000, 3000, 4500, 5500])
    assert video_timing(p).fps == 60


def test_malformed_files_name_file_and_offset(tmp_path):
    good = build_mp4([(5, 1001)])
    p = tmp_path / "trunc.mp4"
    p.write_bytes(good[:-20])
    with pytest.raises(MP4Error, match=r"trunc\.mp4: bad box size .* at byte \d+"):
        video_timing(p)
    q = tmp_path / "nomoov.mp4"
    q.write_bytes(good[: good.index(b"moov") - 4])
    with pytest.raises(MP4Error, match="no 'moov' box"):
        video_timing(q)
    r = tmp_path / "ctts.mp4"
    r.write_bytes(build_mp4([(5, 1001)], ctts=[(3, 0)]))
    with pytest.raises(MP4Error, match="'ctts' covers 3 samples, 'stts' 5"):
        video_timing(r)
