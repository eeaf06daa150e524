"""tools/train_throughput.py: GRIP's training loop timed per network on the tiny dataset
(the figures' plumbing; the H200 figures it produced are in docs/performance.md)."""

from __future__ import annotations

import json

import pytest
import torch

from grip_bench.core.errors import InputError
from tools.train_throughput import main


def test_times_every_network_and_writes_its_figures(tiny_grip_root, tmp_path):
    out = tmp_path / "t.json"
    assert main(["--data", str(tiny_grip_root), "--profile", "smoke", "--steps", "3",
                 "--warmup", "1", "--threads", "1", "--epoch-frames", "1000",
                 "--out", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["profile"] == "smoke" and r["device"] == "cpu" and r["threads"] == 1
    assert list(r["stages"]) == ["anet", "cnet", "rnet"]
    for s in r["stages"].values():
        assert s["steps"] == 3 and 0 < s["batch"] <= 64 and s["params"] > 0
        assert s["frames_per_s"] > 0 and s["step_frames_per_s"] >= s["frames_per_s"]
        # frames/s counts the fetch and the step; the epoch estimate is frames over it
        total_s = s["steps"] * (s["fetch_ms"] + s["step_ms"]) / 1e3
        assert s["frames_per_s"] == pytest.approx(s["steps"] * s["batch"] / total_s, rel=1e-6)
        assert s["epoch_s_estimate"] == pytest.approx(1000 / s["frames_per_s"], rel=1e-9)
        assert "peak_gpu_mib" not in s


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error without CUDA")
def test_a_missing_gpu_is_the_cli_error(tiny_grip_root):
    with pytest.raises(InputError, match="CUDA is not available"):
        main(["--data", str(tiny_grip_root), "--device", "cuda"])
