"""ProceduralHand's matrix-product LBS against the per-vertex-matrix formulation it replaced."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from grip_bench.bodies.hand import ProceduralHand


def reference_lbs(hand: ProceduralHand, pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The previous ``_lbs``: blend a 3 x 4 matrix per vertex, then apply it."""
    rest = hand.rest_joints.to(pose)
    rot, pos = hand.kinematics(pose)
    shift = pos - torch.einsum("njac,jc->nja", rot, rest)
    blend = torch.cat([rot.flatten(2), shift], 2)  # (B, 16, 12)
    per_vertex = torch.einsum("vj,bjk->bvk", hand.weights.to(pose), blend)
    r = per_vertex[..., :9].reshape(*per_vertex.shape[:2], 3, 3)
    verts = torch.einsum("nvac,vc->nva", r, hand.template_vertices.to(pose)) + per_vertex[..., 9:]
    return verts, torch.cat([pos, verts[:, hand.tip_index]], 1)


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-6), (torch.float64, 1e-12)])
def test_lbs_matches_the_per_vertex_formulation(side, dtype, tol):
    hand = ProceduralHand(side, scale=1.1).to(dtype)
    g = torch.Generator().manual_seed(7)
    pose = hand.sample_pose(33, generator=g)
    with torch.no_grad():
        v, j = hand._lbs(pose)
        rv, rj = reference_lbs(hand, pose)
    assert v.dtype == dtype and v.shape == rv.shape and j.shape == rj.shape
    assert (v - rv).abs().max() < tol and (j - rj).abs().max() < tol


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-6), (torch.float64, 1e-12)])
def test_forward_matches_the_reference_with_a_global_pose(dtype, tol):
    from grip_bench.geometry.rotations import axis_angle_to_matrix

    hand = ProceduralHand("right").to(dtype)
    g = torch.Generator().manual_seed(11)
    pose = hand.sample_pose(9, generator=g)
    go = (torch.rand(9, 3, generator=g, dtype=dtype) - 0.5) * 4.0
    tr = torch.rand(9, 3, generator=g, dtype=dtype) - 0.5
    with torch.no_grad():
        v, j = hand(go, pose, tr)
        rv, rj = reference_lbs(hand, pose)
        rot = axis_angle_to_matrix(go)
        rv, rj = rv @ rot.transpose(1, 2) + tr[:, None], rj @ rot.transpose(1, 2) + tr[:, None]
    assert v.is_contiguous() and v.dtype == dtype
    assert (v - rv).abs().max() < tol and (j - rj).abs().max() < tol


def test_lbs_gradients_match_the_reference():
    hand = ProceduralHand("right").double()
    g = torch.Generator().manual_seed(3)
    base = hand.sample_pose(4, generator=g)
    w = torch.randn(4, hand.num_vertices, 3, generator=g, dtype=torch.float64)
    go0 = torch.randn(4, 3, generator=g, dtype=torch.float64)
    tr0 = torch.randn(4, 3, generator=g, dtype=torch.float64)

    def reference(p, go, tr):
        from grip_bench.geometry.rotations import axis_angle_to_matrix

        v, j = reference_lbs(hand, p)
        rot = axis_angle_to_matrix(go)
        return v @ rot.transpose(1, 2) + tr[:, None], j @ rot.transpose(1, 2) + tr[:, None]

    grads = []
    for fn in (hand, reference):
        pose, go, tr = (x.clone().requires_grad_(True) for x in (base, go0, tr0))
        v, j = fn(pose, go, tr) if fn is reference else fn(go, pose, tr)
        ((v * w).sum() + j.square().sum()).backward()
        grads.append((pose.grad, go.grad, tr.grad))
    for a, b in zip(*grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


def test_forward_batches_and_chunks_agree():
    hand = ProceduralHand("left")
    g = torch.Generator().manual_seed(5)
    pose = hand.sample_pose(5, generator=g)
    with torch.no_grad():
        v, j = hand(None, pose)
        for k in range(5):
            vk, jk = hand(None, pose[k : k + 1])
            torch.testing.assert_close(vk[0], v[k], rtol=0, atol=1e-7)
            torch.testing.assert_close(jk[0], j[k], rtol=0, atol=1e-7)


def test_template_mesh_is_the_same_from_the_geometry_cache(tmp_path, monkeypatch):
    from grip_bench.bodies import hand_template as hand_mod

    monkeypatch.setenv("GRIP_BENCH_CACHE", "off")
    built = hand_mod._build_template_mesh()
    monkeypatch.setenv("GRIP_BENCH_CACHE", str(tmp_path))
    hand_mod._template_mesh.cache_clear()
    try:
        first = hand_mod._template_mesh()  # builds and stores
        hand_mod._template_mesh.cache_clear()
        again = hand_mod._template_mesh()  # reads
    finally:
        hand_mod._template_mesh.cache_clear()
    assert len(list(tmp_path.rglob("*.npz"))) == 1
    for v, f in (first, again):
        assert v.dtype == built["vertices"].dtype and f.dtype == built["faces"].dtype
        np.testing.assert_array_equal(v, built["vertices"])
        np.testing.assert_array_equal(f, built["faces"])
