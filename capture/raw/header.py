"""RAW file headers: parse modern and legacy ``% key value`` headers, write modern ones.

A Prophesee RAW file starts with ASCII lines ``% key value\\n``. Modern headers
(Metavision >= 4) end with ``% end`` and carry ``format EVT3;height=720;width=1280``
and ``geometry 1280x720``. Legacy headers have neither: the format comes from
``evt 2.0|2.1|3.0`` and the geometry from ``system_ID`` or the HAL plugin name.

The header dict returned by :func:`parse_header` always has these keys:

``format``
    ``"EVT2"``, ``"EVT21"``, ``"EVT3"`` or ``None`` (no format information).
``width``, ``height``
    Sensor geometry in pixels, or ``None`` when the header does not say.
``endianness``
    ``"little"`` or ``"legacy"`` (EVT 2.1 only: 32-bit halves swapped, as the EVK's IMX636 sends).
``style``
    ``"modern"`` (ends at ``% end``), ``"legacy"`` (no ``% end``) or ``"none"`` (no header).
``fields``
    Every ``key value`` pair as strings, in file order (a repeated key keeps its last value).
"""

from __future__ import annotations

import datetime as _dt
import re

from capture.raw.errors import RawFormatError

FORMATS = ("EVT2", "EVT21", "EVT3")
"""Event formats this codec reads (and, except EVT21, writes)."""

_FORMAT_ALIASES = {
    "EVT2": "EVT2", "EVT20": "EVT2", "EVT2.0": "EVT2", "2.0": "EVT2", "2": "EVT2",
    "EVT21": "EVT21", "EVT2.1": "EVT21", "2.1": "EVT21",
    "EVT3": "EVT3", "EVT30": "EVT3", "EVT3.0": "EVT3", "3.0": "EVT3", "3": "EVT3",
}
_EVT_VERSION = {"EVT2": "2.0", "EVT21": "2.1", "EVT3": "3.0"}

# Geometry of legacy recordings. system_ID values are the HAL's (decimal in headers).
_SYSTEM_ID_GEOMETRY = {
    0x15: (640, 480),    # CCAM3 Gen3 (FX3)
    0x28: (640, 480),    # EVK3 Gen3.1
    0x30: (1280, 720),   # EVK3 Gen4.1
    0x31: (1280, 720),   # EVK3 / EVK4 IMX636
    0x32: (1280, 720),   # EVK2 IMX636
    0x35: (1280, 720),   # EVK3 IMX646
    0x40: (320, 320),    # EVK3 GenX320
}
# Sensor generation named in the HAL plugin name -> geometry (checked in this order).
_PLUGIN_GEOMETRY = (
    ("genx320", (320, 320)),
    ("imx636", (1280, 720)),
    ("imx646", (1280, 720)),
    ("gen41", (1280, 720)),
    ("gen31", (640, 480)),
    ("gen3", (640, 480)),
)

MAX_HEADER_BYTES = 1 << 16
"""A header longer than this is treated as damage."""

_PRINTABLE = re.compile(rb"%[\x20-\x7e\t]*\r?\n")


def normalize_format(name: str, *, source: str = "format") -> str:
    """Canonical format name (``"EVT2"``, ``"EVT21"``, ``"EVT3"``) for any usual spelling.

    Raises
    ------
    RawFormatError
        For a name that is not an event format this codec knows.
    """
    key = str(name).strip().upper().replace(" ", "")
    if key not in _FORMAT_ALIASES:
        raise RawFormatError(f"{source}: unknown event format {name!r} "
                             f"(supported: {', '.join(FORMATS)})")
    return _FORMAT_ALIASES[key]


def _geometry_from_fields(fields: dict[str, str], options: dict[str, str]) -> tuple[int, int] | None:
    if "width" in options and "height" in options:
        return int(options["width"]), int(options["height"])
    geometry = fields.get("geometry")
    if geometry:
        m = re.fullmatch(r"\s*(\d+)\s*x\s*(\d+)\s*", geometry)
        if m:
            return int(m.group(1)), int(m.group(2))
    if "width" in fields and "height" in fields:
        return int(fields["width"]), int(fields["height"])
    system_id = fields.get("system_ID")
    if system_id is not None:
        try:
            sid = int(system_id, 0) if system_id.lower().startswith("0x") else int(system_id)
        except ValueError:
            sid = None
        if sid in _SYSTEM_ID_GEOMETRY:
            return _SYSTEM_ID_GEOMETRY[sid]
    plugin = fields.get("plugin_name", "").lower()
    for tag, geometry in _PLUGIN_GEOMETRY:
        if tag in plugin:
            return geometry
    return None


