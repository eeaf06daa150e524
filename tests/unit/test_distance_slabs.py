"""DistanceField's grid built in slabs: bit for bit the whole-grid build it replaced.

The reference below is the whole-grid algorithm (every node at once: one libigl query, one
coarse fill, one np.gradient, one kink pass), kept verbatim as the naive form of
``DistanceField._grid_arrays``.
"""

import math
import tracemalloc

import igl
import numpy as np
import pytest
import trimesh

from grip_bench.core import constants
from grip_bench.geometry import distance
from grip_bench.geometry.distance import _CORNERS, DistanceField, _trilinear

from .test_geometry_pieces import bowl_mesh


def _naive_coarse_fill(f: DistanceField, nodes: np.ndarray, band: float) -> np.ndarray:
    factor = constants.SDF_COARSE_FACTOR
    H = f.spacing * factor
    shape_c = tuple(int(np.ceil((s - 1) / factor)) + 1 for s in f.shape)
    coarse_nodes = f._node_coords(shape_c, f.origin, H)
    vals = f._exact(coarse_nodes)[0].reshape(shape_c)
    u = (nodes - f.origin) / H
    i = np.clip(np.floor(u), 0, np.array(shape_c) - 2)
    strides = np.array([shape_c[1] * shape_c[2], shape_c[2], 1])
    base = (i * strides).sum(1).astype(np.intp)
    out = _trilinear(vals.ravel(), base, u - i, _CORNERS @ strides)
    return np.where(out < 0, -1.0, 1.0) * np.maximum(np.abs(out), band)


def _naive_kink_cells(f: DistanceField, grad: np.ndarray, near: np.ndarray) -> np.ndarray:
    limit = 4.0 * constants.SDF_KINK_TOL / f.spacing
    views = [grad[i : i + grad.shape[0] - 1, j : j + grad.shape[1] - 1,
                  k : k + grad.shape[2] - 1]
             for i, j, k in _CORNERS]  # fmt: skip
    gmax, gmin = views[0].copy(), views[0].copy()
    all_near = near[:-1, :-1, :-1].copy()
    for v, (i, j, k) in zip(views[1:], _CORNERS[1:], strict=True):
        np.maximum(gmax, v, out=gmax)
        np.minimum(gmin, v, out=gmin)
        all_near &= near[
            i : i + near.shape[0] - 1, j : j + near.shape[1] - 1, k : k + near.shape[2] - 1
        ]
    spread = np.linalg.norm(gmax - gmin, axis=-1)
    flags = np.zeros(f.shape, dtype=bool)
    flags[:-1, :-1, :-1] = all_near & (spread > limit)
    return flags.ravel()


def naive_grid_arrays(f: DistanceField) -> dict[str, np.ndarray]:
    """The whole-grid build: every node's float64 temporaries at once."""
    h = f.spacing
    lo = f._V.min(0) - f.padding
    n = np.ceil((f._V.max(0) + f.padding - lo) / h).astype(int) + 1
    f.origin, f.shape = lo, tuple(int(x) for x in n)
    band = constants.SDF_EXACT_DEPTH + h * math.sqrt(3.0)
    nodes = f._node_coords(f.shape, lo, h)
    s, _, c, normal = igl.signed_distance(
        nodes, f._V, f._F,
        sign_type=igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL,
        lower_bound=-band, upper_bound=band,
    )  # fmt: skip
    near = np.isfinite(s)
    values = np.where(near, s, _naive_coarse_fill(f, nodes, band))
    grad = np.zeros_like(nodes)
    off = nodes[near] - c[near]
    dn = s[near][:, None]
    grad[near] = np.where(np.abs(dn) > 1e-9, off / np.where(dn == 0, 1.0, dn), normal[near])
    grid = values.reshape(f.shape)
    far_grad = np.stack(np.gradient(grid, h), -1).reshape(-1, 3)
    grad[~near] = far_grad[~near]
    grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
    unreliable = _naive_kink_cells(f, grad.reshape(*f.shape, 3), near.reshape(f.shape))
    return {"origin": np.asarray(lo, np.float64), "shape": np.array(f.shape, np.int64),
            "values": values.astype(np.float32), "grad": grad.astype(np.float32),
            "unreliable": unreliable}


