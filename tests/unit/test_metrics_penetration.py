"""Penetration depth: sphere dipped into a half-space, loop reference, hand-worked values."""

import numpy as np
import pytest
import trimesh

from grip_bench.metrics import exact_signed_distance, penetration_depth, penetration_depth_from_sdf


def half_space(size: float = 1.0) -> trimesh.Trimesh:
    """A big box whose top face is the plane z = 0."""
    box = trimesh.creation.box([size] * 3)
    box.apply_translation([0, 0, -size / 2])
    return box


@pytest.mark.parametrize("depth", [0.0005, 0.003, 0.012])
def test_sphere_dipped_to_known_depth(depth):
    ball = trimesh.creation.uv_sphere(radius=0.02)  # has a vertex at the south pole (0, 0, -r)
    ball.apply_translation([0.1, -0.2, 0.02 - depth])
    assert penetration_depth(ball, half_space()) == pytest.approx(depth, abs=1e-9)


def test_no_vertex_inside_is_a_true_zero():
    ball = trimesh.creation.uv_sphere(radius=0.02)
    ball.apply_translation([0, 0, 0.021])
    assert penetration_depth(ball, half_space()) == 0.0


def test_signed_distance_matches_brute_force_for_a_box():
    rng = np.random.default_rng(11)
    box = trimesh.creation.box([0.04, 0.06, 0.08])
    pts = rng.uniform(-0.05, 0.05, size=(200, 3))
    half = np.array([0.02, 0.03, 0.04])
    q = np.abs(pts) - half  # exact box SDF (Inigo Quilez's formula), negative inside
    ref = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    np.testing.assert_allclose(exact_signed_distance(box, pts), ref, atol=1e-12)


def test_array_version_hand_worked():
    d = np.array([[0.01, -0.002, -0.0005], [0.003, 0.004, 0.01]])
    np.testing.assert_allclose(penetration_depth_from_sdf(d), [0.002, 0.0])
