"""The whole GRIP pipeline at the paper's widths (hidden 2048, width 1024, latent 256) on CPU.

ANet (autoregressive, one step per frame), stage-one sensors (ambient + proximity),
CNet on frame pairs, proximity recomputed on CNet's hands, RNet on interaction frames,
both hands. Weights are random (speed does not depend on them); the residual ANet head
is zeroed as in training so the wrists stay on the sequence.

- offline: 1 or 16 copies of a 120-frame grasping sequence per call, or one 300-frame
  sequence (what ``grip-bench predict`` does: one sequence per call) -> frames/s
  (``extra_info``); ANet's recursion runs in overlapping pieces side by side, and with 16
  sequences ANet, CNet and RNet are batched across them too;
- precision: fp32 (what the tables use) and bf16 (``--precision bf16``);
- online: the latency of one new frame, measured as the pipeline on the 2-frame window
  (t-1, t) in streaming mode: an upper bound, as it recomputes frame t-1's sensors too.

Run: ``pytest tests/benchmarks/test_bench_grip_pipeline.py -o addopts="" --benchmark-only -s``.
Measures; asserts nothing about time. Compare with ``grip_bench.grip.flops`` (the FLOPs
floor of the networks alone: ``pipeline_flops_per_frame``).
"""

from __future__ import annotations

import os

import pytest
import torch

from grip_bench.data.grab_io import read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.grip import ANetConfig, CNetConfig, RNetConfig
from grip_bench.grip.flops import pipeline_flops_per_frame
from grip_bench.grip.pipeline import GripPipeline, Options
from grip_bench.grip.train import Variant
from tests.eval_fixtures import grasp_dataset

T = 120


def paper_nets() -> dict:
    torch.manual_seed(0)
    nets = {
        "anet": ANetConfig().build(),
        "cnet": CNetConfig().build(),
        "rnet": RNetConfig().build(),
    }
    torch.nn.init.zeros_(nets["anet"].decoder.head.weight)
    torch.nn.init.zeros_(nets["anet"].decoder.head.bias)
    return {k: n.eval() for k, n in nets.items()}


def _scene(root, n_frames: int):
    seq = read_grab(grasp_dataset(root, T=n_frames)[0])
    lib = ObjectLibrary(root)
    lib.field(seq.obj_name)  # the distance field is built once per object, outside the timing
    torch.set_num_threads(os.cpu_count() or 1)  # the fixture's grasp search pins one thread
    return seq, lib


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return _scene(tmp_path_factory.mktemp("pipeline"), T)


@pytest.fixture(scope="module")
def long_scene(tmp_path_factory):
    """One 300-frame sequence: 10 s at 30 fps, about a GRAB sequence (SynthGRAB's test split
    averages 270 frames)."""
    return _scene(tmp_path_factory.mktemp("pipeline_long"), 300)


def _flops() -> float:
    """Network FLOPs per output frame, RNet counted on every frame (an upper bound)."""
    return pipeline_flops_per_frame(CNetConfig(), ANetConfig(), RNetConfig())


@pytest.mark.parametrize("n_seqs,precision", [(1, "fp32"), (1, "bf16"), (16, "fp32"), (16, "bf16")])
def test_bench_pipeline_offline(benchmark, scene, n_seqs, precision):
    """``n_seqs`` sequences per call (``run_many``: ANet, CNet and RNet batched across them)."""
    seq, lib = scene
    seqs = [seq] * n_seqs
    pipe = GripPipeline(paper_nets(), Options(Variant(), precision=precision))
    pipe.run_many(seqs[:2], lib)  # warm-up: allocations, lazy imports
    out = benchmark.pedantic(lambda: pipe.run_many(seqs, lib), rounds=3, iterations=1)
    assert len(out) == n_seqs and out[0].n_frames == T
    frames = T * n_seqs
    benchmark.extra_info.update(
        frames=frames, threads=torch.get_num_threads(), net_flops_per_frame=_flops()
    )
    if benchmark.stats is not None:
        benchmark.extra_info["frames_per_s"] = frames / benchmark.stats.stats.mean


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_bench_pipeline_offline_one_long_sequence(benchmark, long_scene, precision):
    """``grip-bench predict``'s setting: one sequence per call, its frames batched."""
    seq, lib = long_scene
    pipe = GripPipeline(paper_nets(), Options(Variant(), precision=precision))
    pipe.run(seq, lib)  # warm-up
    out = benchmark.pedantic(lambda: pipe.run(seq, lib), rounds=3, iterations=1)
    assert out.n_frames == seq.n_frames
    benchmark.extra_info.update(frames=seq.n_frames, threads=torch.get_num_threads())
    if benchmark.stats is not None:
        benchmark.extra_info["frames_per_s"] = seq.n_frames / benchmark.stats.stats.mean


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_bench_pipeline_online_frame(benchmark, scene, precision):
    seq, lib = scene
    window = seq.frames(T // 2 - 1, T // 2 + 1)
    pipe = GripPipeline(paper_nets(), Options(Variant(), online=True, precision=precision))
    pipe.run(window, lib)
    out = benchmark.pedantic(lambda: pipe.run(window, lib), rounds=20, iterations=1)
    assert out.n_frames == 2
    if benchmark.stats is not None:
        benchmark.extra_info["latency_ms"] = 1e3 * benchmark.stats.stats.mean
