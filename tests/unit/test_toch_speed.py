"""TOCH prediction's shortcuts give what the plain computations give, bit for bit: the
slab-built ray grid against the per-ray whole-box build, the tight broad phase against
every pair's sphere test, the plane-wise sphere test against the row-wise one, the
interaction frames against measuring every vertex of every frame, and the grid cache's
memory bound."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from grip_baselines import common as U
from grip_baselines import toch, toch_method
from grip_baselines.toch_method import far_frames, interaction_frames

from grip_bench.data.library import ObjectLibrary
from tests.grab_fixtures import make_sequence

pytestmark = pytest.mark.usefixtures("one_thread")  # the 2 test cores are shared


def whole_box_grid(
    o: np.ndarray, d: np.ndarray, max_dist: float, reach_mm: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first grid build (reference): every cell of each ray's dilated bounding box
    measured, ray by ray; ``(start, rays, key)`` as :class:`toch._RayGrid` holds them."""
    reach_mm = -(-reach_mm // toch._GRID_REACH_STEP) * toch._GRID_REACH_STEP
    reach = reach_mm * 1e-3
    a, b = o - max_dist * d, o + max_dist * d
    h = toch._grid_cell(o, d, max_dist)
    lo = np.minimum(a, b).min(0) - reach - h
    dims = np.ceil((np.maximum(a, b).max(0) + reach + h - lo) / h).astype(np.int64)
    keys, owners = [], []
    for i in range(len(o)):
        i0 = np.clip(np.floor((np.minimum(a[i], b[i]) - reach - lo) / h) - 1, 0, dims - 1)
        i1 = np.clip(np.floor((np.maximum(a[i], b[i]) + reach - lo) / h) + 1, 0, dims - 1)
        axes = [np.arange(i0[k], i1[k] + 1, dtype=np.int64) for k in range(3)]
        idx = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        w = lo + (idx + 0.5) * h - o[i]
        s = np.clip(w @ d[i], -max_dist, max_dist)
        dist = np.sqrt(((w - s[:, None] * d[i]) ** 2).sum(1))
        near = dist <= reach
        lin = (idx[near, 0] * dims[1] + idx[near, 1]) * dims[2] + idx[near, 2]
        keys.append(lin * (reach_mm + 1) + np.ceil(dist[near] / 1e-3).astype(np.int64))
        owners.append(np.full(len(lin), i, np.int64))
    k, ray = np.concatenate(keys), np.concatenate(owners)
    order = np.argsort(k, kind="stable")
    counts = np.bincount(k // (reach_mm + 1), minlength=int(dims.prod()))
    return np.r_[0, np.cumsum(counts)], ray[order], k[order]


def _rays(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    o = rng.uniform(-0.08, 0.08, (n, 3))
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize(("max_dist", "reach_mm"), [(0.1, 12), (0.1, 16), (0.03, 9), (0.02, 30)])
def test_slab_grid_equals_the_whole_box_build(max_dist: float, reach_mm: int) -> None:
    """Random rays plus axis-aligned, non-unit and zero directions: the same cells, rays,
    keys and order as measuring every cell of every ray's box, and each cell's nearest
    ray is its first key."""
    o, d = _rays(70, 2)
    d[:6] = np.eye(3)[[0, 1, 2, 0, 1, 2]] * [[1.0], [-1.0], [1.0], [2.0], [0.5], [-3.0]]
    d[6] = 0.0  # a degenerate ray: a point
    toch._GRIDS.clear()
    grid = toch._ray_grid(o, d, max_dist, reach_mm)
    start, rays, key = whole_box_grid(o, d, max_dist, reach_mm)
    assert len(rays) > 1000
    np.testing.assert_array_equal(grid.start.numpy(), start)
    np.testing.assert_array_equal(grid.rays.numpy(), rays)
    np.testing.assert_array_equal(grid.key.numpy(), key)
    r = grid.reach_mm + 1
    busy = np.flatnonzero(start[1:] > start[:-1])
    near = grid.near.numpy()
    np.testing.assert_array_equal(near[busy], key[start[busy]] - busy * r)
    assert (np.delete(near, busy) == r).all()


def _triangles(n_pose: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Bounding spheres ``(centre (M, 3), radius (M,))`` of small random triangles, some
    beyond the grid, one not finite."""
    rng = np.random.default_rng(seed)
    v0 = rng.uniform(-0.12, 0.12, (n_pose, 3))
    v = v0[:, None] + rng.normal(scale=0.004, size=(n_pose, 3, 3))
    v[5] = np.nan
    v[7] += 10.0  # far beyond the grid
    tri = torch.as_tensor(v)
    centre = tri.mean(1)
    radius = (tri - centre[:, None]).norm(dim=-1).amax(1)
    return centre, radius


def test_broad_phase_is_every_pair_whose_sphere_reaches_the_segment() -> None:
    """The candidates are exactly the pairs the row-wise sphere test accepts among all
    ray x triangle pairs, ordered by triangle; each triangle's rays in its cell's order."""
    o, d = (torch.as_tensor(x) for x in _rays(60, 3))
    centre, radius = _triangles(8000, 4)
    toch._GRIDS.clear()
    ray, tri = toch._candidates(o, d, centre, radius, 0.1)
    w = centre[None] - o[:, None]  # (N, M, 3) all pairs, the first (row-wise) sphere test
    s = (w * d[:, None]).sum(-1).clamp(-0.1, 0.1)
    gap = (w - s[..., None] * d[:, None]).pow(2).sum(-1)
    ref = gap <= (radius + toch._SPHERE_MARGIN).pow(2)  # (N, M)
    assert 1000 < len(ray) == int(ref.sum())
    assert ref[ray, tri].all()
    assert (torch.diff(tri) >= 0).all()
    grid = next(iter(toch._GRIDS.values()))
    idx = torch.floor((centre[tri] - grid.lo) / grid.cell).long()
    lin = (idx[:, 0] * grid.dims[1] + idx[:, 1]) * grid.dims[2] + idx[:, 2]
    pos = [int(torch.nonzero(grid.rays[grid.start[c] : grid.start[c + 1]] == r)[0, 0])
           for c, r in zip(lin.tolist(), ray.tolist(), strict=True)]
    rank = torch.tensor(pos)  # each pair's place in its triangle's cell
    same = tri[1:] == tri[:-1]
    assert (rank[1:][same] > rank[:-1][same]).all()


def test_plane_wise_sphere_test_equals_the_row_wise_one() -> None:
    """The sphere test on coordinate planes gives the row-wise test's booleans on a
    million random pairs, boundary cases included (sums in the same order)."""
    g = torch.Generator().manual_seed(5)
    o = torch.rand(300, 3, generator=g, dtype=torch.float64) * 0.2
    d = torch.nn.functional.normalize(torch.randn(300, 3, generator=g, dtype=torch.float64), dim=1)
    centre = torch.rand(5000, 3, generator=g, dtype=torch.float64) * 0.2
    ray = torch.randint(0, 300, (1_000_000,), generator=g)
    tri = torch.randint(0, 5000, (1_000_000,), generator=g)
    w = centre[tri] - o[ray]
    s = (w * d[ray]).sum(-1).clamp(-0.1, 0.1)
    gap = (w - s[:, None] * d[ray]).pow(2).sum(-1)
    radius = torch.zeros(5000, dtype=torch.float64)
    radius[tri] = gap.sqrt() - toch._SPHERE_MARGIN  # each triangle on some pair's boundary
    ref = gap <= (radius[tri] + toch._SPHERE_MARGIN).pow(2)
    got = toch._near_segment(o.T.contiguous(), d.T.contiguous(), centre.T.contiguous(), radius,
                             ray, tri, 0.1)
    assert 0.0 < ref.double().mean() < 1.0
    assert torch.equal(got, ref)


def test_grid_cache_keeps_recent_grids_within_its_memory(monkeypatch: pytest.MonkeyPatch) -> None:
    size = {}
    for seed in (0, 1, 2, 9):
        toch._GRIDS.clear()
        size[seed] = toch._ray_grid(*_rays(20, seed), 0.1, 8).nbytes
    toch._GRIDS.clear()
    grids = [toch._ray_grid(*_rays(20, seed), 0.1, 8) for seed in range(3)]
    assert len(toch._GRIDS) == 3
    assert toch._ray_grid(*_rays(20, 0), 0.1, 8) is grids[0]  # a hit: now the most recent
    monkeypatch.setattr(toch, "_GRID_CACHE_BYTES", size[0] + size[9])
    new = toch._ray_grid(*_rays(20, 9), 0.1, 8)  # evicts the least recent ones (seeds 1, 2)
    assert list(toch._GRIDS.values()) == [grids[0], new]
    monkeypatch.setattr(toch, "_GRID_CACHE_BYTES", 0)
    last = toch._ray_grid(*_rays(20, 10), 0.1, 8)  # over the budget alone: still kept
    assert list(toch._GRIDS.values()) == [last]


@pytest.mark.parametrize("stride", [8, 10**6])  # 10**6: the wrist alone probes
def test_interaction_frames_equal_measuring_every_vertex(
    tiny_grip_root: Path, stride: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An object swept from inside the hand to 50 cm away: the far-frame bound and the
    probe vertices give the mask of measuring every vertex of every frame, frames the
    bound skips are far by the measure, and all three kinds of frame occur."""
    monkeypatch.setattr(toch_method, "_PROBE_STRIDE", stride)
    library = ObjectLibrary(tiny_grip_root)
    T = 60
    seq = make_sequence(T, seed=3, obj_name="mug", intent="lift", sbj_id="s1")
    rng = np.random.default_rng(0)
    direction = rng.normal(size=(T, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    offset = direction * np.linspace(0.0, 0.5, T)[:, None]
    obj = dict(seq.object, transl=(seq.rhand["transl"] + offset).astype(np.float32))
    seq = replace(seq, object=obj).validate()
    for side in ("right", "left"):
        p = seq.hand_params(side)
        world = U.seq_vertices(seq, side, p)
        d = U.signed_distance(library, seq, world)  # (T, V) every vertex, every frame
        for dist in (0.03, 0.08):
            ref = (d <= dist).any(1)
            np.testing.assert_array_equal(interaction_frames(library, seq, side, p, dist), ref)
            far = far_frames(library, seq, world, dist)
            assert (d[far] > dist).all()
            if side == "right" and dist == 0.03:
                assert ref.any() and far.any() and (~ref & ~far).any()
