"""Keep freed heap memory for reuse between batches of events (glibc only).

Each batch (decoded, stored or tracked) allocates NumPy temporaries of 0.1–30 MB. With glibc's defaults those are
returned to the OS when freed and page-faulted back on the next batch; on a VM a fault
costs about 3 µs per 4 KiB page, which made decoding 2–3x slower than the arithmetic.
:func:`keep_freed_memory` raises the thresholds so that blocks up to 32 MiB come from
the heap and up to 256 MiB of free heap is kept for reuse (larger blocks are still
mapped directly; transparent huge pages make those cheap). Measured on the shared
recordings and a 4M-event file: this minimises page faults per decoded file. Called
once when :mod:`capture` is imported (replay: tracking a 5 Mev/s session spent a fifth
of its time in page faults of joining batches without it).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20
TRIM_THRESHOLD_BYTES = 256 << 20


def keep_freed_memory() -> bool:
    """Set glibc's mmap / trim thresholds (see module doc). Returns False where not applicable."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):   # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and \
        bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
