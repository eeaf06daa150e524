"""Object mesh loading, repair, rejection messages and ObjectAsset."""

import numpy as np
import pytest
import trimesh

from grip_bench.core import constants
from grip_bench.core.errors import InputError
from grip_bench.geometry import meshes
from grip_bench.geometry.meshes import ObjectAsset, from_manifold, load_object_mesh, to_manifold


def _sphere(radius=0.05, subdivisions=3):
    return trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)


def _write(mesh, path):
    mesh.export(path)
    return path


# --- good files ----------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".glb"])
def test_load_formats_round_trip(tmp_path, suffix):
    ref = _sphere()
    mesh = load_object_mesh(_write(ref, tmp_path / f"ball{suffix}"))
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.vertices.dtype == np.float64
    assert mesh.volume == pytest.approx(ref.volume, rel=1e-6)
    assert mesh.metadata["source"].endswith(f"ball{suffix}")
    assert mesh.metadata["n_components"] == 1


def test_scene_is_flattened_and_components_counted(tmp_path):
    a = trimesh.creation.box((0.04, 0.04, 0.04))
    b = trimesh.creation.box((0.02, 0.02, 0.02))
    scene = trimesh.Scene()
    scene.add_geometry(a, transform=trimesh.transformations.translation_matrix([0.05, 0, 0]))
    scene.add_geometry(b, transform=trimesh.transformations.translation_matrix([-0.05, 0, 0]))
    mesh = load_object_mesh(_write(scene, tmp_path / "pair.glb"))
    assert mesh.metadata["n_components"] == 2
    assert mesh.volume == pytest.approx(0.04**3 + 0.02**3, rel=1e-6)  # glb stores float32
    assert mesh.bounds[1][0] == pytest.approx(0.07)  # scene transform applied


def test_overlapping_components_are_united(tmp_path):
    a = trimesh.creation.box((0.1, 0.1, 0.1))
    b = a.copy()
    b.apply_translation([0.05, 0, 0])
    mesh = load_object_mesh(_write(trimesh.util.concatenate([a, b]), tmp_path / "two.ply"))
    assert mesh.volume == pytest.approx(0.15 * 0.1 * 0.1, rel=1e-6)  # ply stores float32
    assert mesh.metadata["n_components"] == 1
    assert any("united" in r for r in mesh.metadata["repairs"])


def test_inverted_winding_and_unmerged_vertices_are_repaired(tmp_path):
    ref = _sphere()
    soup = trimesh.Trimesh(
        ref.vertices[ref.faces].reshape(-1, 3),
        np.arange(3 * len(ref.faces)).reshape(-1, 3)[:, ::-1],
        process=False,
    )
    assert soup.volume < 0
    mesh = load_object_mesh(_write(soup, tmp_path / "soup.obj"))
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(ref.volume, rel=1e-6)
    assert len(mesh.vertices) == len(ref.vertices)


def test_small_hole_is_closed(tmp_path):
    ref = _sphere(subdivisions=4)
    holed = trimesh.Trimesh(ref.vertices, ref.faces[3:], process=False)
    mesh = load_object_mesh(_write(holed, tmp_path / "holed.ply"))
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(ref.volume, rel=1e-3)
    assert any("hole" in r for r in mesh.metadata["repairs"])


def test_duplicate_and_degenerate_faces_dropped(tmp_path):
    ref = trimesh.creation.box((0.05, 0.05, 0.05))
    faces = np.vstack([ref.faces, ref.faces[:2], [[0, 0, 1]]])
    mesh = load_object_mesh(
        _write(trimesh.Trimesh(ref.vertices, faces, process=False), tmp_path / "d.obj")
    )
    assert len(mesh.faces) == 12 and mesh.volume == pytest.approx(0.05**3)


def test_scale_argument_fixes_millimetres(tmp_path):
    path = _write(_sphere(radius=50.0), tmp_path / "mm.stl")
    mesh = load_object_mesh(path, scale=0.001)
    assert np.ptp(mesh.vertices, axis=0).max() == pytest.approx(0.1, rel=1e-3)


def test_manifold_round_trip():
    ref = trimesh.creation.torus(0.05, 0.015)
    m = to_manifold(ref)
    assert m.volume() == pytest.approx(ref.volume, rel=1e-9)
    back = from_manifold(m)
    assert back.is_watertight and back.volume == pytest.approx(ref.volume, rel=1e-9)


# --- bad files: clear errors naming the file and the problem ------------------------


def _error(path, **kw) -> InputError:
    with pytest.raises(InputError) as info:
        load_object_mesh(path, **kw)
    assert str(path) in str(info.value)  # the CLI prints "error: <where>: <what>"
    assert info.value.where == str(path)
    return info.value


def test_millimetre_scale_is_named(tmp_path):
    err = _error(_write(_sphere(radius=50.0), tmp_path / "mm.obj"))
    assert "millimetres" in err.what and "--mesh-scale 0.001" in err.what


def test_centimetre_scale_is_named(tmp_path):
    err = _error(_write(_sphere(radius=10.0), tmp_path / "cm.obj"))
    assert "centimetres" in err.what and "--mesh-scale 0.01" in err.what


def test_too_small_is_named(tmp_path):
    err = _error(_write(_sphere(radius=1e-4), tmp_path / "tiny.obj"))
    assert "under" in err.what and "--mesh-scale 1000" in err.what


