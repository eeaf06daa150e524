"""Baseline feature costs on CPU: TOCH correspondence field (2000 rays per frame against
the procedural hand) and the BPS code of one object (4096 basis points).

Measures; asserts nothing about time. Run with ``pytest tests/benchmarks/test_bench_baselines.py
--benchmark-enable`` (the default run skips benchmarks).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from grip_baselines import bps, toch

from grip_bench.core.constants import TOCH_N_POINTS


@pytest.fixture(scope="module")
def grasp_scene():
    """A relaxed right hand over a sphere of radius 4 cm, and 2000 surface samples."""
    from grip_bench.bodies import ProceduralHand

    hand = ProceduralHand("right")
    pose = hand.named_pose("relaxed")[None].double()
    verts = hand(
        torch.zeros(1, 3, dtype=torch.float64), pose, torch.zeros(1, 3, dtype=torch.float64)
    )[0][0]
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.04)
    ball.apply_translation([-0.08, -0.05, 0.0])  # under the palm, fingers curled around
    pts, face = trimesh.sample.sample_surface_even(ball, TOCH_N_POINTS, seed=0)
    canon = hand.template_vertices.double().numpy()
    return pts, ball.face_normals[face], verts.numpy(), hand.faces, canon


def test_bench_correspondence_field(benchmark, grasp_scene):
    torch.set_num_threads(1)
    pts, nrm, verts, faces, canon = grasp_scene
    field = benchmark(toch.correspondence_field, pts, nrm, verts, faces, canon)
    benchmark.extra_info.update(rays=len(pts), hand_faces=len(faces), hits=int(field.hit.sum()))


def test_bench_bps_one_object(benchmark):
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    basis = bps.basis_points()
    code = benchmark(bps.bps_encode, mesh, basis)
    benchmark.extra_info.update(
        basis_points=len(basis), faces=len(mesh.faces), mean_dist=float(np.mean(code))
    )