def parse_header(data: bytes, *, source: str = "<bytes>") -> tuple[dict, int]:
    """Parse the header at the start of a RAW byte string.

    Parameters
    ----------
    data : bytes
        The first bytes of the file (the whole header must be inside; 64 KiB is plenty).
    source : str
        Name used in error messages (the file path).

    Returns
    -------
    header : dict
        ``format``, ``width``, ``height``, ``endianness``, ``style``, ``fields`` (see module doc).
    size : int
        Header length in bytes; the event words start at this offset.

    Raises
    ------
    RawFormatError
        If the header names an unknown format or has unreadable geometry (message names the
        byte offset of the offending line), or a header line runs past :data:`MAX_HEADER_BYTES`.
    """
    data = bytes(data[:MAX_HEADER_BYTES + 1])
    fields: dict[str, str] = {}
    offsets: dict[str, int] = {}
    pos = 0
    style = "none"
    while pos < len(data) and data[pos:pos + 1] == b"%":
        m = _PRINTABLE.match(data, pos)
        if m is None:
            if b"\n" not in data[pos:] and len(data) > MAX_HEADER_BYTES:
                raise RawFormatError(f"{source}: byte {pos}: header line not terminated within "
                                     f"{MAX_HEADER_BYTES} bytes")
            break  # binary data that happens to start with '%': the header ended before it
        line = m.group(0)[1:].decode("ascii").strip()
        line_pos, pos = pos, m.end()
        style = "legacy"
        if line == "end":
            style = "modern"
            break
        key, _, value = line.partition(" ")
        if key:
            fields[key] = value.strip()
            offsets[key] = line_pos
    options: dict[str, str] = {}
    fmt = None
    if "format" in fields:
        name, *opts = fields["format"].split(";")
        fmt = normalize_format(name, source=f"{source}: byte {offsets['format']}")
        for opt in opts:
            k, _, v = opt.partition("=")
            options[k.strip()] = v.strip()
    elif "evt" in fields:
        fmt = normalize_format(fields["evt"], source=f"{source}: byte {offsets['evt']}")
    try:
        geometry = _geometry_from_fields(fields, options)
    except ValueError as exc:
        raise RawFormatError(f"{source}: bad geometry in header ({exc})") from None
    if geometry and not all(0 < v <= MAX_SIZE_PX for v in geometry):
        raise RawFormatError(f"{source}: bad geometry {geometry[0]}x{geometry[1]} in header "
                             f"(event formats address 1..{MAX_SIZE_PX} pixels)")
    endianness = options.get("endianness", fields.get("endianness", "little")).lower()
    if endianness not in ("little", "legacy"):
        raise RawFormatError(f"{source}: unsupported endianness {endianness!r} (little or legacy)")
    header = {
        "format": fmt,
        "width": geometry[0] if geometry else None,
        "height": geometry[1] if geometry else None,
        "endianness": endianness,
        "style": style,
        "fields": fields,
    }
    return header, pos


MAX_SIZE_PX = 2048
"""Largest sensor width or height the EVT formats can address (11-bit coordinates)."""


def header_bytes(format: str = "EVT3", *, width: int, height: int, endianness: str = "little",
                 **extra) -> bytes:
    """A modern RAW header (``% key value`` lines ending with ``% end``).

    Parameters
    ----------
    format : str
        ``"EVT2"``, ``"EVT21"`` or ``"EVT3"`` (other spellings as in :func:`normalize_format`).
    width, height : int
        Sensor geometry in pixels.
    endianness : str
        ``"little"`` or ``"legacy"``; written into the format line for EVT21 only.
    **extra
        More header fields (``serial_number="00050423"``, ``plugin_name=...``,
        ``date="2026-01-01 12:00:00"``); ``None`` values are skipped. Values must be one line.

    Returns
    -------
    bytes
        The header, ASCII; the event words follow it directly.
    """
    fmt = normalize_format(format)
    width, height = int(width), int(height)
    if not (0 < width <= MAX_SIZE_PX and 0 < height <= MAX_SIZE_PX):
        raise ValueError(f"geometry {width}x{height} is outside 1..{MAX_SIZE_PX} pixels")
    options = f";endianness={endianness}" if fmt == "EVT21" else ""
    fields = {"date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S"),
              "evt": _EVT_VERSION[fmt],
              "format": f"{fmt}{options};height={height};width={width}",
              "geometry": f"{width}x{height}",
              "integrator_name": "courtside-spin"}
    for key, value in extra.items():
        if value is None:
            continue
        value = str(value)
        if not re.fullmatch(r"[A-Za-z0-9_.\-]+", key) or not re.fullmatch(r"[\x20-\x7e\t]*", value):
            raise ValueError(f"header field {key!r}={value!r} must be one printable ASCII line")
        if key in ("evt", "format", "geometry"):
            raise ValueError(f"header field {key!r} is set from format/width/height")
        fields[key] = value
    lines = [f"% {k} {v}\n" for k, v in fields.items()] + ["% end\n"]
    return "".join(lines).encode("ascii")