def test_empty_file(tmp_path):
    path = tmp_path / "empty.obj"
    path.write_bytes(b"")
    assert "empty" in _error(path).what


def test_missing_file(tmp_path):
    assert "not found" in _error(tmp_path / "nope.ply").what


def test_unsupported_suffix(tmp_path):
    path = tmp_path / "x.fbx"
    path.write_bytes(b"abc")
    assert "unsupported" in _error(path).what


@pytest.mark.parametrize("suffix", [".ply", ".stl", ".obj", ".glb"])
def test_garbage_bytes(tmp_path, suffix):
    path = tmp_path / f"garbage{suffix}"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    _error(path)


def test_truncated_ply(tmp_path):
    data = _sphere().export(file_type="ply")
    path = tmp_path / "cut.ply"
    path.write_bytes(data[: len(data) // 2])
    _error(path)


def test_hole_too_big(tmp_path):
    ref = _sphere(subdivisions=3)
    cap = ref.triangles_center[:, 2] > 0.6 * 0.05
    mesh = trimesh.Trimesh(ref.vertices, ref.faces[~cap], process=False)
    err = _error(_write(mesh, tmp_path / "bowl.ply"))
    assert "open" in err.what and "hole" in err.what


def test_flat_mesh_has_zero_volume(tmp_path):
    path = tmp_path / "flat.obj"
    path.write_text("v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nf 1 2 3\nf 1 3 4\n")
    err = _error(path)
    assert "flat" in err.what and "volume" in err.what


def test_non_manifold_edge(tmp_path):
    # a closed tetrahedron plus a fin hanging off one of its edges
    verts = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1], [0.1, 0.1, 0.1]], float)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3], [0, 1, 4]])
    err = _error(_write(trimesh.Trimesh(verts, faces, process=False), tmp_path / "fin.ply"))
    assert "non-manifold" in err.what


# --- ObjectAsset ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ball_asset():
    return ObjectAsset.from_mesh(_sphere(radius=0.05, subdivisions=4), name="ball", density=800.0)


def test_asset_samples_lie_on_surface_with_outward_normals(ball_asset):
    a = ball_asset
    assert (
        a.samples.shape == (constants.N_SURFACE_SAMPLES, 3) and a.normals.shape == a.samples.shape
    )
    r = np.linalg.norm(a.samples, axis=1)
    assert np.all(np.abs(r - 0.05) < 1e-3)
    cos = np.einsum("ij,ij->i", a.normals, a.samples / r[:, None])
    assert cos.min() > 0.99


def test_asset_samples_are_even(ball_asset):
    # farthest-point thinning: nearest-neighbour gaps are much more uniform than random sampling
    from scipy.spatial import cKDTree

    gaps = cKDTree(ball_asset.samples).query(ball_asset.samples, k=2)[0][:, 1]
    rand = trimesh.sample.sample_surface(ball_asset.mesh, len(gaps), seed=0)[0]
    rand_gaps = cKDTree(rand).query(rand, k=2)[0][:, 1]
    assert gaps.min() > 3 * rand_gaps.min()
    assert gaps.std() / gaps.mean() < rand_gaps.std() / rand_gaps.mean()


def test_asset_mass_and_bounding_sphere(ball_asset):
    a = ball_asset
    assert a.volume == pytest.approx(a.mesh.volume)
    assert a.mass == pytest.approx(a.volume * 800.0)
    assert a.radius == pytest.approx(0.05, rel=1e-6)
    np.testing.assert_allclose(a.center, 0.0, atol=1e-6)


def test_asset_box_hand_worked():
    # 10 x 6 x 4 cm box at 500 kg/m^3: 240 cm^3 -> 0.12 kg; bounding sphere = half diagonal
    box = trimesh.creation.box((0.10, 0.06, 0.04))
    box.apply_translation([0.01, 0.02, 0.03])
    a = ObjectAsset.from_mesh(box)
    assert a.mass == pytest.approx(0.12)
    assert a.density == constants.DEFAULT_DENSITY
    assert a.radius == pytest.approx(0.5 * np.sqrt(0.01 + 0.0036 + 0.0016), rel=1e-6)
    np.testing.assert_allclose(a.center, [0.01, 0.02, 0.03], atol=1e-6)


def test_asset_sampling_is_deterministic(tmp_path):
    path = _write(trimesh.creation.box((0.05, 0.05, 0.05)), tmp_path / "cube.stl")
    a, b = ObjectAsset.load(path), ObjectAsset.load(path)
    c = ObjectAsset.load(path, seed=1, name="other")
    assert a.name == "cube" and c.name == "other"
    np.testing.assert_array_equal(a.samples, b.samples)
    assert not np.array_equal(a.samples, c.samples)


def test_asset_rejects_open_mesh_and_bad_density():
    ref = _sphere()
    with pytest.raises(InputError, match="watertight"):
        ObjectAsset.from_mesh(trimesh.Trimesh(ref.vertices, ref.faces[1:], process=False))
    with pytest.raises(InputError, match="density"):
        ObjectAsset.from_mesh(ref, density=0.0)


def test_public_names_exported():
    import grip_bench.geometry as g

    assert g.load_object_mesh is meshes.load_object_mesh and g.ObjectAsset is ObjectAsset
    assert g.to_manifold is to_manifold and g.from_manifold is from_manifold
