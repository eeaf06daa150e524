"""Intersection volume: analytic lens and cube, grid reference, precision, failure handling."""

import igl
import numpy as np
import pytest
import trimesh

from grip_bench.metrics import (
    FailureCounter,
    cap_boundary_loops,
    intersection_volume,
    intersection_volume_batch,
    is_closed_manifold,
)


def lens_volume(r: float, d: float) -> float:
    """Volume of the lens shared by two spheres of radius r at centre distance d."""
    return np.pi * (4 * r + d) * (2 * r - d) ** 2 / 12


def sphere(r: float, centre=(0.0, 0.0, 0.0), subdiv: int = 4) -> trimesh.Trimesh:
    s = trimesh.creation.icosphere(subdiv, radius=r)
    s.apply_translation(centre)
    return s


def blob(seed: int, radius: float = 0.03, subdiv: int = 3) -> trimesh.Trimesh:
    """A closed star-shaped random blob (smooth radial bumps), hand-sized."""
    rng = np.random.default_rng(seed)
    s = trimesh.creation.icosphere(subdiv)
    u = s.vertices
    k, phase, amp = (
        rng.normal(size=(3, 3)),
        rng.uniform(0, 6, size=3),
        rng.uniform(0.05, 0.2, size=3),
    )
    bumps = sum(a * np.sin(u @ kk * 2 + p) for a, kk, p in zip(amp, k, phase, strict=True))
    stretch = rng.uniform(0.6, 1.4, size=3)
    return trimesh.Trimesh(u * (1 + bumps)[:, None] * stretch * radius, s.faces, process=False)


def grid_reference(a: trimesh.Trimesh, b: trimesh.Trimesh, pitch: float = 0.001) -> float:
    """Naive IV: cell centres of a 1 mm grid over the overlap of the boxes inside both meshes
    (exact winding-number containment, not trimesh's shell voxels)."""
    lo = np.maximum(a.bounds[0], b.bounds[0])
    hi = np.minimum(a.bounds[1], b.bounds[1])
    if np.any(lo >= hi):
        return 0.0
    axes = [np.arange(lo[i] + pitch / 2, hi[i], pitch) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    inside = igl.winding_number(a.vertices, a.faces, pts) > 0.5
    pts = pts[inside]
    inside_b = igl.winding_number(b.vertices, b.faces, pts) > 0.5
    return inside_b.sum() * pitch**3


def test_lens_of_two_spheres():
    r, d = 0.03, 0.04
    iv = intersection_volume(sphere(r), sphere(r, (d, 0, 0)))
    # icosphere facets sit inside the true sphere; 2562 vertices keep that under 1%
    assert iv == pytest.approx(lens_volume(r, d), rel=0.01)


def test_box_corner_in_box_is_exact():
    a = trimesh.creation.box([0.02] * 3)
    b = trimesh.creation.box([0.02] * 3)
    b.apply_translation([0.01, 0.01, 0.01])
    assert intersection_volume(a, b) == pytest.approx(1e-6, rel=1e-9)  # a 1 cm cube


def test_hand_worked_contained_and_disjoint():
    a = trimesh.creation.box([0.01, 0.02, 0.03])
    big = trimesh.creation.box([0.1] * 3)
    assert intersection_volume(a, big) == pytest.approx(6e-6, rel=1e-9)
    far = big.copy()
    far.apply_translation([1.0, 0, 0])
    assert intersection_volume(a, far) == 0.0  # AABB early-out: a true zero


def test_far_from_origin_and_float32_path_stay_precise(monkeypatch):
    import manifold3d

    r, d = 0.03, 0.04
    ref = intersection_volume(sphere(r), sphere(r, (d, 0, 0)))
    off = np.array([1000.0, -500.0, 250.0])
    far = intersection_volume(sphere(r, off), sphere(r, off + [d, 0, 0]))
    assert far == pytest.approx(ref, rel=1e-6)
    monkeypatch.delattr(manifold3d, "Mesh64")  # older manifold3d: float32 after the local shift
    assert intersection_volume(sphere(r, off), sphere(r, off + [d, 0, 0])) == pytest.approx(
        ref, rel=1e-3
    )


@pytest.mark.parametrize("seed", range(6))
def test_matches_grid_reference_on_random_blobs(seed):
    rng = np.random.default_rng(100 + seed)
    a, b = blob(2 * seed), blob(2 * seed + 1)
    direction = rng.normal(size=3)
    b.apply_translation(direction / np.linalg.norm(direction) * rng.uniform(0.04, 0.07))
    iv, ref = intersection_volume(a, b), grid_reference(a, b)
    if ref > 0.5e-6:  # above 0.5 cm^3 the 1 mm grid is good to a few per cent
        assert iv == pytest.approx(ref, rel=0.03)
    else:
        assert abs(iv - ref) < 0.05e-6


def test_open_mesh_is_nan_and_counted_never_zero():
    closed = sphere(0.03, subdiv=3)
    open_ = closed.copy()
    open_.update_faces(np.arange(len(open_.faces)) > 0)  # punch one triangle out
    failures = FailureCounter()
    assert np.isnan(intersection_volume(open_, closed, failures))
    assert np.isnan(intersection_volume(closed, open_, failures))
    assert failures.count == 2 and failures.reasons["open mesh"] == 2
    assert not is_closed_manifold(open_.faces) and is_closed_manifold(closed.faces)


def test_capping_the_hole_restores_a_valid_volume():
    closed = sphere(0.03, subdiv=3)
    open_ = closed.copy()
    open_.update_faces(~(open_.faces == 0).any(axis=1))  # a fan-shaped hole, like MANO's wrist
    capped = cap_boundary_loops(open_)
    assert is_closed_manifold(capped.faces)
    assert intersection_volume(capped, closed) == pytest.approx(closed.volume, rel=0.01)


def test_batch_matches_single_with_object_poses():
    from scipy.spatial.transform import Rotation

    obj, hand = blob(7), blob(8, radius=0.025)
    T = 4
    rots = Rotation.random(T, random_state=0).as_matrix()
    trans = np.random.default_rng(9).normal(size=(T, 3))
    shift = np.random.default_rng(10).uniform(-0.02, 0.02, size=(T, 3))
    hv = np.stack([hand.vertices + trans[t] + shift[t] for t in range(T)])
    hv[-1] += 1.0  # one frame far away: early-out
    failures = FailureCounter()
    out = intersection_volume_batch(hv, hand.faces, obj, rots, trans, failures)
    for t in range(T):
        posed = obj.copy()
        posed.apply_transform(np.block([[rots[t], trans[t][:, None]], [np.zeros((1, 3)), 1]]))
        assert out[t] == pytest.approx(
            intersection_volume(trimesh.Trimesh(hv[t], hand.faces), posed), rel=1e-6, abs=1e-12
        )
    assert out[-1] == 0.0 and failures.count == 0
    bad = intersection_volume_batch(hv, hand.faces[1:], obj, rots, trans, failures)
    assert np.isnan(bad).all() and failures.count == T
