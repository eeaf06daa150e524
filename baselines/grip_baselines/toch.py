"""TOCH-style motion refiner pieces: object-centric correspondence field, a temporal
denoising autoencoder over it, and the hand fit to a (denoised) field.

Written from the TOCH paper's description, not from its code.

Correspondence field (per object surface sample ``p`` with outward normal ``n``), our
definition of the ray rule:

* If ``p`` is outside the hand, cast the ray ``p + t n`` forward (``t >= 0``); the first hand
  surface it meets within ``max_dist`` is the correspondence and the distance is ``+t``.
* If ``p`` is inside the hand (the hand penetrates the object there), cast backwards
  (``t <= 0``): the nearest hand surface behind ``p`` is the part that went through the
  object, and the distance is ``-|t|`` (negative = penetration).
* Inside/outside comes from the first forward crossing: leaving the hand through a
  face (ray along the face's outward normal) means ``p`` was inside. This needs a closed,
  outward-oriented hand mesh (ProceduralHand and MANO-with-closed-wrist are).

A hit's correspondence is the same barycentric point of the same triangle on the
canonical (unposed) hand, so it says *which* part of the hand is there, independent of
the pose. Lengths are metres.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import igl
import numpy as np
import torch
from torch import nn

from grip_bench.core.constants import TOCH_MAX_DIST, TOCH_WINDOW
from grip_bench.core.errors import InputError
from grip_bench.nn.blocks import check_config, check_shape

__all__ = [
    "CorrespondenceField",
    "FitConfig",
    "FitResult",
    "TemporalAE",
    "TemporalAEConfig",
    "correspondence_field",
    "field_losses",
    "fit_hand_to_field",
    "hit_pos_weight",
    "correspondence_fields",
    "ray_mesh_hits",
    "ray_mesh_hits_batch",
]

FIELD_DIM = 5  # hit, signed distance (m), canonical hand point (m)
_BARY_TOL = 1e-9  # inclusive barycentric bounds: a ray through an edge or vertex still hits
_SPHERE_MARGIN = 1e-9  # m; bounding spheres are padded so rounding never culls a true hit
# Broad-phase grid fixed to the rays (see _candidates). Cell side: ~ the hand's triangle
# size, so a triangle's cell lists the few rays near it; a coarser cell only when a ray
# set spans more than _GRID_MAX_SIDE cells (memory). _GRID_SLACK pads the reach for the
# rounding of a centre's cell. A grid reaches whole multiples of _GRID_REACH_STEP mm (a
# hand's largest triangle rarely asks for a rebuild). _GRID_CACHE_BYTES: memory of the
# cached grids (~5-10 MB per object at the default 256 samples).
_GRID_CELL = 0.005  # m
_GRID_MAX_SIDE = 160
_GRID_SLACK = 1e-6  # m
_GRID_REACH_STEP = 4  # mm
_GRID_CACHE_BYTES = 256 * 2**20
_GRID_BUILD_RAYS = 32  # rays per chunk of a grid build (~100k cells, a few MB)


# ----------------------------------------------------------------------------- ray casting


def _near_segment(
    o: torch.Tensor, d: torch.Tensor, centre: torch.Tensor, radius: torch.Tensor,
    ray: torch.Tensor, tri: torch.Tensor, max_dist: float,
) -> torch.Tensor:
    """Whether the spheres ``(centre[:, tri], radius[tri])`` come within reach of the
    segments ``o[:, ray] + t d[:, ray], |t| <= max_dist``: ``(P,)`` bool for the pairs
    ``ray, tri (P,)``. Points come as coordinate planes (``o, d (3, N)``, ``centre
    (3, M)``), so each pair reads scalars and no (P, 3) rows are gathered or reduced; the
    sums run x + y + z, the order of ``sum(-1)`` over rows, so the values are the same."""
    w = [centre[k][tri] - o[k][ray] for k in range(3)]
    dk = [d[k][ray] for k in range(3)]
    s = (w[0] * dk[0] + w[1] * dk[1] + w[2] * dk[2]).clamp_(-max_dist, max_dist)
    gap = (w[0] - s * dk[0]).pow_(2) + (w[1] - s * dk[1]).pow_(2) + (w[2] - s * dk[2]).pow_(2)
    return gap <= (radius[tri] + _SPHERE_MARGIN).pow_(2)


def _morton_order(points: torch.Tensor) -> torch.Tensor:
    """Order of ``points (F, 3)`` along a Z-order curve (10 bits per axis).

    Only breaks exact ties now: the first sphere-tree broad phase listed a ray's candidate
    triangles in this order, so of two hits at exactly the same distance it kept the one
    earlier here; :func:`ray_mesh_hits_batch` keeps that choice, so its output is the
    same bit for bit."""
    lo, hi = points.amin(0), points.amax(0)
    q = ((points - lo) / (hi - lo).clamp(min=1e-12) * 1023).long()
    code = torch.zeros(len(points), dtype=torch.long)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return torch.argsort(code)


@dataclass(frozen=True)
class _RayGrid:
    """Uniform grid over the reach of fixed ray segments. Cell ``c`` lists, in
    ``rays[start[c]:start[c + 1]]``, the rays whose segment passes within ``reach_mm``
    millimetres of its centre, nearest first by whole millimetres: the entries with
    ``key <= c * (reach_mm + 1) + k`` are the rays within ``k`` mm (``k <= reach_mm``)."""

    lo: torch.Tensor  # (3,) m, corner of cell (0, 0, 0)
    cell: float  # m, cell side
    dims: tuple[int, int, int]
    reach_mm: int
    start: torch.Tensor  # (n_cells + 1,) int64 offsets into rays / key
    rays: torch.Tensor  # (nnz,) int64 ray ids
    key: torch.Tensor  # (nnz,) int64 cell * (reach_mm + 1) + ceil(distance / mm), ascending
    near: torch.Tensor  # (n_cells,) int16 whole mm to the cell's nearest ray (reach_mm + 1: none)

    @property
    def nbytes(self) -> int:
        """Memory held by the grid's arrays (bytes)."""
        return sum(
            x.numel() * x.element_size() for x in (self.start, self.rays, self.key, self.near)
        )


