"""DistanceField: exact path vs analytic and brute force, grid vs exact, signs, types."""

import igl
import manifold3d
import numpy as np
import pytest
import torch
import trimesh

from grip_bench.core import constants
from grip_bench.geometry.distance import DistanceField
from grip_bench.geometry.meshes import from_manifold

BAND = constants.SDF_EXACT_BAND  # 0.5 mm


def _mug(wall=0.004):
    """Hollow cylinder with a bottom and a ring handle (manifold3d CSG), in metres."""
    cyl = manifold3d.Manifold.cylinder
    body = cyl(0.10, 0.04, 0.04, 64) - cyl(0.10, 0.04 - wall, 0.04 - wall, 64).translate(
        (0, 0, wall)
    )
    ring = cyl(0.008, 0.03, 0.03, 32) - cyl(0.02, 0.022, 0.022, 32).translate((0, 0, -0.006))
    handle = ring.rotate((90, 0, 0)).translate((0.05, 0.004, 0.05))
    return from_manifold(body + handle)


SHAPES = {
    "sphere": lambda: trimesh.creation.icosphere(subdivisions=3, radius=0.04),
    "box": lambda: trimesh.creation.box((0.10, 0.06, 0.04)),
    "torus": lambda: trimesh.creation.torus(0.045, 0.015, major_sections=48, minor_sections=24),
    "mug": _mug,
    "thin_mug": lambda: _mug(wall=0.001),
}


@pytest.fixture(scope="module")
def fields():
    return {name: DistanceField(make()) for name, make in SHAPES.items()}


def _winding_sdf(mesh, p):
    """Reference: libigl with generalized winding number sign (independent of our pseudonormals)."""
    st = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_WINDING_NUMBER
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    return igl.signed_distance(p, v, f, sign_type=st)[0]


def _near_surface_points(mesh, n, rng, depth=0.02):
    """Points within ``depth`` of the surface: surface samples pushed along random directions."""
    s, _ = trimesh.sample.sample_surface(mesh, n, seed=rng)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return s + d * rng.uniform(0, depth, (n, 1))


# --- exact path -------------------------------------------------------------------------


def test_box_hand_worked_values(fields):
    df = fields["box"]  # half sizes 0.05, 0.03, 0.02
    p = np.array([[0.08, 0, 0], [0.08, 0.06, 0], [0.01, 0, 0], [0, 0, 0], [0.05, 0.03, 0.02]])
    expected = [0.03, np.hypot(0.03, 0.03), -0.02, -0.02, 0.0]
    np.testing.assert_allclose(df.exact_signed_distance(p), expected, atol=1e-12)
    np.testing.assert_allclose(df.signed_distance(p), expected, atol=1e-5)


def test_box_analytic_sdf(fields):
    df = fields["box"]
    half = np.array([0.05, 0.03, 0.02])
    p = np.random.default_rng(1).uniform(-0.1, 0.1, (20000, 3))
    q = np.abs(p) - half
    ref = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)
    np.testing.assert_allclose(df.exact_signed_distance(p), ref, atol=1e-12)
    near = np.abs(ref) < 0.02
    assert np.abs(df.signed_distance(p) - ref)[near].max() < BAND


def test_sphere_analytic_sdf(fields):
    df = fields["sphere"]
    p = np.random.default_rng(2).uniform(-0.08, 0.08, (20000, 3))
    ref = np.linalg.norm(p, axis=1) - 0.04
    # the icosphere is a polyhedron inscribed in the sphere: faces sit up to ~0.4 mm inside
    np.testing.assert_allclose(df.exact_signed_distance(p), ref, atol=6e-4)
    clear = np.abs(ref) > 6e-4
    assert np.all((df.signed_distance(p[clear]) < 0) == (ref[clear] < 0))


