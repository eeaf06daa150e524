"""Benchmarks of ProceduralHand: batched forward (10k poses), template build, clamp."""

from __future__ import annotations

import pytest
import torch

from grip_bench.bodies import hand_template as hand_mod
from grip_bench.bodies.hand import ProceduralHand

N_POSES = 10_000


@pytest.fixture(scope="module")
def hand():
    return ProceduralHand("right")


@pytest.fixture(scope="module")
def poses(hand):
    g = torch.Generator().manual_seed(0)
    return torch.zeros(N_POSES, 3), hand.sample_pose(N_POSES, generator=g), torch.zeros(N_POSES, 3)


def test_bench_forward_10k(benchmark, hand, poses):
    """Vertices + keypoints of 10k poses in one batched call, float32, no grad."""
    with torch.no_grad():
        verts, joints = benchmark.pedantic(hand, args=poses, rounds=3, iterations=1)
    assert verts.shape == (N_POSES, hand.num_vertices, 3) and joints.shape == (N_POSES, 21, 3)


def test_bench_forward_single(benchmark, hand, poses):
    """One pose (the per-frame latency GRIP's pipeline pays)."""
    go, pose, tr = (x[:1] for x in poses)
    with torch.no_grad():
        benchmark(hand, go, pose, tr)


def test_bench_clamp_10k(benchmark, hand, poses):
    benchmark(hand.clamp, poses[1])


def test_bench_template_build(benchmark, monkeypatch):
    """Cold template build: SDF grid, level set, decimation, relaxation, weights."""
    monkeypatch.setenv("GRIP_BENCH_CACHE", "off")  # not from the on-disk geometry cache

    def build():
        hand_mod._template_mesh.cache_clear()
        hand_mod._template.cache_clear()
        return ProceduralHand("right")

    benchmark.pedantic(build, rounds=2, iterations=1)


def test_bench_forward_sequence_float64(benchmark):
    """One evaluation sequence: 260 frames posed in float64 (what ``evaluate`` does per hand)."""
    hand = ProceduralHand("right").double()
    g = torch.Generator().manual_seed(1)
    pose = hand.sample_pose(260, generator=g)
    go, tr = torch.zeros(260, 3, dtype=torch.float64), torch.zeros(260, 3, dtype=torch.float64)
    with torch.no_grad():
        benchmark(hand, go, pose, tr)
