"""Torch intra-op threads for small-tensor work."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator


@contextlib.contextmanager
def single_thread() -> Iterator[None]:
    """Run torch on one intra-op thread inside the block (restored after).

    Feature building and the baselines' networks work on small tensors: a second thread
    gains little, and when the cores are shared with other processes torch's spinning
    worker threads cost far more than they give (on the 2-core test machine under load the
    default GrabNet training took 664 s with 2 threads and 53 s with 1). Results do not
    depend on it: the features are byte-identical either way (tests/unit/test_grip_features.py).
    """
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
