"""Bounded-error collision pieces (grip_bench.geometry.pieces), checked against an independent
naive measurement: trimesh's signed distance on random points of each piece's hull."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grip_bench.core import constants as C
from grip_bench.geometry.meshes import from_manifold, to_manifold
from grip_bench.geometry.pieces import (
    ExactDistance,
    SurfacePieces,
    surface_pieces,
    vertex_normals,
)


def bowl_mesh() -> trimesh.Trimesh:
    """Hemispherical shell, outer radius 5 cm, wall 5 mm, open side up (+y)."""
    outer = trimesh.creation.icosphere(4, radius=0.05)
    inner = trimesh.creation.icosphere(4, radius=0.045)
    lid = trimesh.creation.box(extents=[0.2, 0.1, 0.2])
    lid.apply_translation([0, 0.05, 0])
    return from_manifold(to_manifold(outer) - to_manifold(inner) - to_manifold(lid))


def naive_outward_error(points: np.ndarray, mesh: trimesh.Trimesh, rng) -> float:
    """Largest distance outside ``mesh`` of 400 random points on the hull of ``points``."""
    hull = trimesh.convex.convex_hull(points)
    samples = np.concatenate([hull.sample(400, seed=int(rng.integers(1 << 30))), hull.vertices])
    inside_positive = trimesh.proximity.signed_distance(mesh, samples)  # trimesh: + inside
    return float(max(0.0, (-inside_positive).max()))


def test_convex_mesh_is_one_exact_piece():
    cube = trimesh.creation.box(extents=[0.04] * 3)
    pieces = surface_pieces(cube.vertices, cube.faces)
    assert len(pieces) == 1 and pieces.error[0] == pytest.approx(0.0, abs=1e-12)
    assert np.isnan(pieces.depth[0])


def test_bowl_pieces_stay_within_the_bound_measured_independently():
    bowl = bowl_mesh()
    pieces = surface_pieces(bowl.vertices, bowl.faces)
    assert len(pieces) > 1  # a bowl is never its own hull
    assert pieces.error.max() <= C.PIECE_MAX_ERROR
    pts = pieces.points(np.asarray(bowl.vertices), vertex_normals(bowl.vertices, bowl.faces))
    rng = np.random.default_rng(0)
    worst = max(naive_outward_error(p, bowl, rng) for p in pts[:: max(1, len(pts) // 40)])
    # the reference samples the hull surface densely; the bound holds up to sampling
    assert worst <= C.PIECE_MAX_ERROR + 1e-4


def test_every_face_is_covered_and_labels_are_respected():
    bowl = bowl_mesh()
    labels = (np.asarray(bowl.vertices)[:, 0] > 0).astype(int)
    pieces = surface_pieces(bowl.vertices, bowl.faces, labels=labels)
    covered = np.zeros(len(bowl.faces), bool)
    for ids in pieces.vertex_ids:
        covered |= np.isin(bowl.faces, ids).all(1)
        # a piece's vertices carry one label, except the corners of faces between labels
        assert len(np.unique(labels[ids])) <= 2
    assert covered.all()


def test_exact_distance_matches_an_analytic_sphere():
    sphere = trimesh.creation.icosphere(5, radius=0.03)
    d = ExactDistance(sphere.vertices, sphere.faces)
    p = np.array([[0, 0, 0.05], [0, 0, 0.0], [0.02, 0, 0]])
    assert np.allclose(d(p), [0.02, -0.03, -0.01], atol=2e-4)  # faceting of a 30 mm sphere


def test_round_trip_through_arrays():
    bowl = bowl_mesh()
    pieces = surface_pieces(bowl.vertices, bowl.faces)
    back = SurfacePieces.from_arrays(pieces.to_arrays())
    assert len(back) == len(pieces)
    assert all(np.array_equal(a, b) for a, b in zip(back.vertex_ids, pieces.vertex_ids,
                                                          strict=True))
    assert np.array_equal(back.error, pieces.error)
