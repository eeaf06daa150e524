"""Session-wide test settings and shared fixtures."""

import atexit
import os
import shutil
import tempfile

import pytest

# Derived object geometry (distance grids, convex pieces, the hand template) is cached on
# disk (grip_bench.geometry.cache). Tests use a fresh folder per session, so they never read
# or fill the user's ~/.cache/grip-bench and always exercise the cold build once.
if "GRIP_BENCH_CACHE" not in os.environ:
    _cache = tempfile.mkdtemp(prefix="grip-bench-test-cache-")
    os.environ["GRIP_BENCH_CACHE"] = _cache
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)


@pytest.fixture
def one_thread():
    """Torch on one thread for the test (``pytestmark = pytest.mark.usefixtures("one_thread")``)."""
    from grip_bench.core.threads import single_thread

    with single_thread():
        yield


@pytest.fixture(scope="module")
def hand():
    """The procedural right hand (modules with their own ``hand`` fixture override it)."""
    from grip_bench.bodies import ProceduralHand

    return ProceduralHand("right")


def pytest_benchmark_update_machine_info(config, machine_info):
    """Every benchmark table records the processor's model and the flags that decide GEMM
    speed (``grip_bench.core.cpu``), beside pytest-benchmark's own cpu fields."""
    from grip_bench.core.cpu import cpu_info

    machine_info["grip_bench_cpu"] = cpu_info().as_dict()
