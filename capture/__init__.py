"""Capture: the data contracts, RAW event streams, live devices, the session store, and the pipeline.

Libraries (never importing the layers above them): :mod:`capture.events` (the data contracts),
:mod:`capture.raw` (RAW codec), :mod:`capture.evk` and :mod:`capture.gopro` (devices with their
fakes), :mod:`capture.session` (the Zarr store), :mod:`capture.ingest` (RAW files and videos into
a session), :mod:`capture.review` (Rerun). The pipeline layer :mod:`capture.pipeline` (record,
live analysis, replay, the demo) is the only part that joins them with ``detect`` and ``spin``;
the command lines (:mod:`capture.run`, :mod:`capture.replay`, the ``courtside`` command in
:mod:`capture.cli`) sit on top.

Importing this package tunes glibc's allocator to keep freed memory for reuse (see ``_malloc``):
decoding, storing and replaying events allocate many large temporaries.
"""

from capture._malloc import keep_freed_memory

keep_freed_memory()
