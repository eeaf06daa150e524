"""Session-wide test settings."""

import atexit
import os
import shutil
import tempfile

# Derived object geometry (distance grids, convex pieces, the hand template) is cached on
# disk (grip_bench.geometry.cache). Tests use a fresh folder per session, so they never read
# or fill the user's ~/.cache/grip-bench and always exercise the cold build once.
if "GRIP_BENCH_CACHE" not in os.environ:
    _cache = tempfile.mkdtemp(prefix="grip-bench-test-cache-")
    os.environ["GRIP_BENCH_CACHE"] = _cache
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)
