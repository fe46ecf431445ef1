"""Small ISO-BMFF (MP4) box reader: per-frame presentation times of the video track, and the
samples of GoPro's GPMF metadata track.

Only the boxes needed for timing are read (``moov/trak/mdia/{mdhd,hdlr,minf/stbl/{stts,ctts}}``
and ``edts/elst``); the media data (``mdat``) is skipped by seeking, so a 4 GB chapter costs a
few kilobytes of reading. :func:`gpmf_samples` reads the ``gpmd`` track's samples (sizes,
chunk offsets, sample-to-chunk); :func:`add_gpmf_track` appends such a track to an MP4 whose
``moov`` comes last (what the simulator and the fake camera serve).
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
            elif kind == b"stsd":
                info["codec"] = _read(f, p0 + 12, 4, path)
            elif kind == b"stsz":
                fixed, count = struct.unpack(">II", _read(f, p0 + 4, 8, path))
                if fixed:
                    info["stsz"] = np.full(count, fixed, np.int64)
                else:
                    if p0 + 12 + 4 * count > p1:
                        raise MP4Error(f"{path}: 'stsz' at byte {p0} claims {count} entries, more than its box holds")
                    info["stsz"] = np.frombuffer(_read(f, p0 + 12, 4 * count, path), ">u4").astype(np.int64)
            elif kind == b"stsc":
                info["stsc"] = _table(f, p0, p1, path, 3)[0].astype(np.int64)
            elif kind == b"stco":
                info["stco"] = _table(f, p0, p1, path, 1)[0][:, 0].astype(np.int64)
            elif kind == b"co64":
                count = struct.unpack(">I", _read(f, p0 + 4, 4, path))[0]
                info["stco"] = np.frombuffer(_read(f, p0 + 8, 8 * count, path), ">u8").astype(np.int64)
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


def _sample_offsets(info: dict, path: Path) -> np.ndarray:
    """File offset of each sample from its chunk offsets, sample-to-chunk map and sizes."""
    sizes, chunks, stsc = info["stsz"], info["stco"], info["stsc"]
    per_chunk = np.zeros(len(chunks), np.int64)
    for i, (first, n, _) in enumerate(stsc):
        last = stsc[i + 1][0] - 1 if i + 1 < len(stsc) else len(chunks)
        per_chunk[first - 1:last] = n
    if per_chunk.sum() != len(sizes):
        raise MP4Error(f"{path}: sample-to-chunk map covers {per_chunk.sum()} samples, 'stsz' {len(sizes)}")
    chunk_of = np.repeat(np.arange(len(chunks)), per_chunk)
    first_in_chunk = np.concatenate([[0], np.cumsum(per_chunk)[:-1]])
    within = np.cumsum(sizes) - sizes - (np.cumsum(sizes) - sizes)[first_in_chunk[chunk_of]]
    return chunks[chunk_of] + within


def gpmf_samples(path):
    """The GPMF samples of a GoPro MP4: ``(payloads, start_s, duration_s)``, or None without a
    ``gpmd`` track.

    Raises
    ------
    MP4Error
        When the track's tables are malformed or point past the file.
    """
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as f:
        moov = next(((p0, p1) for kind, p0, p1 in _boxes(f, 0, size, path) if kind == b"moov"), None)
        if moov is None:
            raise MP4Error(f"{path}: no 'moov' box (not an MP4, or recording not finalised)")
        for kind, p0, p1 in _boxes(f, *moov, path):
            if kind != b"trak":
                continue
            info = _track(f, p0, p1, path)
            if info.get("codec") != b"gpmd":
                continue
            if not all(k in info for k in ("stsz", "stco", "stsc", "stts", "timescale")):
                raise MP4Error(f"{path}: GPMF track without its sample tables")
            offsets = _sample_offsets(info, path)
            stts = info["stts"]
            dur = np.repeat(stts[:, 1].astype(np.int64), stts[:, 0].astype(np.int64))
            if len(dur) != len(offsets):
                raise MP4Error(f"{path}: GPMF 'stts' covers {len(dur)} samples, 'stsz' {len(offsets)}")
            payloads = [_read(f, int(o), int(n), path) for o, n in zip(offsets, info["stsz"])]
            start = np.concatenate([[0], np.cumsum(dur)[:-1]]) / float(info["timescale"])
            return payloads, start, dur / float(info["timescale"])
    return None


def _box(kind: bytes, *parts: bytes) -> bytes:
    body = b"".join(parts)
    return struct.pack(">I4s", 8 + len(body), kind) + body


def add_gpmf_track(path, payloads: list[bytes], sample_duration_s, timescale: int = 90_000) -> Path:
    """Append a GPMF metadata track (``meta`` handler, ``gpmd`` samples of ``sample_duration_s``
    each, or one duration per sample (a clip's last payload is shorter), one per chunk) to an
    MP4 whose ``moov`` is its last box; the video is left untouched.

    Raises
    ------
    MP4Error
        When the file's last box is not ``moov``.
    """
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as f:
        boxes = list(_boxes(f, 0, size, path))
        kind, m0, m1 = boxes[-1]
        if kind != b"moov":
            raise MP4Error(f"{path}: 'moov' is not the last box; cannot append a metadata track")
        moov_start = m0 - 8
        moov = _read(f, m0, m1 - m0, path)
    n = len(payloads)
    deltas = np.rint(np.broadcast_to(np.asarray(sample_duration_s, np.float64), (n,)) * timescale).astype(np.int64)
    runs = np.flatnonzero(np.diff(deltas, prepend=-1) != 0)  # stts: (count, delta) per run
    counts = np.diff(np.append(runs, n))
    data = b"".join(payloads)
    offsets, pos = [], moov_start + 8  # the new mdat takes the old moov's place
    for p in payloads:
        offsets.append(pos)
        pos += len(p)
    duration = int(deltas.sum())
    tkhd = _box(b"tkhd", struct.pack(">IIIIII", 3, 0, 0, 99, 0, duration), b"\0" * 8,
                struct.pack(">hhhh", 0, 0, 0, 0), struct.pack(">9I", 0x10000, 0, 0, 0, 0x10000, 0, 0, 0, 0x40000000),
                struct.pack(">II", 0, 0))
    mdhd = _box(b"mdhd", struct.pack(">IIIIIHH", 0, 0, 0, timescale, duration, 0x55C4, 0))
    hdlr = _box(b"hdlr", struct.pack(">II4s", 0, 0, b"meta"), b"\0" * 12, b"GoPro MET\0")
    dinf = _box(b"dinf", _box(b"dref", struct.pack(">II", 0, 1), _box(b"url ", struct.pack(">I", 1))))
    stsd = _box(b"stsd", struct.pack(">II", 0, 1), _box(b"gpmd", b"\0" * 6, struct.pack(">H", 1)))
    stts = _box(b"stts", struct.pack(">II", 0, len(runs)),
                *(struct.pack(">II", int(c), int(deltas[r])) for c, r in zip(counts, runs)))
    stsc = _box(b"stsc", struct.pack(">IIIII", 0, 1, 1, 1, 1))
    stsz = _box(b"stsz", struct.pack(">III", 0, 0, n), struct.pack(f">{n}I", *(len(p) for p in payloads)))
    stco = _box(b"stco", struct.pack(">II", 0, n), struct.pack(f">{n}I", *offsets))
    trak = _box(b"trak", tkhd, _box(b"mdia", mdhd, hdlr, _box(b"minf", _box(b"nmhd", struct.pack(">I", 0)), dinf,
                                                            _box(b"stbl", stsd, stts, stsc, stsz, stco))))
    with open(path, "r+b") as f:
        f.seek(moov_start)
        f.truncate()
        f.write(_box(b"mdat", data))
        f.write(_box(b"moov", moov, trak))
    return path