_GRIDS: OrderedDict[tuple, _RayGrid] = OrderedDict()  # most recently used last


def _grid_cell(o: np.ndarray, d: np.ndarray, max_dist: float) -> float:
    """Cell side (m) of the ray grid of ``o, d (N, 3)``: ``_GRID_CELL``, or coarser when
    the segments span more than ``_GRID_MAX_SIDE`` cells (bounded memory)."""
    ends = np.concatenate([o - max_dist * d, o + max_dist * d])
    return max(_GRID_CELL, float((ends.max(0) - ends.min(0)).max()) / _GRID_MAX_SIDE)


def _expand(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(row, rank)`` of ``counts (R,)`` items per row: each item's row and its place in
    it, ``(sum(counts),)`` int64 each, in row order."""
    row = np.repeat(np.arange(len(counts)), counts)
    return row, np.arange(len(row)) - np.repeat(np.cumsum(counts) - counts, counts)


def _ray_cells(
    o: np.ndarray, d: np.ndarray, max_dist: float, reach: float, lo: np.ndarray, h: float,
    i0: np.ndarray, i1: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Cells ``(M, 3)`` int64 and their ray ``(M,)`` (ascending, each cell once per ray)
    that may have their centre within ``reach`` (m) of the segments ``o + s d,
    |s| <= max_dist`` (``o, d (N, 3)``), among each ray's box of cells ``i0, i1 (N, 3)``
    (inclusive): a superset of them, built slab by slab across each ray's main axis ``k``.
    The centres of slab ``j`` lie on one plane ``x_k = c_j``; those within ``reach`` are
    near the stretch of the segment with ``|x_k - c_j| <= reach``, so the slab's cells are
    the box of that stretch widened by ``reach``. Bounds are padded by ``_GRID_SLACK`` (m)
    against rounding, so no cell within reach is left out, and a long segment visits a
    thin tube of its bounding box instead of all of it (~6x fewer cells)."""
    n = len(o)
    k = np.argmax(np.abs(d), 1)  # (N,) |d[k]| >= |d| / sqrt(3)
    point = d[np.arange(n), k] == 0  # a zero direction: the segment is a point
    if point.any():  # the whole (small) box of each such ray
        cells = [
            (ray, np.stack(np.meshgrid(*(np.arange(i0[ray, a], i1[ray, a] + 1)
                                         for a in range(3)), indexing="ij"), -1).reshape(-1, 3))
            for ray in np.flatnonzero(point)
        ]
    ray, j = _expand(np.where(point, 0, i1[np.arange(n), k] - i0[np.arange(n), k] + 1))
    kk = k[ray]
    j += i0[ray, kk]  # (J,) the slabs along axis k of each ray
    plane = lo[kk] + (j + 0.5) * h  # the slabs' centre coordinate
    pad = reach + _GRID_SLACK
    ok, dk = o[ray, kk], d[ray, kk]
    sa, sb = (plane - pad - ok) / dk, (plane + pad - ok) / dk
    s0 = np.maximum(np.minimum(sa, sb), -max_dist)
    s1 = np.minimum(np.maximum(sa, sb), max_dist)
    keep = s0 <= s1
    ray, kk, j, s0, s1 = ray[keep], kk[keep], j[keep], s0[keep], s1[keep]
    first, size = [], []
    for m in (kk + 1) % 3, (kk + 2) % 3:  # each other axis: centres in [x0 - pad, x1 + pad]
        x0, x1 = o[ray, m] + s0 * d[ray, m], o[ray, m] + s1 * d[ray, m]
        c0 = np.ceil((np.minimum(x0, x1) - pad - lo[m]) / h - 0.5 - _GRID_SLACK / h)
        c1 = np.floor((np.maximum(x0, x1) + pad - lo[m]) / h - 0.5 + _GRID_SLACK / h)
        c0 = np.clip(c0, i0[ray, m], i1[ray, m]).astype(np.int64)
        c1 = np.clip(c1, i0[ray, m], i1[ray, m]).astype(np.int64)
        first.append(c0)
        size.append(np.maximum(c1 - c0 + 1, 0))
    slab, rank = _expand(size[0] * size[1])
    idx = np.empty((len(slab), 3), np.int64)
    rows = np.arange(len(slab))
    kk = kk[slab]
    idx[rows, kk] = j[slab]
    idx[rows, (kk + 1) % 3] = first[0][slab] + rank // size[1][slab]
    idx[rows, (kk + 2) % 3] = first[1][slab] + rank % size[1][slab]
    owner = ray[slab]
    if point.any():
        owner = np.concatenate([owner] + [np.full(len(c), r) for r, c in cells])
        idx = np.concatenate([idx] + [c for _, c in cells])
        order = np.argsort(owner, kind="stable")
        owner, idx = owner[order], idx[order]
    return idx, owner


def _ray_grid(o: np.ndarray, d: np.ndarray, max_dist: float, reach_mm: int) -> _RayGrid:
    """A :class:`_RayGrid` of rays ``o, d (N, 3)`` that reaches at least ``reach_mm``,
    cached per ray set: the rays of a prediction are the object's fixed surface samples,
    the same for every frame, window and hand, while only the hand moves. A wider reach
    than the cached grid's rebuilds it (rounded up to ``_GRID_REACH_STEP`` mm). The cache
    keeps the most recently used grids up to ``_GRID_CACHE_BYTES`` (a test split's objects
    each come back several times; a build of 256 rays costs ~0.1 s)."""
    key = (hashlib.sha1(o.tobytes() + d.tobytes()).hexdigest(), o.shape, max_dist)
    grid = _GRIDS.get(key)
    if grid is not None and grid.reach_mm >= reach_mm:
        _GRIDS.move_to_end(key)
        return grid
    reach_mm = -(-reach_mm // _GRID_REACH_STEP) * _GRID_REACH_STEP
    reach = reach_mm * 1e-3
    a, b = o - max_dist * d, o + max_dist * d  # segment ends (N, 3)
    h = _grid_cell(o, d, max_dist)
    lo = np.minimum(a, b).min(0) - reach - h
    dims = np.ceil((np.maximum(a, b).max(0) + reach + h - lo) / h).astype(np.int64)
    i0 = np.clip(np.floor((np.minimum(a, b) - reach - lo) / h) - 1, 0, dims - 1).astype(np.int64)
    i1 = np.clip(np.floor((np.maximum(a, b) + reach - lo) / h) + 1, 0, dims - 1).astype(np.int64)
    keys, rays = [], []
    for c in range(0, len(o), _GRID_BUILD_RAYS):  # once per ray set; chunks bound the memory
        sl = slice(c, c + _GRID_BUILD_RAYS)
        idx, owner = _ray_cells(o[sl], d[sl], max_dist, reach, lo, h, i0[sl], i1[sl])
        owner += c
        bounds = np.searchsorted(owner, np.arange(c, c + len(o[sl]) + 1))
        per_ray = np.diff(bounds)  # cells of each ray (owner ascends)
        w = lo + (idx + 0.5) * h - np.repeat(o[sl], per_ray, 0)  # (M, 3)
        # The distances of the cells as the first (per ray, whole box) build computed
        # them, its per-ray matrix-vector product included: the same grid bit for bit.
        s = np.empty(len(w))
        for i, (p, q) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
            s[p:q] = w[p:q] @ d[c + i]
        np.clip(s, -max_dist, max_dist, out=s)
        dist = np.sqrt(((w - s[:, None] * np.repeat(d[sl], per_ray, 0)) ** 2).sum(1))
        near = dist <= reach
        idx = idx[near]
        lin = (idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]
        keys.append(lin * (reach_mm + 1) + np.ceil(dist[near] / 1e-3).astype(np.int64))
        rays.append(owner[near])
    k, ray = np.concatenate(keys), np.concatenate(rays)
    # a cell's rays by key, then in ray order: (key, ray) made one unique integer, so the
    # fast (unstable) sort gives that order
    order = np.argsort(k * len(o) + ray)
    k, ray = k[order], ray[order]
    cells = k // (reach_mm + 1)
    start = np.r_[0, np.cumsum(np.bincount(cells, minlength=int(dims.prod())))]
    near = np.full(int(dims.prod()), reach_mm + 1, np.int16)
    busy = start[1:] > start[:-1]
    near[busy] = k[start[:-1][busy]] - cells[start[:-1][busy]] * (reach_mm + 1)
    grid = _RayGrid(
        torch.as_tensor(lo), h, tuple(int(x) for x in dims), reach_mm,
        torch.as_tensor(start), torch.as_tensor(ray), torch.as_tensor(k), torch.as_tensor(near),
    )
    _GRIDS[key] = grid
    _GRIDS.move_to_end(key)
    while len(_GRIDS) > 1 and sum(g.nbytes for g in _GRIDS.values()) > _GRID_CACHE_BYTES:
        _GRIDS.popitem(last=False)
    return grid


def _candidates(
    o: torch.Tensor, d: torch.Tensor, centre: torch.Tensor, radius: torch.Tensor,
    max_dist: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Broad phase: every ray/triangle pair ``(ray (P,), triangle (P,))`` whose bounding
    sphere ``(centre (M, 3), radius (M,))`` comes within reach of the ray segment
    (:func:`_near_segment`), for any number ``M`` of triangles (all posed frames at once),
    ordered by triangle, then by the rays' order in the triangle's grid cell.

    A triangle is looked up in the grid cell of its centre ``c``: when its sphere comes
    within ``r`` of a segment, the cell's centre ``g`` is within ``r + |c - g|`` of it, so
    the cell's rays within that distance (rounded up to whole millimetres, never beyond the
    grid's reach) are all the rays the triangle can reach. The grid is asked for the
    reach of the worst case ``|c - g| = h sqrt(3) / 2``, so one grid serves a whole hand;
    each triangle then reads only the rays its own offset needs (~40 % fewer pairs than
    the worst case). A cell whose nearest ray is beyond that is skipped without a search."""
    centre_all, radius_all = centre, radius
    # A finite radius needs finite corners minus a finite centre, so it alone decides.
    finite = torch.isfinite(radius)
    if bool(finite.all()):
        tri = None  # the common case: no copy of the triangles
    else:
        tri = torch.nonzero(finite)[:, 0]
        if len(tri) == 0:
            return tri, tri
        centre, radius = centre[tri], radius[tri]
    on = o.numpy(), d.numpy()
    slack = _SPHERE_MARGIN + _grid_cell(*on, max_dist) * 3**0.5 / 2 + _GRID_SLACK
    # ceil is monotone: the largest triangle's reach is the largest of the reaches
    grid = _ray_grid(*on, max_dist, int(torch.ceil((radius.max() + slack) / 1e-3)))
    u = (centre - grid.lo) / grid.cell  # (M, 3) position in cells
    idx = torch.floor(u)
    inside = ((idx >= 0) & (idx < torch.tensor(grid.dims))).all(1)
    sel = None if bool(inside.all()) else torch.nonzero(inside)[:, 0]
    if sel is not None:
        u, radius, idx = u[sel], radius[sel], idx[sel]
        tri = sel if tri is None else tri[sel]
    # |c - g| (m); its rounding (~1e-16 m) is far inside _GRID_SLACK
    off = (u - idx).sub_(0.5).norm(dim=-1).mul_(grid.cell)
    mm = torch.ceil((radius + off + (_SPHERE_MARGIN + _GRID_SLACK)) / 1e-3).long()
    mm = mm.clamp_(max=grid.reach_mm)
    idx = idx.long()
    lin = (idx[:, 0] * grid.dims[1] + idx[:, 1]) * grid.dims[2] + idx[:, 2]
    busy = torch.nonzero(grid.near[lin] <= mm)[:, 0]  # cells with a ray within reach
    lin, mm = lin[busy], mm[busy]
    tri = busy if tri is None else tri[busy]
    first = grid.start[lin]
    count = torch.searchsorted(grid.key, lin * (grid.reach_mm + 1) + mm, right=True) - first
    tri = torch.repeat_interleave(tri, count)
    offset = torch.repeat_interleave(first - (torch.cumsum(count, 0) - count), count)
    ray = grid.rays[offset + torch.arange(len(tri))]
    planes = (x.T.contiguous() for x in (o, d, centre_all))
    keep = _near_segment(*planes, radius_all, ray, tri, max_dist)
    return ray[keep], tri[keep]


def _moller_trumbore(
    o: torch.Tensor, d: torch.Tensor, v0: torch.Tensor, e1: torch.Tensor, e2: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Exact (float64) ray-triangle test on pairs ``(P, 3)`` -> t, u, v ``(P,)`` and a hit mask."""
    p = torch.linalg.cross(d, e2, dim=-1)
    det = (e1 * p).sum(-1)
    ok = det.abs() > 1e-15
    inv = 1.0 / torch.where(ok, det, torch.ones_like(det))
    s = o - v0
    u = (s * p).sum(-1) * inv
    q = torch.linalg.cross(s, e1, dim=-1)
    v = (d * q).sum(-1) * inv
    t = (e2 * q).sum(-1) * inv
    ok &= (u >= -_BARY_TOL) & (v >= -_BARY_TOL) & (u + v <= 1 + _BARY_TOL)
    return t, u, v, ok


def _nearest_per_ray(
    rows: np.ndarray, key: np.ndarray, n: int, tie: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """Index into the pairs of each ray's smallest finite ``key`` ``(n,)``; -1 for rays
    with none. Exact ties go to the smallest ``tie(pairs)`` (asked only when there are)."""
    best = np.full(n, -1)
    if len(rows):
        order = np.lexsort((key, rows))
        first = np.r_[True, rows[order][1:] != rows[order][:-1]]
        tied = ~first[1:] & first[:-1] & (key[order][1:] == key[order][:-1])
        tied &= np.isfinite(key[order][:-1])
        if tied.any():
            order = np.lexsort((tie(np.isin(rows, rows[order][:-1][tied])), key, rows))
        best[rows[order][first]] = order[first]
    return best


def ray_mesh_hits(
    origins: np.ndarray,
    directions: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    max_dist: float = TOCH_MAX_DIST,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The correspondence rule of this module for rays against one closed mesh.

    origins, directions (N, 3) (unit directions); vertices (V, 3); faces (F, 3).
    Returns ``t (N,)`` signed ray parameter (nan = no hit within ``max_dist``), ``face (N,)``
    (-1 = no hit), ``bary (N, 3)`` barycentric weights of the hit on that face; numpy.
    One pose of :func:`ray_mesh_hits_batch`.
    """
    t, face, bary = ray_mesh_hits_batch(
        origins, directions, np.asarray(vertices, np.float64)[None], faces, max_dist
    )
    return t[0], face[0], bary[0]


def ray_mesh_hits_batch(
    origins: np.ndarray,
    directions: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    max_dist: float = TOCH_MAX_DIST,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`ray_mesh_hits` of the same rays against ``B`` poses of one closed mesh.

    origins, directions (N, 3) (unit directions); vertices (B, V, 3); faces (F, 3).
    Returns ``t (B, N)``, ``face (B, N)``, ``bary (B, N, 3)`` as :func:`ray_mesh_hits`.

    Only crossings with ``|t| <= max_dist`` are looked at: the nearest of them tells
    whether the origin is inside (leaving forwards, or entering when seen from behind),
    which for a closed mesh agrees with the parity of all crossings. Broad phase: each
    triangle's bounding sphere against the rays listed in the cell of a grid fixed to the
    rays (built once per ray set, :func:`_ray_grid`), all poses in one pass; then exact
    float64 Möller-Trumbore on the pairs whose sphere reaches the segment.
    """
    o = torch.as_tensor(np.array(origins, np.float64))
    d = torch.as_tensor(np.array(directions, np.float64))
    vt = torch.as_tensor(np.array(vertices, np.float64))
    f = torch.as_tensor(np.array(faces, np.int64))
    if vt.ndim != 3 or vt.shape[-1] != 3 or o.shape != d.shape or o.ndim != 2:
        raise InputError(
            f"vertices {tuple(vt.shape)} must be (B, V, 3), origins {tuple(o.shape)} and "
            f"directions {tuple(d.shape)} (N, 3)",
            where="ray_mesh_hits_batch",
        )
    nb, n, nf = vt.shape[0], len(o), len(f)
    # (B*F, 3) corners; index_select copies the rows as indexing does, ~2x faster
    v0, v1, v2 = (vt.index_select(1, f[:, k].contiguous()).reshape(-1, 3) for k in range(3))
    centre = (v0 + v1 + v2) / 3
    radius = torch.maximum((v0 - centre).norm(dim=-1), (v1 - centre).norm(dim=-1))
    radius = torch.maximum(radius, (v2 - centre).norm(dim=-1))  # (B*F,)
    ray, tri = _candidates(o, d, centre, radius, max_dist)
    a = v0[tri]  # edges of the candidate pairs only (the same values as of all, indexed)
    e1, e2 = v1[tri] - a, v2[tri] - a
    t, u, v, ok = _moller_trumbore(o[ray], d[ray], a, e1, e2)
    ok &= t.abs() <= max_dist
    # Faces are wound outwards, so d . (e1 x e2) > 0 means the ray leaves the hand there.
    leaving = (d[ray] * torch.linalg.cross(e1, e2, dim=-1)).sum(-1) > 0
    ray, tri, t, u, v, leaving = (x[ok].numpy() for x in (ray, tri, t, u, v, leaving))
    if len(t) == 0:
        return np.full((nb, n), np.nan), np.full((nb, n), -1), np.zeros((nb, n, 3))
    pose, cand = tri // nf, tri % nf
    rows = pose * n + ray  # one row per (pose, ray)

    def morton_rank(among: np.ndarray) -> np.ndarray:
        """Position of each pair's triangle in its pose's Z-order (0 outside ``among``)."""
        rank = np.zeros(len(rows), np.int64)
        for k in np.unique(pose[among]):
            pos = np.empty(nf, np.int64)
            pos[_morton_order(centre[k * nf : (k + 1) * nf]).numpy()] = np.arange(nf)
            sel = among & (pose == k)
            rank[sel] = pos[cand[sel]]
        return rank

    fwd = _nearest_per_ray(rows, np.where(t >= 0, t, np.inf), nb * n, morton_rank)
    back = _nearest_per_ray(rows, np.where(t < 0, -t, np.inf), nb * n, morton_rank)
    fwd = np.where((fwd >= 0) & (t[fwd] >= 0), fwd, -1)  # a ray with only backward pairs
    back = np.where((back >= 0) & (t[back] < 0), back, -1)
    has_f, has_b = fwd >= 0, back >= 0
    nearest_is_fwd = has_f & (~has_b | (t[fwd] <= -t[back]))
    inside = np.where(nearest_is_fwd, leaving[fwd], has_b & ~leaving[back])
    pick = np.where(inside, back, fwd)
    hit = pick >= 0
    pk = np.where(hit, pick, 0)
    t_out = np.where(hit, t[pk], np.nan)
    face_out = np.where(hit, cand[pk], -1)
    uu, vv = (np.where(hit, x[pk], 0.0) for x in (u, v))
    bary = np.where(hit[:, None], np.stack([1 - uu - vv, uu, vv], 1), 0.0)
    return t_out.reshape(nb, n), face_out.reshape(nb, n), bary.reshape(nb, n, 3)


@dataclass
class CorrespondenceField:
    """Per object sample: ``hit (N,)`` bool, ``distance (N,)`` signed (m, 0 on a miss),
    ``canonical (N, 3)`` point on the canonical hand (m, 0 on a miss), ``face (N,)``
    hand triangle (-1 on a miss), ``bary (N, 3)`` barycentric weights on it."""

    hit: np.ndarray
    distance: np.ndarray
    canonical: np.ndarray
    face: np.ndarray
    bary: np.ndarray

    def as_array(self) -> np.ndarray:
        """``(N, 5)``: hit, distance, canonical xyz, the layout :class:`TemporalAE` uses
        (``(B, N, 5)`` for the fields of :func:`correspondence_fields`)."""
        return np.concatenate(
            [self.hit[..., None].astype(np.float64), self.distance[..., None], self.canonical],
            -1,
        )


def correspondence_field(
    obj_points: np.ndarray,
    obj_normals: np.ndarray,
    hand_vertices: np.ndarray,
    hand_faces: np.ndarray,
    canonical_hand_vertices: np.ndarray,
    max_dist: float = TOCH_MAX_DIST,
) -> CorrespondenceField:
    """TOCH correspondence field of one frame (rule in the module docstring).

    obj_points, obj_normals (N, 3): object surface samples and unit outward normals;
    hand_vertices (V, 3): the posed hand in the same frame; hand_faces (F, 3);
    canonical_hand_vertices (V, 3): the same hand in its canonical pose. Metres.
    """
    if np.ndim(hand_vertices) != 2:
        raise InputError(
            f"hand vertices {np.shape(hand_vertices)} must be (V, 3)", where="correspondence_field"
        )
    field = correspondence_fields(
        obj_points, obj_normals, np.asarray(hand_vertices)[None], hand_faces,
        canonical_hand_vertices, max_dist,
    )
    return CorrespondenceField(**{k: v[0] for k, v in vars(field).items()})


def correspondence_fields(
    obj_points: np.ndarray,
    obj_normals: np.ndarray,
    hand_vertices: np.ndarray,
    hand_faces: np.ndarray,
    canonical_hand_vertices: np.ndarray,
    max_dist: float = TOCH_MAX_DIST,
) -> CorrespondenceField:
    """:func:`correspondence_field` of ``B`` frames of one hand against the same object
    samples (one broad phase for all of them): hand_vertices (B, V, 3); the other inputs
    as there. Returns a :class:`CorrespondenceField` whose arrays have a leading ``B``
    (``as_array`` -> ``(B, N, 5)``)."""
    pts = np.asarray(obj_points, np.float64)
    nrm = np.asarray(obj_normals, np.float64)
    canon = np.asarray(canonical_hand_vertices, np.float64)
    faces = np.asarray(hand_faces, np.int64)
    posed = np.asarray(hand_vertices, np.float64)
    if pts.shape != nrm.shape or pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(
            f"points {pts.shape} and normals {nrm.shape} must both be (N, 3)",
            where="correspondence_field",
        )
    if posed.ndim != 3 or canon.shape != posed.shape[1:]:
        raise InputError(
            f"canonical {canon.shape} vs posed {posed.shape} (B frames of it)",
            where="correspondence_field",
        )
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    t, face, bary = ray_mesh_hits_batch(pts, nrm, posed, faces, max_dist)
    hit = face >= 0
    tri = canon[faces[np.where(hit, face, 0)]]  # (B, N, 3, 3)
    canonical = np.where(hit[..., None], np.einsum("bnk,bnkc->bnc", bary, tri), 0.0)
    return CorrespondenceField(hit, np.where(hit, t, 0.0), canonical, face, bary)


# ----------------------------------------------------------------------------- TemporalAE


@dataclass
class TemporalAEConfig:
    field_dim: int = FIELD_DIM
    local_dim: int = 64  # per-point geometry feature (position, normal)
    frame_dim: int = 256  # max-pooled per-frame code
    gru_hidden: int = 256  # per direction
    gru_layers: int = 1
    window: int = TOCH_WINDOW  # frames per window the model is trained on
    # Lengths are divided by this (m) inside the network so features are O(1).
    length_scale: float = TOCH_MAX_DIST
    # > 0: a per-point skip path of this width. Each point's own noisy field over time
    # goes through two temporal convolutions (kernel ``skip_kernel``) into the decoder,
    # and the distance / correspondence outputs are residuals on the noisy values. 0: the
    # noisy field reaches the decoder only through the pooled per-frame code (the first
    # design; it must rebuild every point's field from a frame_dim-sized code, which a
    # CPU-trained model does not learn: its fields came out worse than the noisy input).
    skip_dim: int = 0
    skip_kernel: int = 5
    decoder_hidden: int = 256  # per-point decoder: hidden widths decoder_hidden, half of it

    def __post_init__(self) -> None:
        check_config(self, may_be_zero=("skip_dim",))
        if self.field_dim != FIELD_DIM:
            raise ValueError(f"TemporalAEConfig.field_dim must be {FIELD_DIM}")

    def build(self) -> TemporalAE:
        return TemporalAE(self)


def _mlp(*dims: int) -> nn.Sequential:
    """Shared per-point MLP: Linear-ReLU between layers, plain Linear at the end."""
    layers = []
    for a, b in zip(dims[:-1], dims[1:], strict=True):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*layers[:-1])


class TemporalAE(nn.Module):
    """Denoising autoencoder of correspondence fields over a window of frames.

    Encoder: a PointNet per frame (shared MLP over each point's position, normal and
    field, then max-pool) -> a bidirectional GRU over the frames. Decoder: per point, the
    frame's temporal code plus a feature of the point's *geometry only* -> clean field.
    With ``cfg.skip_dim = 0`` the noisy field reaches the decoder only through the pooled,
    temporally mixed code. With ``skip_dim > 0`` the decoder also sees each point's own
    field smoothed over time (two temporal convolutions per point), and the distance and
    correspondence it outputs are corrections of the noisy ones: the pooled code says
    where the hand is as a whole, the skip path keeps the per-point detail.
    """

    def __init__(self, cfg: TemporalAEConfig) -> None:
        super().__init__()
        self.cfg = cfg
        geo = 6  # position, normal
        self.geometry = _mlp(geo, cfg.local_dim, cfg.local_dim)
        self.point_enc = _mlp(geo + cfg.field_dim, 64, 128, cfg.frame_dim)
        self.gru = nn.GRU(
            cfg.frame_dim,
            cfg.gru_hidden,
            num_layers=cfg.gru_layers,
            batch_first=True,
            bidirectional=True,
        )
        skip = cfg.skip_dim
        if skip:
            k, pad = cfg.skip_kernel, cfg.skip_kernel // 2
            self.skip = nn.Sequential(
                nn.Conv1d(cfg.field_dim, skip, k, padding=pad, padding_mode="replicate"),
                nn.ReLU(),
                nn.Conv1d(skip, skip, k, padding=pad, padding_mode="replicate"),
                nn.ReLU(),
            )
        self.decoder = _mlp(
            cfg.local_dim + 2 * cfg.gru_hidden + skip,
            cfg.decoder_hidden,
            max(cfg.decoder_hidden // 2, 1),
            cfg.field_dim,
        )

    def _scale_field(self, field: torch.Tensor, inverse: bool = False) -> torch.Tensor:
        k = self.cfg.length_scale if inverse else 1.0 / self.cfg.length_scale
        return torch.cat([field[..., :1], field[..., 1:] * k], -1)

    def forward(
        self, points: torch.Tensor, normals: torch.Tensor, field: torch.Tensor
    ) -> torch.Tensor:
        """points, normals (B, T, N, 3) object frame; field (B, T, N, 5) = hit in {0, 1},
        distance (m), canonical point (m). Returns (B, T, N, 5): hit *logit*, distance (m),
        canonical point (m). T is free (train on ``cfg.window``)."""
        check_shape(points, (None, None, None, 3), "TemporalAE points")
        b, t, n, _ = points.shape
        check_shape(normals, (b, t, n, 3), "TemporalAE normals")
        check_shape(field, (b, t, n, FIELD_DIM), "TemporalAE field")
        geo = torch.cat([points / self.cfg.length_scale, normals], -1)  # (B, T, N, 6)
        h = self.point_enc(torch.cat([geo, self._scale_field(field)], -1))  # (B, T, N, frame_dim)
        frame = h.amax(dim=2)  # (B, T, frame_dim)
        temporal, _ = self.gru(frame)  # (B, T, 2*gru_hidden)
        local = self.geometry(geo)  # (B, T, N, local_dim)
        parts = [local, temporal[:, :, None].expand(-1, -1, n, -1)]
        if not self.cfg.skip_dim:
            return self._scale_field(self.decoder(torch.cat(parts, -1)), inverse=True)
        scaled = self._scale_field(field)  # (B, T, N, 5)
        per_point = scaled.permute(0, 2, 3, 1).reshape(b * n, FIELD_DIM, t)  # time last
        skip = self.skip(per_point).reshape(b, n, -1, t).permute(0, 3, 1, 2)  # (B, T, N, skip)
        out = self.decoder(torch.cat([*parts, skip], -1))
        # Residual on the noisy distance and correspondence; the hit logit is absolute.
        out = torch.cat([out[..., :1], out[..., 1:] + scaled[..., 1:]], -1)
        return self._scale_field(out, inverse=True)  # (B, T, N, 5)


def hit_pos_weight(hits: torch.Tensor | np.ndarray, max_weight: float = 50.0) -> float:
    """BCE weight of the positive (hit) class: ``#misses / #hits`` of target fields
    ``(..., N)`` in {0, 1}, at most ``max_weight`` (1 when there is no hit).

    Only a small share of object points are touched by the hand (~5-10 % of the
    samples in a SynthGRAB interaction window), so an unweighted BCE is minimised early
    by "nothing is touched": every probability stays below 0.5 and the fit has nothing
    to fit. Weighting the hits by the class ratio balances the two classes, so the 0.5
    threshold separates them.
    """
    h = torch.as_tensor(hits, dtype=torch.float64)
    n_hit = float(h.sum())
    if n_hit == 0:
        return 1.0
    return float(min((h.numel() - n_hit) / n_hit, max_weight))


def field_losses(
    pred: torch.Tensor,
    target: torch.Tensor,
    w_hit: float = 1.0,
    w_dist: float = 1.0,
    w_corr: float = 1.0,
    pos_weight: float = 1.0,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """TemporalAE loss: BCE on hits, L1 on distance and canonical point where the target hits.

    pred (..., 5) with hit logits; target (..., 5) with hits in {0, 1}; lengths in metres,
    read in cm (x100) so they weigh like the BCE. ``pos_weight`` weighs the hit class in
    the BCE (see :func:`hit_pos_weight`). Returns ``(total, {term: value})``.
    """
    hit = target[..., 0]
    mask = hit > 0.5
    denom = mask.sum().clamp(min=1)
    terms = {
        "hit": nn.functional.binary_cross_entropy_with_logits(
            pred[..., 0], hit, pos_weight=pred.new_tensor(float(pos_weight))
        ),
        "distance": 100.0 * ((pred[..., 1] - target[..., 1]).abs() * mask).sum() / denom,
        "correspondence": 100.0
        * ((pred[..., 2:] - target[..., 2:]).norm(dim=-1) * mask).sum()
        / denom,
    }
    total = w_hit * terms["hit"] + w_dist * terms["distance"] + w_corr * terms["correspondence"]
    return total, terms


# ----------------------------------------------------------------------------- fitting

HandForward = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
# (global_orient (T, 3), hand_pose (T, 15, 3), transl (T, 3)) -> vertices (T, V, 3)


@dataclass
class FitConfig:
    n_iters: int = 150
    lr_pose: float = 1e-2  # rad per Adam step at the start (decays to 0, cosine)
    lr_transl: float = 2e-3  # m per Adam step at the start
    fit_orient: bool = True
    w_data: float = 1.0  # squared correspondence error, in cm^2
    w_smooth: float = 1.0  # squared acceleration of pose (rad) and translation (cm)
    w_prior: float = 1e-2  # squared deviation of the pose from the input (rad^2)
    length_unit: float = 0.01  # m; lengths in the loss are read in this unit (cm)


@dataclass
class FitResult:
    global_orient: torch.Tensor  # (T, 3)
    hand_pose: torch.Tensor  # (T, 15, 3)
    transl: torch.Tensor  # (T, 3)
    losses: list[float]  # total loss per iteration


def _surface_anchors(
    canonical_points: np.ndarray, canonical_vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Project canonical correspondences onto the canonical hand: face ``(M,)``, bary ``(M, 3)``."""
    v = np.ascontiguousarray(canonical_vertices, np.float64)
    f = np.ascontiguousarray(faces, np.int64)
    p = np.ascontiguousarray(canonical_points, np.float64)
    _, face, closest = igl.point_mesh_squared_distance(p, v, f)
    bary = igl.barycentric_coordinates(
        closest, *(np.ascontiguousarray(v[f[face, k]]) for k in range(3))
    )
    return face, np.asarray(bary)


def _accel(x: torch.Tensor) -> torch.Tensor:
    """Mean squared second difference over the frame axis 0 (0 for fewer than 3 frames)."""
    if x.shape[0] < 3:
        return x.new_zeros(())
    return (x[2:] - 2 * x[1:-1] + x[:-2]).pow(2).sum(tuple(range(1, x.ndim))).mean()


def fit_hand_to_field(
    obj_points: np.ndarray,
    obj_normals: np.ndarray,
    hit: np.ndarray,
    distance: np.ndarray,
    canonical: np.ndarray,
    hand_forward: HandForward,
    canonical_vertices: np.ndarray,
    hand_faces: np.ndarray,
    init_global_orient: torch.Tensor,
    init_hand_pose: torch.Tensor,
    init_transl: torch.Tensor,
    cfg: FitConfig | None = None,
    subset_forward: Callable[[np.ndarray], HandForward] | None = None,
) -> FitResult:
    """Fit per-frame hand parameters to a correspondence field (TOCH's last stage).

    obj_points, obj_normals (T, N, 3) in the frame the hand is posed in; hit (T, N) bool;
    distance (T, N) (m); canonical (T, N, 3) canonical hand points (m). The hand point at
    each canonical correspondence, posed, should land at ``p + distance * n``. Plus a
    smoothness term on pose/translation accelerations and a prior keeping the pose near
    the input. init_* (T, 3), (T, 15, 3), (T, 3) axis-angle / metres. Adam, ``n_iters``.
    ``subset_forward(ids)``, if given, returns a ``hand_forward`` that poses only the
    vertices ``ids (K,)`` (``(T, K, 3)``); the fit then skins just the corners of the
    triangles it anchors to instead of the whole hand at every step. The fit runs on the
    device of the ``init_*`` tensors (``hand_forward`` must pose the hand there).
    """
    cfg = cfg or FitConfig()
    hit = np.asarray(hit, bool)
    t_idx, p_idx = np.nonzero(hit)
    if len(t_idx) == 0:
        raise InputError("the field has no hits: nothing to fit", where="fit_hand_to_field")
    dtype, dev = init_hand_pose.dtype, init_hand_pose.device
    target = (
        np.asarray(obj_points)[t_idx, p_idx]
        + np.asarray(distance)[t_idx, p_idx, None] * np.asarray(obj_normals)[t_idx, p_idx]
    )
    face, bary = _surface_anchors(
        np.asarray(canonical)[t_idx, p_idx], canonical_vertices, hand_faces
    )
    corners = np.asarray(hand_faces, np.int64)[face]  # (M, 3) hand vertex ids
    if subset_forward is not None:
        needed, corners = np.unique(corners, return_inverse=True)
        hand_forward = subset_forward(needed)
        corners = corners.reshape(-1, 3)  # (M, 3) rows of the posed subset
    corners = torch.as_tensor(corners, device=dev)
    bary_t = torch.as_tensor(bary, dtype=dtype, device=dev)
    target_t = torch.as_tensor(target, dtype=dtype, device=dev)
    frames = torch.as_tensor(t_idx, device=dev)

    orient = init_global_orient.detach().clone().requires_grad_(cfg.fit_orient)
    pose = init_hand_pose.detach().clone().requires_grad_(True)
    transl = init_transl.detach().clone().requires_grad_(True)
    groups = [{"params": [pose], "lr": cfg.lr_pose}, {"params": [transl], "lr": cfg.lr_transl}]
    if cfg.fit_orient:
        groups.append({"params": [orient], "lr": cfg.lr_pose})
    opt = torch.optim.Adam(groups)
    # Cosine decay to zero: Adam's steps stay ~lr in size, so the decay is what lets the
    # fit settle to sub-millimetre precision within a fixed budget.
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.n_iters)
    unit = cfg.length_unit
    history = []
    for _ in range(cfg.n_iters):
        opt.zero_grad()
        verts = hand_forward(orient, pose, transl)  # (T, V, 3)
        posed = (verts[frames[:, None], corners] * bary_t[..., None]).sum(1)  # (M, 3)
        data = ((posed - target_t) / unit).pow(2).sum(-1).mean()
        smooth = _accel(pose) + _accel(orient) + _accel(transl / unit)
        prior = (pose - init_hand_pose).pow(2).sum((1, 2)).mean() + (
            orient - init_global_orient
        ).pow(2).sum(-1).mean()
        loss = cfg.w_data * data + cfg.w_smooth * smooth + cfg.w_prior * prior
        loss.backward()
        opt.step()
        sched.step()
        history.append(loss.detach())  # no device sync per step; read once at the end
    losses = torch.stack(history).tolist() if history else []
    return FitResult(orient.detach(), pose.detach(), transl.detach(), losses)
