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


def test_exact_distance_matches_libigl_and_trimesh_near_a_hand():
    """The cached-tree distance against ``igl.signed_distance`` (pseudonormal signs, the
    reference it replaces) on points around the procedural hand, on its vertices, face
    centres and edge midpoints (the features whose sign needs a pseudonormal), and against
    trimesh's independent signed distance on a sample."""
    import igl

    from grip_bench.bodies.hand import ProceduralHand

    hand = ProceduralHand()
    v = hand.template_vertices.detach().double().numpy()
    f = np.asarray(hand.faces, dtype=np.int64)
    rng = np.random.default_rng(0)
    near = v[rng.integers(0, len(v), 4000)] + rng.normal(0, 0.004, (4000, 3))
    p = np.concatenate([near, v, v[f].mean(1), 0.5 * (v[f[:, 0]] + v[f[:, 1]])])
    d = ExactDistance(v, f)
    ref = igl.signed_distance(p, v, f, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0]
    np.testing.assert_allclose(d(p), ref, atol=1e-12)
    np.testing.assert_allclose(d(p[:50]), ref[:50], atol=1e-12)  # the tree is reused
    # trimesh (+ inside) picks candidate faces by bounding box: the same signs, distances
    # within 20 um (its closest point inside the thin hand is not always the nearest face)
    tm = -trimesh.proximity.signed_distance(trimesh.Trimesh(v, f, process=False), near[:300])
    mine = d(near[:300])
    assert (np.sign(mine) == np.sign(tm)).all()
    np.testing.assert_allclose(mine, tm, atol=2e-5)


def test_refined_pieces_meet_the_bound_on_a_bent_surface():
    """Pieces built on a straight bar (large patches: 256 faces) and re-posed on the bar
    bent 90 degrees at x = 0 round a 20 mm radius (a finger flexing; the bar is 12 mm
    thick, so nothing self-intersects) stick out past the bound (3.3 mm); ``refine_pieces``
    rebuilds those on the bent surface, within the bound (measured independently), every
    face still covered."""
    from grip_bench.geometry.pieces import outward_errors, refine_pieces

    bar = trimesh.creation.box(extents=[0.08, 0.012, 0.016])
    for _ in range(3):
        bar = bar.subdivide()
    v0 = np.asarray(bar.vertices)
    radius, arc = 0.02, 0.02 * np.pi / 2
    x = v0[:, 0]
    theta = np.clip(x, 0, arc) / radius  # 0..90 degrees over the arc, then straight on
    r, rest = radius - v0[:, 1], np.clip(x - arc, 0, None)
    fold = v0.copy()
    bent = x > 0
    fold[bent, 0] = (r * np.sin(theta) + rest * np.cos(theta))[bent]
    fold[bent, 1] = (radius - r * np.cos(theta) + rest * np.sin(theta))[bent]
    f = np.asarray(bar.faces)
    pieces = surface_pieces(v0, f, labels=np.zeros(len(v0), int), depth=C.PIECE_HAND_DEPTH,
                            patch_faces=256)
    sdf = ExactDistance(fold, f)
    normals = vertex_normals(fold, f)
    err = outward_errors(pieces.points(fold, normals), sdf)
    assert err.max() > C.PIECE_MAX_ERROR  # the fold breaks some of them
    better = refine_pieces(pieces, err, fold, f, sdf, normals)
    after = outward_errors(better.points(fold, normals), sdf)
    np.testing.assert_allclose(after, better.error, atol=1e-12)
    assert after.max() <= C.PIECE_MAX_ERROR
    folded = trimesh.Trimesh(fold, f, process=False)
    rng = np.random.default_rng(0)
    pts = better.points(fold, normals)
    worst = max(naive_outward_error(p, folded, rng) for p in pts[:: max(1, len(pts) // 30)])
    assert worst <= C.PIECE_MAX_ERROR + 1e-4
    covered = np.zeros(len(f), bool)
    for ids in better.vertex_ids:
        covered |= np.isin(f, ids).all(1)
    assert covered.all()


def test_round_trip_through_arrays():
    bowl = bowl_mesh()
    pieces = surface_pieces(bowl.vertices, bowl.faces)
    back = SurfacePieces.from_arrays(pieces.to_arrays())
    assert len(back) == len(pieces)
    assert all(np.array_equal(a, b) for a, b in zip(back.vertex_ids, pieces.vertex_ids,
                                                          strict=True))
    assert np.array_equal(back.error, pieces.error)


def test_hull_samples_of_many_sets_equal_a_loop_over_each_hull():
    """``hull_samples`` gathers every set's hull vertices, face centroids and edge midpoints
    at once; a per-hull loop (midpoints of every face's three edges, so each edge twice) has
    the same points per set, and flat or degenerate sets give their own points."""
    from scipy.spatial import ConvexHull

    from grip_bench.geometry.pieces import hull_samples

    rng = np.random.default_rng(3)
    sets = [rng.normal(size=(n, 3)) * [1, 1, 0.2] for n in (4, 9, 30)]
    sets += [np.zeros((3, 3)), rng.normal(size=(6, 3)) * [1, 1, 0]]  # a point, a plane
    samples, owner = hull_samples(sets)
    for i, p in enumerate(sets):
        mine = samples[owner == i]
        if i >= 3:
            np.testing.assert_array_equal(mine, p)
            continue
        h = ConvexHull(p)
        tri = p[h.simplices]
        ref = np.concatenate([p[h.vertices], tri.mean(1),
                              (0.5 * (tri + tri[:, [1, 2, 0]])).reshape(-1, 3)])
        assert len(mine) == len(h.vertices) + len(tri) + len(tri) * 3 // 2  # Euler: E = 3F/2
        assert {tuple(x) for x in mine} == {tuple(x) for x in ref}


def test_scatter_sum_is_np_add_at_bit_for_bit():
    """The bincount scatter adds each row's terms in np.add.at's order, so the sums (and the
    normals and pseudonormals built on them) are the same floats, not merely close."""
    from grip_bench.geometry.pieces import scatter_sum

    rng = np.random.default_rng(3)
    index = rng.integers(0, 50, 4000)
    values = rng.normal(size=(4000, 3)) * 10.0 ** rng.integers(-6, 3, (4000, 1))
    naive = np.zeros((60, 3))
    np.add.at(naive, index, values)
    assert np.array_equal(scatter_sum(index, values, 60), naive)


def test_edge_ids_equal_a_row_wise_unique():
    """One integer key per edge orders the edges as ``np.unique(..., axis=0)`` does."""
    from grip_bench.geometry.pieces import _edge_ids

    mesh = trimesh.creation.icosphere(3)
    f = np.asarray(mesh.faces, np.int64)
    edges = np.stack([np.sort(f[:, [(k + 1) % 3, (k + 2) % 3]], axis=1) for k in range(3)],
                     axis=1).reshape(-1, 2)
    _, naive = np.unique(edges, axis=0, return_inverse=True)
    assert np.array_equal(_edge_ids(f, len(mesh.vertices)), naive.reshape(-1))
    assert _edge_ids(f, len(mesh.vertices)) is _edge_ids(f.copy(), len(mesh.vertices))  # cached
