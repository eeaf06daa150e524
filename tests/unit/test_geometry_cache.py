"""On-disk geometry cache: location, keys, atomic writes, corrupt entries, and results that are
bit-identical whether they come from the cache or are built (distance grids, convex pieces)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from grip_bench.core import constants
from grip_bench.geometry import cache as GC
from grip_bench.geometry.distance import DistanceField


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    d = tmp_path / "geom-cache"
    monkeypatch.setenv(GC.ENV_VAR, str(d))
    monkeypatch.setattr(GC, "_warned", set())
    return d


def _entries(root: Path, kind: str | None = None) -> list[Path]:
    base = root / kind if kind else root
    return sorted(base.rglob("*.npz")) if base.exists() else []


def _mesh():
    return trimesh.creation.torus(0.045, 0.015, major_sections=32, minor_sections=16)


# --- location and keys -------------------------------------------------------------------
def test_cache_root_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(GC.ENV_VAR, str(tmp_path / "a"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert GC.cache_root() == tmp_path / "a"
    monkeypatch.delenv(GC.ENV_VAR)
    assert GC.cache_root() == tmp_path / "xdg" / "grip-bench"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert GC.cache_root() == tmp_path / "home" / ".cache" / "grip-bench"
    for off in ("off", "0", "none", "FALSE"):
        monkeypatch.setenv(GC.ENV_VAR, off)
        assert GC.cache_root() is None


def test_keys_depend_on_mesh_bytes_params_and_kind():
    v, f = np.random.default_rng(0).normal(size=(10, 3)), np.arange(12).reshape(4, 3) % 10
    k = GC.mesh_key("sdf_grid", v, f, {"spacing": 0.002})
    assert k == GC.mesh_key("sdf_grid", v.tolist(), f.astype(np.int32), {"spacing": 0.002})
    w = v.copy()
    w[3, 1] = np.nextafter(w[3, 1], np.inf)
    others = [GC.mesh_key("sdf_grid", w, f, {"spacing": 0.002}),
              GC.mesh_key("sdf_grid", v, f[:, ::-1], {"spacing": 0.002}),
              GC.mesh_key("sdf_grid", v, f, {"spacing": 0.0021}),
              GC.mesh_key("sdf_far", v, f, {"spacing": 0.002})]
    assert len({k, *others}) == 5


# --- storage -------------------------------------------------------------------------------
def test_roundtrip_is_atomic_and_keeps_dtypes(cache_dir):
    arrays = {
        "a": np.arange(5, dtype=np.float32),
        "b": np.ones((2, 3), bool),
        "c": np.array(3, np.int64),
    }
    calls = []

    def build():
        calls.append(1)
        return arrays

    first = GC.cached_arrays("demo", "ab" * 32, build)
    again = GC.cached_arrays("demo", "ab" * 32, build)
    assert len(calls) == 1
    for k, a in arrays.items():
        assert again[k].dtype == a.dtype and np.array_equal(again[k], a) and first[k] is a
    files = list(cache_dir.rglob("*"))
    assert [p.name for p in files if p.is_file()] == ["ab" * 32 + ".npz"]  # no temp file left


def test_corrupt_entry_is_rebuilt_with_one_warning(cache_dir):
    key = "cd" * 32
    GC.save_arrays("demo", key, {"x": np.arange(3.0)})
    path = _entries(cache_dir, "demo")[0]
    path.write_bytes(path.read_bytes()[:40])  # truncated
    with pytest.warns(RuntimeWarning, match="unreadable"):
        out = GC.cached_arrays("demo", key, lambda: {"x": np.arange(3.0) + 1})
    np.testing.assert_array_equal(out["x"], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(GC.load_arrays("demo", key)["x"], [1.0, 2.0, 3.0])  # rewritten
    path.write_bytes(b"not a zip file")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the second corrupt entry does not warn again
        assert GC.load_arrays("demo", key) is None
    # an entry without the arrays the reader needs, or failing its check, counts as corrupt
    GC.save_arrays("demo", key, {"y": np.zeros(1)})
    assert GC.load_arrays("demo", key, names=("x",)) is None
    assert GC.load_arrays("demo", key, validate=lambda a: a["y"].shape == (2,)) is None
    assert GC.load_arrays("demo", key, validate=lambda a: a["y"].shape == (1,)) is not None


def test_pickled_entries_are_refused(cache_dir):
    key = "ef" * 32
    GC.save_arrays("demo", key, {"x": np.zeros(1)})
    path = _entries(cache_dir, "demo")[0]
    np.savez(path, x=np.array([{"evil": 1}], dtype=object))
    with pytest.warns(RuntimeWarning):
        assert GC.load_arrays("demo", key) is None


def test_disabled_cache_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv(GC.ENV_VAR, "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path))
    DistanceField(trimesh.creation.icosphere(2, radius=0.03))
    assert _entries(tmp_path) == []


def test_unwritable_cache_only_warns(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv(GC.ENV_VAR, str(blocker / "sub"))  # a folder below a file
    monkeypatch.setattr(GC, "_warned", set())
    with pytest.warns(RuntimeWarning, match="cannot write"):
        out = GC.cached_arrays("demo", "01" * 32, lambda: {"x": np.ones(2)})
    np.testing.assert_array_equal(out["x"], [1.0, 1.0])


# --- cached results equal built ones ---------------------------------------------------------
_FIELD_STATE = ("_vol", "_gvol", "_trusted", "_scale", "_shift", "_cell_scale")


def _same_field(a: DistanceField, b: DistanceField) -> None:
    assert a.shape == b.shape and np.array_equal(a.origin, b.origin)
    np.testing.assert_array_equal(a._unreliable, b._unreliable)
    for name in _FIELD_STATE:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and bool((x == y).all()), name


def test_distance_field_is_identical_cached_or_built(cache_dir, monkeypatch):
    mesh = _mesh()
    monkeypatch.setenv(GC.ENV_VAR, "off")
    built = DistanceField(mesh)
    monkeypatch.setenv(GC.ENV_VAR, str(cache_dir))
    cold = DistanceField(mesh)  # builds and writes
    assert len(_entries(cache_dir, "sdf_grid")) == 1
    warm = DistanceField(mesh)  # reads
    _same_field(built, cold)
    _same_field(built, warm)
    rng = np.random.default_rng(0)
    p = rng.uniform(-0.09, 0.09, (4000, 3))
    for far in ("exact", "bound", "coarse"):
        np.testing.assert_array_equal(
            built.signed_distance(p, far=far), warm.signed_distance(p, far=far)
        )
    np.testing.assert_array_equal(built.gradient(p), warm.gradient(p))
    n_tiers = len(built._far_tiers())
    assert (
        len(_entries(cache_dir, "sdf_far")) == n_tiers
    )  # the lazily built far grids are cached too
    for a, b in zip(built._far_tiers(), DistanceField(mesh)._far_tiers(), strict=True):
        np.testing.assert_array_equal(a._vol, b._vol)


def test_gradients_are_read_only_when_needed(cache_dir):
    mesh = trimesh.creation.icosphere(2, radius=0.03)
    built = DistanceField(mesh)
    assert _entries(cache_dir, "sdf_grad") == []  # written once a gradient is asked for
    p = np.random.default_rng(2).uniform(-0.05, 0.05, (3000, 3))
    built.gradient(p[:1])
    assert len(_entries(cache_dir, "sdf_grad")) == 1
    loaded = DistanceField(mesh)
    assert loaded._gvol_data is None  # distances never touch the gradient volume
    np.testing.assert_array_equal(loaded.signed_distance(p), built.signed_distance(p))
    assert loaded._gvol_data is None
    np.testing.assert_array_equal(loaded.gradient(p), built.gradient(p))
    for path in _entries(cache_dir, "sdf_grad"):
        path.unlink()  # a lost gradient entry is rebuilt on demand
    again = DistanceField(mesh)
    np.testing.assert_array_equal(again.gradient(p), built.gradient(p))
    assert len(_entries(cache_dir, "sdf_grad")) == 1


def test_distance_field_keys_follow_parameters(cache_dir, monkeypatch):
    mesh = trimesh.creation.icosphere(2, radius=0.03)
    DistanceField(mesh)
    DistanceField(mesh, spacing=0.003)
    monkeypatch.setattr(constants, "SDF_KINK_TOL", 0.5e-3)
    DistanceField(mesh)
    assert len(_entries(cache_dir, "sdf_grid")) == 3


@pytest.mark.parametrize("damage", ["bytes", "shapes"])
def test_corrupt_distance_grid_is_rebuilt_identically(cache_dir, damage):
    mesh = trimesh.creation.icosphere(2, radius=0.03)
    first = DistanceField(mesh)
    for path in _entries(cache_dir, "sdf_grid"):
        if damage == "bytes":
            path.write_bytes(b"\0" * 100)
        else:  # a readable entry whose arrays do not fit together
            with np.load(path) as z:
                arrays = {k: z[k] for k in z.files}
            arrays["vol"] = arrays["vol"][:-1]
            np.savez(path, **arrays)
    with pytest.warns(RuntimeWarning, match="unreadable"):
        again = DistanceField(mesh)
    _same_field(first, again)
    _same_field(first, DistanceField(mesh))  # the rebuilt entry reads back


def test_convex_pieces_are_identical_cached_or_built(cache_dir, monkeypatch):
    from grip_bench.metrics import physics

    torus = _mesh()
    monkeypatch.setattr(physics, "_PIECE_CACHE", {})
    monkeypatch.setenv(GC.ENV_VAR, "off")
    built = physics.convex_decomposition(torus)
    monkeypatch.setenv(GC.ENV_VAR, str(cache_dir))
    physics._PIECE_CACHE.clear()
    cold = physics.convex_decomposition(torus)
    assert len(_entries(cache_dir, "convex_pieces")) == 1
    physics._PIECE_CACHE.clear()
    calls = []
    monkeypatch.setattr(physics, "_run_coacd", lambda *a: calls.append(a) or [])
    warm = physics.convex_decomposition(torus)
    assert calls == []  # read from disk: CoACD did not run
    assert len(built) == len(cold) == len(warm) > 3
    for a, b, c in zip(built, cold, warm, strict=True):
        assert a.dtype == b.dtype == c.dtype == np.float64
        assert a.tobytes() == b.tobytes() == c.tobytes()


# --- frame changes used by the sensors and the evaluation ---------------------------------------
def test_world_to_object_and_to_world_match_einsum():
    from scipy.spatial.transform import Rotation

    from grip_bench.core.frames import rotate_rows as _rotate_rows
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.sensors import to_world

    rng = np.random.default_rng(1)
    for T, N in ((37, 500), (1, 1), (4, 0)):
        R = Rotation.random(T, random_state=2).as_matrix()
        d = rng.normal(size=(T, N, 3))
        local, t = rng.normal(size=(N, 3)), rng.normal(size=(T, 3))
        for x in (d, d.astype(np.float32)):
            ref = np.einsum("tnj,tij->tni", x, R)
            out = _rotate_rows(x, R)
            assert out.dtype == ref.dtype and out.shape == ref.shape
            np.testing.assert_allclose(out, ref, rtol=0, atol=1e-15)
        ref = np.einsum("tij,nj->tni", R, local) + t[:, None]
        out = to_world(local, R, t)
        assert out.dtype == ref.dtype and out.shape == ref.shape
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-15)
        seq = _FakeSeq(Rotation.from_matrix(R).as_rotvec(), t)
        for x in (d, d.astype(np.float32)):
            ref = np.einsum("tnj,tij->tni", x - t[:, None], seq.object_rotations())
            out = ObjectLibrary("unused").world_to_object(seq, x)
            assert out.dtype == ref.dtype and out.shape == ref.shape
            np.testing.assert_allclose(out, ref, rtol=0, atol=1e-15)


class _FakeSeq:
    def __init__(self, rotvec, transl):
        self.object = {"global_orient": rotvec, "transl": transl}

    def object_rotations(self):
        from scipy.spatial.transform import Rotation

        return Rotation.from_rotvec(self.object["global_orient"]).as_matrix()


def test_outside_and_box_distance_match_the_row_formulas():
    field = DistanceField(trimesh.creation.box((0.05, 0.03, 0.02)))
    rng = np.random.default_rng(3)
    hi = field.origin + field.spacing * (np.array(field.shape) - 1)
    q = rng.normal(size=(20000, 3)) * 0.1
    q[:100] = field.origin  # on the grid's faces
    q[100:200] = hi
    q[200:300, 1] = hi[1]
    np.testing.assert_array_equal(
        field._outside_grid(q), ((q < field.origin) | (q > hi)).any(axis=1)
    )
    lo, up = field.mesh.bounds
    ref = np.linalg.norm(np.maximum(np.maximum(lo - q, q - up), 0.0), axis=1)
    np.testing.assert_array_equal(field._box_distance(q), ref)
    assert field._box_distance(q[:0]).shape == (0,)


def test_exact_values_skip_only_signs_that_are_known():
    """``_exact_values`` (the sign test skipped outside the bounding box) equals ``_exact``."""
    import manifold3d

    from grip_bench.geometry.meshes import from_manifold

    cyl = manifold3d.Manifold.cylinder
    mug = from_manifold(
        cyl(0.10, 0.04, 0.04, 64) - cyl(0.10, 0.036, 0.036, 64).translate((0, 0, 0.004))
    )
    rng = np.random.default_rng(5)
    for mesh in (mug, _mesh(), trimesh.creation.box((0.05, 0.03, 0.02))):
        field = DistanceField(mesh, spacing=0.005)
        lo, hi = mesh.bounds
        p = np.concatenate([
            rng.uniform(lo - 0.3, hi + 0.3, (20000, 3)),  # mostly outside the box
            rng.uniform(lo, hi, (5000, 3)),  # inside the box: sign test kept
            np.clip(rng.uniform(lo - 0.01, hi + 0.01, (5000, 3)), lo - 1e-3, hi + 1e-3),  # margin
        ])  # fmt: skip
        np.testing.assert_array_equal(field._exact_values(p), field._exact(p)[0])
        assert field._exact_values(p[:0]).shape == (0,)
