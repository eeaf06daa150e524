"""The far="coarse" read path: each point's grid decided once, one read per grid, bit for bit
the sequential per-point path it replaced (kept here as the reference); the grouped form."""

import manifold3d
import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from grip_bench.core.errors import InputError
from grip_bench.geometry import distance as D
from grip_bench.geometry.meshes import from_manifold


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


def _cup():
    """A hollow cup with a ring handle (thin walls: kinks, unreliable cells), metres."""
    cyl = manifold3d.Manifold.cylinder
    body = cyl(0.10, 0.04, 0.04, 48) - cyl(0.10, 0.037, 0.037, 48).translate((0, 0, 0.003))
    ring = cyl(0.008, 0.03, 0.03, 24) - cyl(0.02, 0.022, 0.022, 24).translate((0, 0, -0.006))
    return from_manifold(body + ring.rotate((90, 0, 0)).translate((0.05, 0.004, 0.05)))


SHAPES = {
    "sphere": lambda: trimesh.creation.icosphere(subdivisions=3, radius=0.04),
    "box": lambda: trimesh.creation.box((0.12, 0.05, 0.03)),
    "cup": _cup,
}


@pytest.fixture(scope="module")
def fields():
    return {name: D.DistanceField(make()) for name, make in SHAPES.items()}


def reference_tiered(field, q, exact_cells):
    """``signed_distance(q, far="coarse")`` as it was computed before one-read-per-grid: the
    fine grid reads the points it holds, then each far tier reads *every* remaining point and
    keeps those inside its box, the exact path beyond the last tier."""
    out = np.empty(len(q))
    rest = np.flatnonzero(field._outside_grid(q))
    inside = np.ones(len(q), bool)
    inside[rest] = False
    if inside.any():
        near = q[inside]
        out[inside] = field._near_first(near, "exact") if exact_cells else field.interpolated(near)
    for tier in field._far_tiers():
        if not len(rest):
            break
        sub = q[rest]
        d = D._read(tier._vol, tier._scale, tier._shift, sub)
        beyond = D._outside_box(sub, tier.origin, tier._hi)
        out[rest[~beyond]] = d[~beyond]
        rest = rest[beyond]
    if len(rest):
        out[rest] = field._exact_values(q[rest])
    return out


def _probe_points(field, rng, n=20000):
    """Points at every level: near the surface, in each far tier, beyond the last, and on
    each grid box's faces and corners (exactly, and one float step either side)."""
    lo, hi = field.mesh.bounds
    centre = (lo + hi) / 2
    pts = [centre + rng.uniform(-1.0, 1.0, (n, 3)) * rng.choice([0.06, 0.15, 0.5, 1.0], (n, 1))]
    s, _ = trimesh.sample.sample_surface(field.mesh, 2000, seed=rng)
    pts.append(s + rng.normal(scale=0.01, size=s.shape))
    for blo, bhi in field._boxes():
        u = rng.uniform(0, 1, (300, 3))
        for k in range(3):
            for face in (blo[k], bhi[k]):
                p = blo + u * (bhi - blo)
                for v in (face, np.nextafter(face, -np.inf), np.nextafter(face, np.inf)):
                    p = p.copy()
                    p[:, k] = v
                    pts.append(p)
        corners = np.array([[(blo, bhi)[i][0], (blo, bhi)[j][1], (blo, bhi)[m][2]]
                            for i in (0, 1) for j in (0, 1) for m in (0, 1)])
        pts.append(corners)
    return np.concatenate(pts)


@pytest.mark.parametrize("shape", list(SHAPES))
def test_coarse_is_the_sequential_path_bit_for_bit(fields, shape):
    field = fields[shape]
    q = _probe_points(field, np.random.default_rng(len(shape)))
    levels = field._levels(q)
    assert set(np.unique(levels)) == {0, 1, 2, 3}  # the fine grid, both tiers, exact beyond
    for exact_cells in (True, False):
        got = field.signed_distance(q, far="coarse", exact_cells=exact_cells)
        np.testing.assert_array_equal(got, reference_tiered(field, q, exact_cells))
    # float32 and torch inputs go through the same conversion as before
    t = torch.from_numpy(q[:5000].astype(np.float32))
    np.testing.assert_array_equal(
        field.signed_distance(t, far="coarse").numpy(),
        reference_tiered(field, t.double().numpy(), True).astype(np.float32))


def test_levels_are_the_first_box_holding_each_point(fields):
    """Levels against a per-point loop over the boxes, with inclusive faces."""
    field = fields["cup"]
    q = _probe_points(field, np.random.default_rng(7), n=3000)
    boxes = field._boxes()
    ref = [next((b for b, (lo, hi) in enumerate(boxes) if np.all((p >= lo) & (p <= hi))),
                len(boxes)) for p in q]
    np.testing.assert_array_equal(field._levels(q), ref)


def test_chunks_do_not_change_values(fields, monkeypatch):
    field = fields["box"]
    q = _probe_points(field, np.random.default_rng(3), n=5000)
    whole = field.signed_distance(q, far="coarse")
    monkeypatch.setattr(D, "_CHUNK", 997)
    np.testing.assert_array_equal(field.signed_distance(q, far="coarse"), whole)


