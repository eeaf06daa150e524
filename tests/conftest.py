"""Session-wide test settings and shared fixtures."""

import atexit
import os
import shutil
import tempfile

import pytest

# Before any test module imports numpy: grip_bench pins numpy's, OpenBLAS's and torch's kernels
# as it loads (core/numerics.py), so the tests compute what the CLI computes.
import grip_bench  # noqa: F401, E402

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


@pytest.fixture(scope="session")
def tiny_grip_root(tmp_path_factory):
    """The tiny GRIP dataset of ``tests.grip_fixtures`` (16 frames a sequence); read only."""
    from tests.grip_fixtures import write_grip_dataset

    return write_grip_dataset(tmp_path_factory.mktemp("gripdata"), T=16)


@pytest.fixture(scope="session")
def tiny_grip_checkpoint(tiny_grip_root, tmp_path_factory):
    """GRIP trained once per session on :func:`tiny_grip_root` with ``tiny_profile()``
    (the pipeline and the stream tests read the same checkpoint)."""
    import torch

    from grip_bench.grip.method import GripMethod
    from grip_bench.methods.api import TrainContext
    from tests.grip_fixtures import tiny_profile

    out = tmp_path_factory.mktemp("ckpt") / "grip.pt"
    torch.set_num_threads(1)
    return GripMethod().train(tiny_grip_root, out,
                              TrainContext(profile=tiny_profile(), progress=False))


def pytest_benchmark_update_machine_info(config, machine_info):
    """Every benchmark table records the processor's model and the flags that decide GEMM
    speed (``grip_bench.core.cpu``), beside pytest-benchmark's own cpu fields."""
    from grip_bench.core.cpu import cpu_info

    machine_info["grip_bench_cpu"] = cpu_info().as_dict()
