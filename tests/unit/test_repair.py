"""Explicit mesh repair (geometry/repair.py): welding, holes, unions, distances, units, cache."""

import numpy as np
import pytest
import trimesh

from grip_bench.core.errors import InputError
from grip_bench.geometry import meshes
from grip_bench.geometry import repair as R
from grip_bench.geometry.meshes import MeshOptions, load_object_mesh


def _soup(mesh):
    """Every face with its own three vertices (a seam everywhere)."""
    return trimesh.Trimesh(mesh.vertices[mesh.faces].reshape(-1, 3),
                           np.arange(3 * len(mesh.faces)).reshape(-1, 3), process=False)


def test_seam_split_cube_welds_closed_same_volume():
    box = trimesh.creation.box((0.05, 0.04, 0.03))
    out, rep = R.repair(_soup(box), "cube")
    assert out.is_watertight and rep.method == "welded"
    assert rep.welded_vertices == 36 - 8 and out.volume == pytest.approx(box.volume, rel=1e-9)


def test_sphere_with_small_hole_closed_close_to_analytic():
    s = trimesh.creation.icosphere(4, 0.05)
    holed = trimesh.Trimesh(s.vertices, s.faces[3:], process=False)
    out, rep = R.repair(holed, "ball", tolerance_mm=5)
    assert rep.method == "surface" and rep.closed_holes >= 1 and out.is_watertight
    assert 0 < rep.max_mm < 3.0  # the fan's centre sits within the hole's radius
    assert out.volume == pytest.approx(4 / 3 * np.pi * 0.05**3, rel=5e-3)


def test_overlapping_shells_union_matches_analytic_lens():
    r, d = 0.05, 0.04
    a = trimesh.creation.icosphere(5, r)
    b = a.copy()
    b.apply_translation([d, 0, 0])
    out, rep = R.repair(trimesh.util.concatenate([a, b]), "pair")
    lens = np.pi * (4 * r + d) * (2 * r - d) ** 2 / 12
    assert rep.shells_in == 2 and rep.shells_out == 1 and rep.max_mm < 0.01
    assert rep.hidden_input_fraction > 0.1  # the inner walls, removed by the union
    assert out.volume == pytest.approx(2 * a.volume - lens, rel=5e-3)


def test_self_intersecting_open_shells_rebuilt_by_winding_number():
    """An open box (one face missing, inside another box) cannot be surface-repaired."""
    a = trimesh.creation.box((0.04, 0.04, 0.04))
    b = a.copy()
    b.apply_translation([0.02, 0, 0])
    inner = b.triangles_center[:, 0] < 0.001  # b's -x face lies inside a
    b = trimesh.Trimesh(b.vertices, b.faces[~inner], process=False)
    out, rep = R.repair(trimesh.util.concatenate([a, b]), "boxes", tolerance_mm=1)
    assert rep.method == "winding-number" and out.is_watertight
    assert rep.cell_mm == pytest.approx(1 / 3)
    assert out.volume == pytest.approx(0.06 * 0.04 * 0.04, rel=2e-2)
    assert rep.max_mm <= 1.0


def _point_triangle(p, tri):
    """Naive distance of a point to a triangle: interior projection, else its edges."""
    a, b, c = tri
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    q = p - np.dot(p - a, n) * n
    inside = all(np.dot(np.cross(v1 - v0, q - v0), n) >= 0 for v0, v1 in ((a, b), (b, c), (c, a)))
    if inside:
        return abs(np.dot(p - a, n))
    best = np.inf
    for v0, v1 in ((a, b), (b, c), (c, a)):
        t = np.clip(np.dot(p - v0, v1 - v0) / np.dot(v1 - v0, v1 - v0), 0, 1)
        best = min(best, np.linalg.norm(p - (v0 + t * (v1 - v0))))
    return best


def test_distance_report_matches_brute_force():
    src = trimesh.creation.box((0.04, 0.04, 0.04))
    rep = src.copy()
    rep.apply_scale(1.05)
    d = R.surface_distances(src, rep, count=300, seed=3)
    p_in, _ = R._samples(src, 300, 3)
    p_out = np.vstack([R._samples(rep, 300, 4)[0], rep.vertices])
    d_in = [min(_point_triangle(p, t) for t in rep.triangles) for p in p_in]
    d_out = [min(_point_triangle(p, t) for t in src.triangles) for p in p_out]
    assert d["in_max"] == pytest.approx(max(d_in), abs=1e-9)
    assert d["out_max"] == pytest.approx(max(d_out), abs=1e-9)
    assert d["mean"] == pytest.approx(np.mean(d_in + d_out), abs=1e-9)
    assert d["max"] == pytest.approx(0.001 * np.sqrt(3), rel=1e-6)  # the corners moved


def test_repair_beyond_tolerance_names_the_flag(tmp_path):
    s = trimesh.creation.icosphere(3, 0.05)
    cap = s.triangles_center[:, 2] > 0.045
    path = tmp_path / "bowl.ply"
    trimesh.Trimesh(s.vertices, s.faces[~cap], process=False).export(path)
    with pytest.raises(InputError) as e:
        load_object_mesh(path)
    assert "--accept-repair" in e.value.what and "open" in e.value.what
    assert e.value.where == str(path)


def test_units_check_and_scale(tmp_path):
    path = tmp_path / "mm.obj"
    trimesh.creation.icosphere(2, 40.0).export(path)
    with pytest.raises(InputError, match="looks like millimetres: pass --mesh-scale 0.001"):
        load_object_mesh(path)
    mesh = load_object_mesh(path, options=MeshOptions(scale=0.001))
    assert np.ptp(mesh.vertices, axis=0).max() == pytest.approx(0.08, rel=1e-3)
    cm = tmp_path / "cm.obj"
    trimesh.creation.icosphere(2, 4.0).export(cm)
    with pytest.raises(InputError, match="centimetres: pass --mesh-scale 0.01"):
        load_object_mesh(cm)


def test_second_load_reads_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GRIP_BENCH_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "seam.obj"
    _soup(trimesh.creation.box((0.05, 0.05, 0.05))).export(path)
    first = load_object_mesh(path)
    assert first.metadata["repair"]["cached"] is False

    def boom(*a, **k):
        raise AssertionError("repaired again")

    monkeypatch.setattr(meshes, "repair", boom)
    second = load_object_mesh(path)
    assert second.metadata["repair"]["cached"] is True
    assert np.array_equal(first.vertices, second.vertices)
    assert np.array_equal(first.faces, second.faces)
    # other options are another entry
    with pytest.raises(AssertionError, match="repaired again"):
        load_object_mesh(path, options=MeshOptions(accept_repair_mm=2.0))