def _groups(field, rng, G=120, n=200):
    """G rigidly moved copies of one random point cloud (radius ~0.12 m), their centres from
    the object's middle to 1 m away, so that groups sit in every grid, across their faces
    and beyond the last; returns points (G, n, 3)."""
    cloud = rng.normal(size=(n, 3))
    cloud *= 0.12 * rng.random((n, 1)) ** (1 / 3) / np.linalg.norm(cloud, axis=1, keepdims=True)
    R = Rotation.random(G, random_state=rng.integers(1 << 31)).as_matrix()
    lo, hi = field.mesh.bounds
    d = rng.normal(size=(G, 3))
    d *= np.linspace(0.0, 1.0, G)[:, None] / np.linalg.norm(d, axis=1, keepdims=True)
    return np.einsum("gij,nj->gni", R, cloud) + ((lo + hi) / 2 + d)[:, None]


@pytest.mark.parametrize("shape", list(SHAPES))
def test_grouped_is_the_sequential_path_bit_for_bit(fields, shape, monkeypatch):
    field = fields[shape]
    rng = np.random.default_rng(11)
    p = _groups(field, rng)
    flat = p.reshape(-1, 3)
    tight = (p.min(axis=1), p.max(axis=1))  # boxes touching their extreme points
    widen = rng.uniform(0, 0.05, (2, len(p), 3))
    loose = (tight[0] - widen[0], tight[1] + widen[1])
    for exact_cells in (True, False):
        ref = reference_tiered(field, flat, exact_cells).reshape(p.shape[:2])
        for lo, hi in (tight, loose):
            got = field.signed_distance_grouped(p, lo, hi, exact_cells)
            np.testing.assert_array_equal(got, ref)
    # whole groups at one level, mixed ones, and groups beyond every grid all occur
    lo, hi = tight
    levels = field._group_levels(flat, p.shape[1], lo, hi).reshape(p.shape[:2])
    np.testing.assert_array_equal(levels.ravel(), field._levels(flat))
    pure = (levels == levels[:, :1]).all(axis=1)
    assert pure.any() and (~pure).any() and (levels == len(field._boxes())).all(axis=1).any()
    monkeypatch.setattr(D, "_CHUNK", 1000)  # several chunks of whole groups
    np.testing.assert_array_equal(field.signed_distance_grouped(p, lo, hi),
                                  reference_tiered(field, flat, True).reshape(p.shape[:2]))


def test_grouped_groups_on_grid_faces(fields):
    """Groups lying exactly on a grid box's face (their box's side equal to the face) count
    as inside it, as their points do; a group with one point a float step (or 0.5 mm)
    beyond the face straddles it, and that point goes to the next grid."""
    field = fields["sphere"]
    rng = np.random.default_rng(5)
    pts = []
    for blo, bhi in field._boxes():
        for k in range(3):
            for face, out in ((blo[k], -np.inf), (bhi[k], np.inf)):
                for beyond in (None, np.nextafter(face, out), face + np.sign(out) * 5e-4):
                    g = blo + rng.uniform(0, 1, (50, 3)) * (bhi - blo)
                    g[:, k] = face
                    if beyond is not None:
                        g[0, k] = beyond
                    pts.append(g)
    p = np.stack(pts)
    lo, hi = p.min(axis=1), p.max(axis=1)
    ref = reference_tiered(field, p.reshape(-1, 3), True).reshape(p.shape[:2])
    np.testing.assert_array_equal(field.signed_distance_grouped(p, lo, hi), ref)
    levels = field._group_levels(p.reshape(-1, 3), p.shape[1], lo, hi).reshape(p.shape[:2])
    assert (levels[:, 0] != levels[:, 1]).sum() >= 2 * 6 * (len(field._boxes()) - 1)


def test_grouped_shapes_and_empty(fields):
    field = fields["sphere"]
    with pytest.raises(InputError, match="signed_distance_grouped"):
        field.signed_distance_grouped(np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((4, 3)))
    with pytest.raises(InputError):
        field.signed_distance_grouped(np.zeros((2, 5, 3)), np.zeros((3, 3)), np.zeros((3, 3)))
    assert field.signed_distance_grouped(np.zeros((0, 5, 3)), np.zeros((0, 3)),
                                         np.zeros((0, 3))).shape == (0, 5)
    assert field.signed_distance(np.zeros((0, 3)), far="coarse").shape == (0,)


def test_read32_is_read(fields):
    """The tiled float32 transform gives _read's values, tails of every length included."""
    tier = fields["cup"]._far_tiers()[1]
    q = np.random.default_rng(2).uniform(-0.8, 0.8, (1000, 3))
    for m in (1, 63, 64, 65, 1000):
        got = D._read32(tier._vol, tier._scale_rows, tier._shift_rows, q[:m].astype(np.float32))
        np.testing.assert_array_equal(got.astype(np.float64),
                                      D._read(tier._vol, tier._scale, tier._shift, q[:m]))
