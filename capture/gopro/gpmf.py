"""GoPro's GPMF metadata: the per-frame exposure, frame skips and readout time of a clip.

GPMF (GoPro's KLV metadata, `github.com/gopro/gpmf-parser`) is stored in the MP4 as a timed
metadata track (handler ``meta``, sample entry ``gpmd``), about one payload per second. Facts
used:

- every item is a 32-bit aligned KLV: FourCC key, one type character, one byte structure size,
  a big-endian 16-bit repeat count, then ``size * repeat`` bytes padded to 4; type ``\\0`` means
  the payload is nested items (``DEVC`` > ``STRM`` > data); big-endian numbers throughout;
- ``SCAL`` in a stream divides the stream's values;
- ``SHUT``: exposure time per frame, seconds; ``ISOE``: sensor ISO; ``MSKP``: frames skipped or
  duplicated between the sensor and the encoded video (HERO9 on; normally 0); ``SROT``: sensor
  readout time (one value per clip from HERO8 on; unit not documented, stored as read).

A small reader of our own (about 100 lines) rather than ``py-gpmf-parser``: we need four keys
from one stream kind, the MP4 track is already walked by :mod:`capture.gopro.mp4`, and a
compiled wrapper would be a build dependency for that. :func:`build` writes the same format,
for the simulator and the fake camera.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

_TYPES = {"b": ">i1", "B": ">u1", "s": ">i2", "S": ">u2", "l": ">i4", "L": ">u4", "f": ">f4", "d": ">f8",
          "j": ">i8", "J": ">u8"}
"""GPMF numeric type characters and their NumPy dtypes (big-endian)."""


class GPMFError(ValueError):
    """A GPMF payload is malformed (item and byte offset named)."""


@dataclass(frozen=True)
class Item:
    """One KLV item: ``key`` (FourCC), ``type`` (one character, ``"\\0"`` for nested),
    ``value`` (list of :class:`Item` when nested, a NumPy array for numbers, bytes otherwise)."""

    key: str
    type: str
    value: object


def parse(data: bytes, offset: int = 0, end: int | None = None) -> list[Item]:
    """Parse a GPMF payload into items (nested ones recursively).

    Raises
    ------
    GPMFError
        On a header or length that runs past the payload.
    """
    end = len(data) if end is None else end
    out = []
    pos = offset
    while pos + 8 <= end:
        key, typ, size, repeat = struct.unpack_from(">4scBH", data, pos)
        n = size * repeat
        stop = pos + 8 + n
        if stop > end:
            raise GPMFError(f"GPMF item {key!r} at byte {pos} claims {n} bytes, only {end - pos - 8} left")
        t = typ.decode("latin-1")
        if t == "\0":
            value = parse(data, pos + 8, stop)
        elif t in _TYPES and size % np.dtype(_TYPES[t]).itemsize == 0:
            value = np.frombuffer(data, _TYPES[t], n // np.dtype(_TYPES[t]).itemsize, pos + 8).astype(
                np.dtype(_TYPES[t]).newbyteorder("="))
        else:
            value = bytes(data[pos + 8:stop])
        out.append(Item(key.decode("latin-1"), t, value))
        pos = pos + 8 + ((n + 3) & ~3)
    return out


def build(key: str, type_: str, value) -> bytes:
    """One KLV item: numbers (``type_`` in :data:`_TYPES`), bytes (``"c"``), or nested item
    bytes (``type_ = "\\0"``, ``value`` the concatenated children)."""
    if type_ == "\0" or type_ == "c":
        body, size, repeat = bytes(value), 1, len(value)
        if type_ == "\0":
            size, repeat = 4, len(body) // 4
    else:
        arr = np.ascontiguousarray(value, dtype=_TYPES[type_])
        body, size, repeat = arr.tobytes(), arr.dtype.itemsize, arr.size
    return struct.pack(">4scBH", key.encode("latin-1"), type_.encode("latin-1"), size, repeat) + body + \
        b"\0" * (-len(body) % 4)


@dataclass(frozen=True)
class FrameMetadata:
    """Per-frame camera metadata of one clip, from its GPMF track.

    Attributes
    ----------
    t_s : ndarray, shape (N,)
        Time of each ``SHUT`` value on the clip's clock (s), spread evenly over its payload.
    exposure_s : ndarray, shape (N,)
        Exposure time (``SHUT``), seconds.
    iso : ndarray, shape (N,) or (0,)
        Sensor ISO (``ISOE``) where present.
    frame_skips : ndarray of int, shape (M,)
        ``MSKP`` values (frames skipped or duplicated; normally 0); empty when absent.
    readout : float or None
        ``SROT`` as stored (sensor readout time).
    """

    t_s: np.ndarray
    exposure_s: np.ndarray
    iso: np.ndarray
    frame_skips: np.ndarray
    readout: float | None

    def exposure_at(self, t_frame_s: np.ndarray) -> np.ndarray:
        """Exposure (s) of frames at clip times ``t_frame_s`` (nearest ``SHUT`` sample)."""
        t = np.asarray(t_frame_s, np.float64)
        i = np.clip(np.searchsorted(self.t_s, t), 1, max(len(self.t_s) - 1, 1))
        left = np.abs(t - self.t_s[i - 1]) <= np.abs(self.t_s[np.minimum(i, len(self.t_s) - 1)] - t)
        return self.exposure_s[np.where(left, i - 1, np.minimum(i, len(self.t_s) - 1))]


def _streams(items: list[Item]):
    for it in items:
        if it.type == "\0":
            if it.key == "STRM":
                yield it.value
            yield from _streams(it.value)


def frame_metadata(payloads: list[bytes], sample_t_s: np.ndarray, sample_dur_s: np.ndarray) -> FrameMetadata | None:
    """Collect ``SHUT``/``ISOE``/``MSKP``/``SROT`` from the GPMF samples of a clip.

    Parameters
    ----------
    payloads : list of bytes
        The GPMF samples in time order.
    sample_t_s, sample_dur_s : ndarray, shape (len(payloads),)
        Start and duration of each sample on the clip's clock (s).

    Returns
    -------
    FrameMetadata or None
        None when no sample carries ``SHUT``.
    """
    t, shut, iso, skips, readout = [], [], [], [], None
    for data, t0, dur in zip(payloads, sample_t_s, sample_dur_s):
        for stream in _streams(parse(data)):
            scale = next((np.asarray(i.value, np.float64) for i in stream if i.key == "SCAL"), None)

            def values(item):
                v = np.asarray(item.value, np.float64).ravel()
                return v / scale.ravel()[0] if scale is not None and scale.size == 1 else v

            for it in stream:
                if it.key == "SHUT" and isinstance(it.value, np.ndarray):
                    v = values(it)
                    shut.append(v)
                    t.append(t0 + np.arange(len(v)) * dur / max(len(v), 1))
                elif it.key == "ISOE" and isinstance(it.value, np.ndarray):
                    iso.append(values(it))
                elif it.key == "MSKP" and isinstance(it.value, np.ndarray):
                    skips.append(np.asarray(it.value).ravel().astype(np.int64))
                elif it.key == "SROT" and isinstance(it.value, np.ndarray) and it.value.size:
                    readout = float(values(it)[0])
    if not shut:
        return None
    cat = lambda xs, dt: np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)  # noqa: E731
    return FrameMetadata(t_s=cat(t, np.float64), exposure_s=cat(shut, np.float64), iso=cat(iso, np.float64),
                         frame_skips=cat(skips, np.int64), readout=readout)


def camera_payload(exposure_s, *, iso=None, frame_skips=None, readout=None) -> bytes:
    """One GPMF payload as a GoPro writes it (``DEVC`` > ``STRM`` streams) for one sample's frames."""
    streams = [build("STRM", "\0", build("STNM", "c", b"Exposure time (shutter speed)") +
                     build("SIUN", "c", b"s") + build("SHUT", "f", exposure_s))]
    if iso is not None:
        streams.append(build("STRM", "\0", build("STNM", "c", b"Sensor ISO") + build("ISOE", "S", iso)))
    if frame_skips is not None:
        streams.append(build("STRM", "\0", build("STNM", "c", b"Main video frame skip") +
                             build("MSKP", "S", frame_skips)))
    if readout is not None:
        streams.append(build("STRM", "\0", build("STNM", "c", b"Sensor read out time") + build("SROT", "f", [readout])))
    return build("DEVC", "\0", build("DVNM", "c", b"Camera") + b"".join(streams))
