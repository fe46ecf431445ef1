"""Capture: RAW event streams, live devices, clocks and the session store.

Importing this package tunes glibc's allocator to keep freed memory for reuse (see ``_malloc``):
decoding, storing and replaying events allocate many large temporaries.
"""

from capture._malloc import keep_freed_memory

keep_freed_memory()