def test_closest_points_match_brute_force():
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    df = DistanceField(mesh, spacing=0.004)
    p = np.random.default_rng(3).uniform(-0.09, 0.09, (300, 3))
    tris = mesh.triangles
    # every point against every triangle
    cand = trimesh.triangles.closest_point(
        np.repeat(tris[None], len(p), 0).reshape(-1, 3, 3), np.repeat(p, len(tris), 0)
    ).reshape(len(p), len(tris), 3)
    dist = np.linalg.norm(cand - p[:, None], axis=2)
    best = dist.argmin(1)
    closest, sdist, faces = df.closest_points(p)
    np.testing.assert_allclose(np.abs(sdist), dist.min(1), atol=1e-12)
    np.testing.assert_allclose(closest, cand[np.arange(len(p)), best], atol=1e-9)
    np.testing.assert_allclose(dist[np.arange(len(p)), faces], dist.min(1), atol=1e-12)
    inside = mesh.contains(p)
    assert np.all((sdist < 0) == inside)


@pytest.mark.parametrize("name", list(SHAPES))
def test_exact_sign_matches_winding_number(fields, name):
    df = fields[name]
    lo, hi = df.mesh.bounds
    p = np.random.default_rng(4).uniform(lo - 0.02, hi + 0.02, (20000, 3))
    ref = _winding_sdf(df.mesh, p)
    np.testing.assert_allclose(df.exact_signed_distance(p), ref, atol=1e-12)


# --- grid path ----------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SHAPES))
def test_grid_agrees_with_exact_near_surface(fields, name):
    df = fields[name]
    rng = np.random.default_rng(5)
    p = _near_surface_points(df.mesh, 20000, rng)
    lo, hi = df.mesh.bounds
    p = np.vstack([p, rng.uniform(lo - 0.01, hi + 0.01, (20000, 3))])
    ref = _winding_sdf(df.mesh, p)
    near = np.abs(ref) < 0.02
    err = np.abs(df.signed_distance(p) - ref)
    assert err[near].max() < BAND
    assert err.max() < 5e-3  # beyond 2 cm the grid holds coarse values
    clear = np.abs(ref) > BAND
    assert np.all(np.sign(df.signed_distance(p[clear])) == np.sign(ref[clear]))


def test_known_inside_outside_points(fields):
    cases = {
        "torus": ([[0.045, 0, 0], [0, 0.045, 0]], [[0, 0, 0], [0, 0, 0.03], [0.1, 0, 0]]),
        "mug": (
            [[0.038, 0, 0.05], [0, 0, 0.002], [0.05, 0.004, 0.076]],
            [[0, 0, 0.05], [0.05, 0, 0.05]],
        ),
        "thin_mug": ([[0.0395, 0, 0.05], [0, 0, 0.0005]], [[0, 0, 0.05], [0.0385, 0, 0.05]]),
    }
    for name, (inside, outside) in cases.items():
        df = fields[name]
        assert np.all(df.signed_distance(np.array(inside)) < 0), name
        assert np.all(df.signed_distance(np.array(outside)) > 0), name


def test_lazy_export():
    import grip_bench.geometry as g

    assert g.DistanceField is DistanceField


def test_thin_walls_are_sent_to_the_exact_path(fields):
    # a 1 mm wall is thinner than a 2 mm cell: interpolation there cannot be trusted
    assert fields["thin_mug"].unreliable_fraction > fields["mug"].unreliable_fraction
    assert fields["sphere"].unreliable_fraction < 0.01


def test_points_outside_grid_use_exact(fields):
    df = fields["sphere"]
    p = np.array([[0.5, 0, 0], [0, -1.0, 0.2]])
    np.testing.assert_allclose(df.signed_distance(p), df.exact_signed_distance(p), atol=0)


def test_gradient_is_outward_normal(fields):
    df = fields["sphere"]
    rng = np.random.default_rng(6)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p = d * rng.uniform(0.03, 0.3, (2000, 1))  # inside the grid and far outside it
    g = df.gradient(p)
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-6)
    assert np.einsum("ij,ij->i", g, d).min() > 0.97
    # finite differences of the exact distance agree
    eps = 1e-5
    fd = np.stack(
        [
            (df.exact_signed_distance(p + eps * e) - df.exact_signed_distance(p - eps * e))
            / (2 * eps)
            for e in np.eye(3)
        ],
        1,
    )
    assert np.einsum("ij,ij->i", g, fd).min() > 0.97


