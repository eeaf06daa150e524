"""core.memory.release_freed_memory returns freed heap memory to the system (glibc)."""

import numpy as np
import pytest

from grip_bench.core.memory import release_freed_memory


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        return int(f.read().split("VmRSS:")[1].split()[0]) / 1024


@pytest.mark.skipif(not release_freed_memory(), reason="the C library has no malloc_trim")
def test_freed_holes_in_the_heap_go_back():
    # 60 KB arrays come from the heap (below glibc's mmap threshold); keeping every 20th
    # leaves holes that the heap's automatic top trimming cannot give back
    arrays = [np.ones(60 * 1024 // 8) for _ in range(3000)]  # ~176 MiB, pages touched
    kept = arrays[::20]
    del arrays
    before = _rss_mib()
    assert release_freed_memory()
    after = _rss_mib()
    assert before - after > 100, (before, after)
    assert all(float(a[0]) == 1.0 for a in kept)  # live arrays untouched
