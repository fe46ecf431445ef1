"""Small ISO-BMFF (MP4) box reader: per-frame presentation times of the video track.

Only the boxes needed for timing are read (``moov/trak/mdia/{mdhd,hdlr,minf/stbl/{stts,ctts}}``
and ``edts/elst``); the media data (``mdat``) is skipped by seeking, so a 4 GB chapter costs a
few kilobytes of reading.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

_CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl", b"edts"}


class MP4Error(ValueError):
    """The file is not an MP4 this reader understands (named file and byte offset)."""


@dataclass(frozen=True)
class VideoTiming:
    """Timing of one MP4 file's video track.

    Attributes
    ----------
    pts : ndarray of int64, shape (N,)
        Presentation time of each frame in display order, in ``timescale`` ticks, edit list applied
        (the first displayed frame is at the edit's start, normally 0).
    timescale : int
        Ticks per second of the track (``mdhd``).
    duration : int
        Track duration in ticks (sum of the sample durations).
    width, height : int
        Frame size in pixels from the track header (0 when absent).
    """

    pts: np.ndarray
    timescale: int
    duration: int
    width: int
    height: int

    @property
    def t_s(self) -> np.ndarray:
        """Frame presentation times in seconds, shape (N,)."""
        return self.pts / float(self.timescale)

    @property
    def fps(self) -> Fraction:
        """Nominal frame rate as an exact fraction (frames per second).

        The most common sample duration ``d`` gives ``timescale / d`` (e.g. 60000/1001 for 59.94);
        a one-frame track's is its one sample's duration, the track's duration.
        """
        if len(self.pts) == 1 and self.duration > 0:
            return Fraction(self.timescale, self.duration)
        if len(self.pts) < 2:
            raise MP4Error("frame rate needs at least one frame of known duration")
        d = np.diff(np.sort(self.pts))
        vals, counts = np.unique(d, return_counts=True)
        return Fraction(self.timescale, int(vals[np.argmax(counts)]))


def _boxes(f, start: int, end: int, path: Path):
    """Yield (type, payload_offset, payload_end) of the boxes in [start, end)."""
    pos = start
    while pos + 8 <= end:
        f.seek(pos)
        head = f.read(8)
        if len(head) < 8:
            raise MP4Error(f"{path}: truncated box header at byte {pos}")
        size, kind = struct.unpack(">I4s", head)
        hdr = 8
        if size == 1:
            ext = f.read(8)
            if len(ext) < 8:
                raise MP4Error(f"{path}: truncated 64-bit box size at byte {pos}")
            size = struct.unpack(">Q", ext)[0]
            hdr = 16
        elif size == 0:
            size = end - pos
        if size < hdr or pos + size > end:
            raise MP4Error(f"{path}: bad box size {size} for {kind!r} at byte {pos}")
        yield kind, pos + hdr, pos + size
        pos += size


def _read(f, off: int, n: int, path: Path) -> bytes:
    f.seek(off)
    b = f.read(n)
    if len(b) != n:
        raise MP4Error(f"{path}: truncated box payload at byte {off}")
    return b


def _table(f, off: int, end: int, path: Path, fields: int) -> np.ndarray:
    """Full-box table of ``fields`` uint32 per entry after version/flags + entry count."""
    vf, count = struct.unpack(">II", _read(f, off, 8, path))
    n = count * fields * 4
    if off + 8 + n > end:
        raise MP4Error(f"{path}: table at byte {off} claims {count} entries, more than its box holds")
    arr = np.frombuffer(_read(f, off + 8, n, path), dtype=">u4").reshape(count, fields)
    return arr, vf >> 24


def _track(f, off: int, end: int, path: Path) -> dict:
    info: dict = {}
    stack = [(off, end)]
    while stack:
        s, e = stack.pop()
        for kind, p0, p1 in _boxes(f, s, e, path):
            if kind in _CONTAINERS:
                stack.append((p0, p1))
            elif kind == b"hdlr":
                info["handler"] = _read(f, p0 + 8, 4, path)
            elif kind == b"mdhd":
                version = _read(f, p0, 1, path)[0]
                if version == 1:
                    ts, dur = struct.unpack(">IQ", _read(f, p0 + 20, 12, path))
                else:
                    ts, dur = struct.unpack(">II", _read(f, p0 + 12, 8, path))
                info["timescale"], info["mdhd_duration"] = ts, dur
            elif kind == b"tkhd":
                version = _read(f, p0, 1, path)[0]
                wh = _read(f, p1 - 8, 8, path)
                w, h = struct.unpack(">II", wh)
                info["width"], info["height"] = w >> 16, h >> 16
                info["tkhd_version"] = version
            elif kind == b"stts":
                info["stts"] = _table(f, p0, p1, path, 2)[0]
            elif kind == b"ctts":
                arr, version = _table(f, p0, p1, path, 2)
                offs = arr[:, 1].astype(np.uint32)
                info["ctts"] = (arr[:, 0].astype(np.int64),
                                offs.view(np.int32).astype(np.int64) if version == 1 else offs.astype(np.int64))
            elif kind == b"elst":
                version = _read(f, p0, 1, path)[0]
                count = struct.unpack(">I", _read(f, p0 + 4, 4, path))[0]
                size = 20 if version == 1 else 12
                entries = []
                for i in range(count):
                    raw = _read(f, p0 + 8 + i * size, size, path)
                    if version == 1:
                        seg, mt = struct.unpack(">Qq", raw[:16])
                    else:
                        seg, mt = struct.unpack(">Ii", raw[:8])
                    entries.append((seg, mt))
                info["elst"] = entries
    return info


def video_timing(path) -> VideoTiming:
    """Read the video track's per-frame presentation times from an MP4/MOV file.

    Parameters
    ----------
    path : str or Path
        The MP4 file.

    Returns
    -------
    VideoTiming
        Presentation times in display order (``stts`` decode deltas + ``ctts`` offsets, minus the
        edit list's media start), timescale, duration and frame size.

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist.
    MP4Error
        When the file has no ``moov`` box or no video track, or a box is malformed.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video file not found: {path}")
    size = path.stat().st_size
    with open(path, "rb") as f:
        moov = next(((p0, p1) for kind, p0, p1 in _boxes(f, 0, size, path) if kind == b"moov"), None)
        if moov is None:
            raise MP4Error(f"{path}: no 'moov' box (not an MP4, or recording not finalised)")
        for kind, p0, p1 in _boxes(f, *moov, path):
            if kind != b"trak":
                continue
            info = _track(f, p0, p1, path)
            if info.get("handler") != b"vide":
                continue
            if "stts" not in info or "timescale" not in info:
                raise MP4Error(f"{path}: video track without 'stts' or 'mdhd'")
            stts = info["stts"]
            deltas = np.repeat(stts[:, 1].astype(np.int64), stts[:, 0].astype(np.int64))
            dts = np.concatenate([[0], np.cumsum(deltas)[:-1]]) if len(deltas) else deltas
            pts = dts.copy()
            if "ctts" in info:
                counts, offs = info["ctts"]
                c = np.repeat(offs, counts)
                if len(c) != len(pts):
                    raise MP4Error(f"{path}: 'ctts' covers {len(c)} samples, 'stts' {len(pts)}")
                pts = pts + c
            media_start = next((mt for seg, mt in info.get("elst", []) if mt >= 0), 0)
            pts = np.sort(pts) - media_start
            return VideoTiming(pts=pts, timescale=int(info["timescale"]), duration=int(deltas.sum()),
                               width=int(info.get("width", 0)), height=int(info.get("height", 0)))
    raise MP4Error(f"{path}: no video track")
