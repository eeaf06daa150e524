"""Per-frame latency of ``GripStream.step`` at the paper's widths (hidden 2048, width 1024,
latent 256; random weights, ANet's residual head zeroed as in training) against the
batch-1 floor, measured in the same run.

The floor: at batch 1 every weight is read once per frame, so a frame costs at least the
networks' weight bytes (183 MB in fp32, 1/2 in bf16, 1/4 in int8) over the GEMV rate of
this CPU at GRIP's weight size (``grip_bench.bench.perf.gemv_bandwidth``, which may sit in
a large last-level cache), on the same one thread. The stream also runs the sensors, FK and
the rotations of one frame, which the floor leaves out.

Run: ``pytest tests/benchmarks/test_bench_stream.py -o addopts="" --benchmark-only -s``.
Measures (``extra_info``: p50/p95 ms, the floor, their ratio); asserts nothing about time.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from grip_bench.bench.perf import Settings, gemv_bandwidth, grip_weight_bytes, paper_nets
from grip_bench.data.grab_io import read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.grip.stream import GripStream, frame_of
from grip_bench.grip.train import Variant
from tests.eval_fixtures import grasp_dataset

T = 60
BYTES_PER_WEIGHT = {"fp32": 4, "bf16": 2, "int8": 1}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("stream")
    seq = read_grab(grasp_dataset(root, T=T)[0])
    lib = ObjectLibrary(root)
    lib.field(seq.obj_name)  # built once per object, outside the timing
    # one thread: a live stream is one core's work; batch-1 GEMVs gain little from a second
    # thread and lose much when the cores are shared (measured: docs/streaming.md)
    torch.set_num_threads(1)
    return seq, lib, paper_nets()


def gemv_gb_s() -> list[float]:
    """GEMV fp32 GB/s samples at GRIP's weight size, these threads (as ``grip-bench bench``)."""
    settings = Settings.make(quick=True, repeats=3, threads=torch.get_num_threads())
    return gemv_bandwidth(settings, grip_weight_bytes())[0].values


@pytest.mark.parametrize("precision", ["fp32", "bf16", "int8"])
def test_bench_stream_step(benchmark, scene, precision):
    seq, lib, nets = scene
    stream = GripStream(nets, Variant(), lib, seq.obj_name, precision=precision,
                        height=seq.height, hand_scale=seq.hand_scale, fps=seq.fps)
    frames = [frame_of(seq, t) for t in range(seq.n_frames)]
    for f in frames[:3]:  # warm-up: lazy imports, caches, the kernels' first calls
        stream.step(f)
    at = iter(range(10**9))

    def step():  # the take goes on: each call is the next frame (looping over the clip)
        return stream.step(frames[next(at) % len(frames)])

    before = gemv_gb_s()  # the floor just before and just after: a shared machine's load drifts
    out = benchmark.pedantic(step, rounds=2 * T, iterations=1)
    gemv = float(np.median(before + gemv_gb_s()))
    assert out["right"]["hand_pose"].shape == (45,)
    floor_ms = grip_weight_bytes() * BYTES_PER_WEIGHT[precision] / 4 / (gemv * 1e9) * 1e3
    benchmark.extra_info.update(precision=precision, threads=torch.get_num_threads(),
                                gemv_fp32_gb_s=gemv, floor_ms=floor_ms,
                                loadavg=list(os.getloadavg()))
    if benchmark.stats is not None:
        ms = 1e3 * np.asarray(benchmark.stats.stats.data)
        p50, p95 = float(np.percentile(ms, 50)), float(np.percentile(ms, 95))
        benchmark.extra_info.update(p50_ms=p50, p95_ms=p95, p50_over_floor=p50 / floor_ms)
        print(f"\nstream {precision}: p50 {p50:.2f} ms, p95 {p95:.2f} ms, floor "
              f"{floor_ms:.2f} ms ({gemv:.1f} GB/s GEMV), p50/floor {p50 / floor_ms:.2f}")
