"""Prophesee RAW files and streams (EVT 2.0, 2.1, 3.0): headers, decoders (compiled word loops), encoders.

Public API
----------
read(path) -> RawFile
    Decode a whole file (``.events``, ``.triggers``, ``.width``, ``.height``, ``.format``, ``.header``).
iter_chunks(source, chunk_bytes=...) / RawReader(source)
    Decode a file, file object or byte iterator batch by batch in bounded memory.
StreamDecoder(format, time_shift=False)
    ``.decode(bytes) -> (events, triggers)`` for live streams in any chunking.
parse_header(data) / header_bytes(format=..., width=..., height=...)
    Read / write the ``% key value`` header.
write(path, events, triggers=None, format="EVT3", width=..., height=...) / encode(...)
    Encode arrays as a RAW file (EVT3 with vectors, or EVT2).
info(path) / scan(reader, on_batch=None)
    Counts, time range and mean rate of a file, decoding it in bounded memory.

A pure codec: it imports nothing of the project but ``capture.events``. Command line:
``python -m capture.raw info FILE``; a RAW file becomes a session with ``capture.ingest``.
"""

from capture.raw.errors import RawDamageWarning, RawFormatError
from capture.raw.files import RawFile, encode, info, read, scan, write
from capture.raw.header import FORMATS, header_bytes, normalize_format, parse_header
from capture.raw.stream import RawReader, StreamDecoder, iter_chunks

__all__ = ["FORMATS", "RawDamageWarning", "RawFile", "RawFormatError", "RawReader", "StreamDecoder",
           "encode", "header_bytes", "info", "iter_chunks", "normalize_format", "parse_header", "read", "scan",
           "write"]
