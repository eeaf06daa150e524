"""TOCH ray casting: the grid broad phase over many poses at once against a naive
all-pairs reference (every ray against every triangle, pytorch3d-style), and its tie rule."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
import torch
from grip_baselines import toch
from scipy.spatial.transform import Rotation

if TYPE_CHECKING:
    from grip_bench.bodies.hand import ProceduralHand

pytestmark = pytest.mark.usefixtures("one_thread")  # the 2 test cores are shared


def naive_hits(
    o: np.ndarray, d: np.ndarray, v: np.ndarray, faces: np.ndarray, max_dist: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The module's rule the slow way: Möller-Trumbore of every ray against every
    triangle (numpy, no broad phase), nearest crossing within ``max_dist`` decides
    inside/outside, then the nearest crossing on the side the rule picks."""
    v0, v1, v2 = (v[faces[:, k]] for k in range(3))
    e1, e2 = v1 - v0, v2 - v0
    n = len(o)
    t_out, face_out, bary_out = np.full(n, np.nan), np.full(n, -1), np.zeros((n, 3))
    for i in range(n):
        p = np.cross(d[i], e2)
        det = (e1 * p).sum(1)
        ok = np.abs(det) > 1e-15
        inv = 1.0 / np.where(ok, det, 1.0)
        s = o[i] - v0
        u = (s * p).sum(1) * inv
        q = np.cross(s, e1)
        w = (d[i] * q).sum(1) * inv
        t = (e2 * q).sum(1) * inv
        ok &= (u >= -1e-9) & (w >= -1e-9) & (u + w <= 1 + 1e-9) & (np.abs(t) <= max_dist)
        if not ok.any():
            continue
        leaving = np.cross(e1, e2) @ d[i] > 0
        ids = np.flatnonzero(ok)
        nearest = ids[np.argmin(np.abs(t[ids]))]
        inside = leaving[nearest] if t[nearest] >= 0 else not leaving[nearest]
        side = ids[t[ids] < 0] if inside else ids[t[ids] >= 0]
        if len(side):
            k = side[np.argmin(np.abs(t[side]))]
            t_out[i], face_out[i] = t[k], k
            bary_out[i] = 1 - u[k] - w[k], u[k], w[k]
    return t_out, face_out, bary_out


def test_batched_grid_broad_phase_equals_naive_all_pairs(hand: ProceduralHand) -> None:
    """Three poses of the hand (one scaled x2.5, so its triangles need a wider grid than
    the cached one) against the same rays: the same hits as the all-pairs reference, and
    each pose alone gives the batch's row bit for bit."""
    canon = hand.template_vertices.double().numpy()
    faces = np.asarray(hand.faces)
    rng = np.random.default_rng(1)
    o = rng.uniform([-0.2, -0.05, -0.06], [0.03, 0.03, 0.08], (120, 3))
    d = rng.normal(size=(120, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rot = Rotation.from_rotvec([0.2, -0.3, 0.1]).as_matrix()
    poses = [canon, canon @ rot.T + [0.01, 0.0, -0.005], (canon - canon.mean(0)) * 2.5]
    toch._GRIDS.clear()
    t, face, bary = toch.ray_mesh_hits_batch(o, d, np.stack(poses[:2]), faces, 0.05)
    t2, face2, bary2 = toch.ray_mesh_hits_batch(o, d, np.stack(poses), faces, 0.05)  # wider
    np.testing.assert_array_equal(face2[:2], face)
    np.testing.assert_array_equal(t2[:2], t)
    assert (face2 >= 0).sum() > 60 and (t2 < 0).sum() > 10  # outside and inside cases both seen
    for k, v in enumerate(poses):
        t_ref, face_ref, bary_ref = naive_hits(o, d, v, faces, 0.05)
        np.testing.assert_array_equal(face2[k], face_ref)
        np.testing.assert_allclose(t2[k], t_ref, rtol=0, atol=1e-15)
        np.testing.assert_allclose(bary2[k], bary_ref, rtol=0, atol=1e-12)
        one = toch.ray_mesh_hits(o, d, v, faces, 0.05)
        for a, b in zip(one, (t2[k], face2[k], bary2[k]), strict=True):
            np.testing.assert_array_equal(a, b)


def test_exact_tie_goes_to_the_earlier_triangle_in_z_order(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A ray through the shared edge of two triangles meets both at the same ``t``; the
    hit is the one the sphere-tree broad phase listed first (the earlier in Z-order), as
    before the grid, so fields stay the same bit for bit."""
    # A closed tetrahedron-like slab: two coplanar top triangles sharing the edge x = z.
    v = np.array(
        [[0, 1, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1], [0.5, 0, 0.5]], np.float64
    ) * 0.02
    faces = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    o = np.array([[0.005, 0.05, 0.005]])  # above the shared edge (0,0,0)-(1,1,1)*0.02 in xz
    d = np.array([[0.0, -1.0, 0.0]])
    orders: list[int] = []
    morton = toch._morton_order
    monkeypatch.setattr(toch, "_morton_order", lambda c: (orders.append(len(c)), morton(c))[1])
    t, face, _ = toch.ray_mesh_hits(o, d, v, faces, 0.1)
    assert face[0] in (0, 1) and t[0] == pytest.approx(0.03)
    assert orders == [len(faces)]  # the tie was seen and broken by the Z-order
    tri = torch.as_tensor(v[faces])
    order = toch._morton_order((tri[:, 0] + tri[:, 1] + tri[:, 2]) / 3).numpy()
    rank = np.argsort(order)
    assert rank[0] != rank[1]
    assert face[0] == (0 if rank[0] < rank[1] else 1)
    # Listing the faces the other way round renames them, the triangle chosen stays.
    t_f, face_f, _ = toch.ray_mesh_hits(o, d, v, faces[[1, 0, 2, 3, 4, 5]], 0.1)
    assert t_f[0] == t[0] and face_f[0] == 1 - face[0]
