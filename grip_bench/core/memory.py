"""Handing freed memory back to the operating system between the phases of a unit.

glibc's allocator keeps freed heap memory for reuse, and its mmap threshold grows with
each large array freed, so after a phase that allocates and frees many arrays (reading
every training sequence, building distance fields) a process keeps gigabytes it no longer
uses, and the next phase's arrays come on top: nearest-neighbour's training held 2.5 GB
after collecting its 50,000 keys, of which 0.76 GB was live, and peaked at 4.3 GB in the
SVD that followed; with the freed memory returned first it peaked at 2.5 GB
(docs/performance.md). Values never depend on it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import gc


@functools.cache
def _malloc_trim():  # the C function, or None where the C library has none (macOS, musl)
    name = ctypes.util.find_library("c")
    try:
        return getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    except OSError:
        return None


def release_freed_memory() -> bool:
    """Collect garbage cycles, then return the C heap's free memory to the system
    (glibc ``malloc_trim(0)``); True when the C library offers that."""
    gc.collect()
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
