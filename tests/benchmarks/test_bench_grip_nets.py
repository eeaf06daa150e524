"""Forward throughput of ANet + CNet + RNet at the paper's widths on CPU.

Measures; asserts nothing about time. Run with ``pytest tests/benchmarks/test_bench_grip_nets.py
--benchmark-enable`` (the default run skips benchmarks). ``extra_info`` records frames/s, the
analytic FLOPs per frame and the achieved FLOP rate, so the runtime can be set against the
FLOPs floor (``grip_bench.grip.flops.runtime_floor``).
"""

from __future__ import annotations

import pytest
import torch

from grip_bench.grip import ANetConfig, CNetConfig, RNetConfig
from grip_bench.grip.flops import flops_per_frame


def paper_pipeline(batch: int):
    """Build the three networks in eval mode and inputs for ``batch`` frames."""
    torch.manual_seed(0)
    cnet_cfg, anet_cfg, rnet_cfg = CNetConfig(), ANetConfig(), RNetConfig()
    cnet, anet, rnet = (c.build().eval() for c in (cnet_cfg, anet_cfg, rnet_cfg))
    inputs = dict(
        current=torch.randn(batch, anet_cfg.n_joints, 6),
        noisy_future=torch.randn(batch, anet_cfg.n_future, anet_cfg.n_joints, 6),
        body=torch.randn(batch, 2, cnet_cfg.body_dim),
        ambient=torch.rand(batch, 2, 2, cnet_cfg.ambient_dim),
        proximity=torch.rand(batch, 2, 2, cnet_cfg.proximity_dim),
        future=torch.randn(batch, cnet_cfg.future_dim),
        proximity_refined=torch.rand(batch, 2, rnet_cfg.proximity_dim),
        mask=torch.ones(batch, dtype=torch.bool),
    )

    def run():
        with torch.inference_mode():
            anet(inputs["current"], inputs["noisy_future"])
            out = cnet(inputs["body"], inputs["ambient"], inputs["proximity"], inputs["future"])
            # In the pipeline the proximity is recomputed on CNet's hands; here it is a stand-in.
            return rnet(out.poses_t, inputs["proximity_refined"], mask=inputs["mask"])

    flops = sum(flops_per_frame(c) for c in (cnet_cfg, anet_cfg, rnet_cfg))
    return run, flops


@pytest.mark.parametrize("batch", [1, 256])
def test_bench_grip_forward(benchmark, batch):
    run, flops = paper_pipeline(batch)
    run()  # first call allocates; keep it out of the timing
    refined = benchmark.pedantic(run, rounds=5 if batch > 1 else 20, iterations=1, warmup_rounds=1)
    assert refined.shape == (batch, 2, 15, 6)
    benchmark.extra_info.update(flops_per_frame=flops, batch=batch, threads=torch.get_num_threads())
    if benchmark.stats is not None:  # None under --benchmark-disable
        seconds = benchmark.stats.stats.mean
        benchmark.extra_info.update(
            frames_per_s=batch / seconds,
            gflops_per_s=flops * batch / seconds / 1e9,
        )