# --- types and shapes ----------------------------------------------------------------------


def test_types_and_shapes_follow_input(fields):
    df = fields["box"]
    p = np.random.default_rng(7).uniform(-0.08, 0.08, (2, 5, 3))
    for arr in (p, p.astype(np.float32), torch.from_numpy(p), torch.from_numpy(p).float()):
        d = df.signed_distance(arr)
        assert type(d) is type(arr) and d.dtype == arr.dtype and tuple(d.shape) == (2, 5)
        assert tuple(df.gradient(arr).shape) == (2, 5, 3)
        assert tuple(df.exact_signed_distance(arr).shape) == (2, 5)
        c, dist, f = df.closest_points(arr)
        assert (
            tuple(c.shape) == (2, 5, 3) and tuple(dist.shape) == (2, 5) and tuple(f.shape) == (2, 5)
        )
        assert type(c) is type(arr) and type(f) is type(arr)
    np.testing.assert_allclose(
        df.signed_distance(torch.from_numpy(p)).numpy(), df.signed_distance(p)
    )
    assert df.signed_distance(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match="points"):
        df.signed_distance(np.zeros((4, 2)))


def test_far_bound_is_a_lower_bound_outside_and_exact_inside(fields):
    field = fields["mug"]
    rng = np.random.default_rng(3)
    far = rng.uniform(-0.4, 0.4, (2000, 3))
    far = far[field._outside_grid(far)]  # inside the grid both modes read the grid
    assert len(far) > 500
    near = field.mesh.sample(300, seed=4) + rng.normal(0, 0.005, (300, 3))
    exact_far = field.exact_signed_distance(far)
    bound_far = field.signed_distance(far, far="bound")
    assert np.all(bound_far <= exact_far + 1e-9)  # safe for sphere tracing
    assert np.all(bound_far >= 0.0)  # far points are never reported inside
    np.testing.assert_array_equal(
        field.signed_distance(near, far="bound"), field.signed_distance(near)
    )
    with pytest.raises(ValueError, match="far"):
        field.signed_distance(near, far="nope")


@pytest.mark.parametrize("shape", ["box", "sphere"])
def test_far_tiers_meet_the_trilinear_bound(fields, shape):
    """Outside a convex mesh the SDF's Hessian is at most 1/d in two directions, so trilinear
    interpolation over cells of spacing h errs by at most h^2 / (4 d'), d' the distance of the
    cell's nearest corner; each point is read from the tier that holds it, exact beyond."""
    field = fields[shape]
    rng = np.random.default_rng(6)
    u = rng.normal(size=(6000, 3))
    pts = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(0.03, 1.2, (6000, 1))
    pts = pts[field._outside_grid(pts)]
    got = field.signed_distance(pts, far="coarse")
    exact = field.exact_signed_distance(pts)
    bound = np.full(len(pts), 0.0)
    rest = np.ones(len(pts), bool)
    for (h, _), tier in zip(constants.SDF_FAR_TIERS, field._far_tiers(), strict=True):
        held = rest & np.all((pts >= tier.origin) & (pts <= tier._hi), axis=1)
        bound[held] = h**2 / (4 * np.maximum(exact[held] - h * np.sqrt(3), 1e-3))
        rest &= ~held
    assert rest.any() and (~rest).sum() > 1000  # every tier and the exact remainder are used
    np.testing.assert_array_equal(got[rest], exact[rest])
    assert np.all(np.abs(got - exact) <= bound + 2e-6)  # + float32 grid rounding


def test_far_coarse_is_close_to_exact_beyond_the_grid(fields):
    field = fields["mug"]
    rng = np.random.default_rng(5)
    pts = rng.uniform(-0.3, 0.3, (3000, 3))
    pts = pts[field._outside_grid(pts)]
    coarse = field.signed_distance(pts, far="coarse")
    exact = field.exact_signed_distance(pts)
    # trilinear over 1 cm cells of an SDF more than 3 cm from the surface: mm-level at worst
    assert np.abs(coarse - exact).max() < 3e-3
    assert np.all(coarse > 0)
