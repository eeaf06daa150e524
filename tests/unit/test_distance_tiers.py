"""The far="coarse" read path (compiled, geometry.gridread): each point's grid decided once and
read, bit for bit the sequential per-point torch path it replaced (kept here as the
reference); the moved-points form the sensors use."""

import manifold3d
import numpy as np
import pytest
import torch
import torch.nn.functional as F
import trimesh
from scipy.spatial.transform import Rotation

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


def _frames(rng, T, reach=1.0):
    """T random frames (rot (T, 3, 3), transl (T, 3)) whose origins sit 0 to ``reach`` m
    from the origin, and T random object poses (GRAB's row-vector rotations, translations)."""
    rot = Rotation.random(T, random_state=rng.integers(1 << 31)).as_matrix()
    d = rng.normal(size=(T, 3))
    d *= np.linspace(0.0, reach, T)[:, None] / np.linalg.norm(d, axis=1, keepdims=True)
    obj_rot = Rotation.random(T, random_state=rng.integers(1 << 31)).as_matrix()
    return rot, d, obj_rot, rng.normal(scale=0.02, size=(T, 3))


@pytest.mark.parametrize("shape", list(SHAPES))
def test_moved_points_are_the_two_step_path_bit_for_bit(fields, shape):
    """One compiled pass (move, then read) equals hand_points_in_object then the coarse
    read, at every level, for both exact_cells settings; NaN frames included."""
    from grip_bench.sensors import hand_points_in_object

    field = fields[shape]
    rng = np.random.default_rng(13)
    local = rng.normal(scale=0.08, size=(300, 3))
    rot, transl, obj_rot, obj_transl = _frames(rng, 60)
    transl[7] = np.nan  # a frame without a wrist
    q = hand_points_in_object(local, rot, transl, obj_rot, obj_transl)
    assert set(np.unique(field._levels(q.reshape(-1, 3)))) == {0, 1, 2, 3}
    for exact_cells in (True, False):
        ref = reference_tiered(field, q.reshape(-1, 3), exact_cells).reshape(60, 300)
        got = field.moved_signed_distance(local, rot, transl, obj_rot, obj_transl, exact_cells)
        np.testing.assert_array_equal(got, ref)
    assert field.moved_signed_distance(local[:0], rot, transl, obj_rot, obj_transl).shape == (60, 0)
    assert field.signed_distance(np.zeros((0, 3)), far="coarse").shape == (0,)


def test_compiled_read_is_grid_sample_bit_for_bit():
    """gridread's trilinear and nearest reads against torch's grid_sample (3-D, zero padding,
    align_corners) on random volumes, at points inside, on the border, outside (some
    corners missing) and NaN."""
    from grip_bench.geometry import gridread as G

    rng = np.random.default_rng(8)
    for dims in ((5, 7, 9), (2, 2, 2), (33, 17, 40)):
        vol = rng.normal(size=dims).astype(np.float32)
        u = rng.uniform(-1.3, 1.3, (20000, 3)).astype(np.float32)
        u[:300] = np.round(u[:300] * 4) / 4  # on nodes and cell faces
        u[300:310, 1] = np.nan
        t = torch.from_numpy(vol)[None, None]
        g = torch.from_numpy(u).view(1, 1, 1, -1, 3)
        ref = F.grid_sample(t, g, align_corners=True).view(-1).numpy()
        near = F.grid_sample(t, g, mode="nearest", align_corners=True).view(-1).numpy()
        got, got_near = _compiled_reads(G, vol.reshape(-1), np.array(dims), u)
        np.testing.assert_array_equal(got, ref)
        np.testing.assert_array_equal(got_near, near)


def _compiled_reads(G, flat, dims, u):
    from numba import njit

    @njit
    def both(flat, D, H, W, u, a, b):
        for n in range(u.shape[0]):
            a[n] = G._trilinear(flat, D, H, W, u[n, 0], u[n, 1], u[n, 2])
            b[n] = G._nearest(flat, D, H, W, u[n, 0], u[n, 1], u[n, 2])

    a, b = np.empty(len(u), np.float32), np.empty(len(u), np.float32)
    both(flat, *[int(x) for x in dims], u, a, b)
    return a, b
