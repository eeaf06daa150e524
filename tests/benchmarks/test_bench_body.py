"""ProceduralBody forward kinematics and arm IK throughput (pytest-benchmark; measures only)."""

from __future__ import annotations

import pytest
import torch

from grip_bench.bodies.body import ProceduralBody

N_FRAMES = 10_000


@pytest.fixture(scope="module")
def body():
    return ProceduralBody()


@pytest.fixture(scope="module")
def poses():
    g = torch.Generator().manual_seed(0)
    r = lambda *s: torch.randn(*s, generator=g)  # noqa: E731
    return dict(global_orient=r(N_FRAMES, 3) * 0.3, body_pose=r(N_FRAMES, 21, 3) * 0.3,
                transl=r(N_FRAMES, 3), left_hand_pose=r(N_FRAMES, 15, 3) * 0.3,
                right_hand_pose=r(N_FRAMES, 15, 3) * 0.3)


def test_bench_fk_10k_frames(benchmark, body, poses):
    out = benchmark(lambda: body(**poses))
    assert out.joints.shape == (N_FRAMES, 55, 3)


def test_bench_arm_ik_10k_frames(benchmark, body, poses):
    target = body(**poses).joints[:, 20] + 0.05
    rot = torch.eye(3).expand(N_FRAMES, 3, 3)
    pose, _ = benchmark(lambda: body.solve_arm("left", poses["global_orient"], poses["body_pose"],
                                               poses["transl"], target, rot))
    assert pose.shape == (N_FRAMES, 21, 3)