def _assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        assert np.array_equal(a[k], b[k]), k


@pytest.fixture(autouse=True)
def _no_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GRIP_BENCH_CACHE", str(tmp_path / "cache"))


def _annulus() -> trimesh.Trimesh:
    """A concave ring: outer radius 3 cm, inner 1.5 cm, 2 cm tall."""
    return trimesh.creation.annulus(r_min=0.015, r_max=0.03, height=0.02, sections=48)


@pytest.mark.parametrize("rows", [1, 2, 3])
def test_many_slabs_equal_the_whole_grid(monkeypatch, rows):
    """A coarse box grid (4 mm nodes, 41 rows: not a multiple of 2 or 3) cut into 1-3 rows."""
    mesh = trimesh.creation.box((0.10, 0.06, 0.04))
    f = DistanceField(mesh, spacing=0.004, padding=0.03)
    n1, n2 = f.shape[1:]
    assert f.shape[0] % 2 and f.shape[0] % 3
    monkeypatch.setattr(distance, "_SLAB_NODES", rows * n1 * n2)
    reference = naive_grid_arrays(f)
    _assert_same(f._grid_arrays(), reference)
    assert reference["unreliable"].any()  # the box's edges: the kink pass is exercised


@pytest.mark.parametrize("make", [_annulus, bowl_mesh], ids=["annulus", "bowl"])
@pytest.mark.parametrize("rows", [1, 4, 7])
def test_concave_meshes_equal_the_whole_grid(monkeypatch, make, rows):
    mesh = make()
    f = DistanceField(mesh, spacing=0.003, padding=0.03)
    n0, n1, n2 = f.shape
    assert n0 % rows or rows == 1
    monkeypatch.setattr(distance, "_SLAB_NODES", rows * n1 * n2 + n1)  # rounds down to rows
    reference = naive_grid_arrays(f)
    near = np.abs(reference["values"]) < constants.SDF_EXACT_DEPTH
    assert near.any() and (~near).any()  # both the exact band and the coarse fill
    _assert_same(f._grid_arrays(), reference)


def test_default_slab_and_one_slab_equal_the_whole_grid(monkeypatch):
    """The module's slab size (two slabs of this 91^3 grid), and one slab holding the whole
    grid (no overlap at all)."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.06)
    f = DistanceField(mesh)
    n0, n1, n2 = f.shape
    assert distance._SLAB_NODES // (n1 * n2) < n0  # more than one slab
    reference = naive_grid_arrays(f)
    _assert_same(f._grid_arrays(), reference)
    monkeypatch.setattr(distance, "_SLAB_NODES", int(np.prod(f.shape)))
    _assert_same(f._grid_arrays(), reference)


@pytest.mark.filterwarnings("ignore:divide by zero")  # _to_torch_volumes' cell scale, 2 rows
def test_two_row_grid(monkeypatch):
    """The smallest grid np.gradient accepts along the slab axis: two rows, one per slab."""
    mesh = trimesh.creation.box((0.001, 0.04, 0.04))
    f = DistanceField(mesh, spacing=0.004, padding=0.001)
    assert f.shape[0] == 2
    monkeypatch.setattr(distance, "_SLAB_NODES", 1)
    _assert_same(f._grid_arrays(), naive_grid_arrays(f))


def test_slabs_bound_the_build_memory(monkeypatch):
    """numpy's peak allocation during the build (tracemalloc) is the float32/bool outputs
    (17 bytes a node) plus one slab's temporaries, not ~20 float64 per node of the grid."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    f = DistanceField(mesh)  # 81^3 = 531k nodes
    nodes = int(np.prod(f.shape))
    monkeypatch.setattr(distance, "_SLAB_NODES", 1 << 15)
    tracemalloc.start()
    try:
        f._grid_arrays()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    outputs = 17 * nodes
    assert peak < outputs + 1000 * (1 << 15)  # ~9 MB + 33 MB; the whole-grid build: > 80 MB
