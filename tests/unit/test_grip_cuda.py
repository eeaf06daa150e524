"""GRIP's inference pipeline on a CUDA device (``--device cuda``): the networks run where
they were loaded, the NumPy between them stays on the host, and the hands match the CPU's.

Skipped on machines without CUDA (CI); run on a GPU machine with
``pytest tests/unit/test_grip_cuda.py``. Without CUDA, ``net_device`` is still checked.
"""

import numpy as np
import pytest
import torch

from grip_bench.data.grab_io import list_sequences, read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.grip.method import GripMethod
from grip_bench.grip.pipeline import net_device
from grip_bench.methods.api import PredictContext

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def test_net_device_is_where_the_first_tensor_lives():
    lin = torch.nn.Linear(3, 2)
    assert net_device(lin) == torch.device("cpu")
    assert net_device(torch.nn.ReLU()) == torch.device("cpu")  # no tensors: the host
    bn = torch.nn.BatchNorm1d(4)
    bn.weight, bn.bias = None, None  # buffers only
    assert net_device(bn.to("meta")) == torch.device("meta")


@CUDA
@pytest.mark.parametrize("online", [False, True])
def test_cuda_hands_match_the_cpu(tiny_grip_root, tiny_grip_checkpoint, online):
    torch.set_num_threads(1)
    seq = read_grab(list_sequences(tiny_grip_root)[0])
    lib = ObjectLibrary(tiny_grip_root)
    preds = {}
    for device in ("cpu", "cuda"):
        m = GripMethod()
        m.load(tiny_grip_checkpoint, device=device)
        preds[device] = m.predict(seq, PredictContext(library=lib, device=device, online=online))
    for hand in ("rhand", "lhand"):
        for key in ("hand_pose", "global_orient", "transl"):
            a, b = getattr(preds["cpu"], hand)[key], getattr(preds["cuda"], hand)[key]
            # TF32 and other GEMM kernels round differently from the CPU's
            np.testing.assert_allclose(b, a, atol=2e-3, err_msg=f"{hand}.{key}")
