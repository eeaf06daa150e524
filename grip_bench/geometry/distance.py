"""Signed distance to an object: a precomputed grid with an exact (libigl) fallback.

Distances are in metres, negative inside, for points in the object's own frame.
The grid holds exact values at every node within ``SDF_EXACT_DEPTH`` (+ one cell
diagonal) of the surface, and coarse-grid values further out. Queries use
trilinear interpolation, except

* points outside the grid, and
* points in cells where trilinear interpolation is unreliable: the corner
  gradients disagree (a thin wall, a sharp edge, the medial axis inside the
  object), so the SDF has a kink or strong curvature inside the cell,

which go to the exact path (AABB tree built once, sign by angle-weighted
pseudonormals, robust on watertight meshes).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import igl
import numpy as np
import torch
import torch.nn.functional as F
import trimesh

from grip_bench.core import constants

if TYPE_CHECKING:  # numba costs ~0.3 s to import: loaded on the first grid read
    from .gridread import GridStack

__all__ = ["DistanceField", "grid_signed_distance_many"]

_CHUNK = 1 << 18  # points per query chunk: bounds the temporaries of huge batched calls
_BOX_MARGIN = 1e-3  # m; exact queries this far outside the mesh's bounding box skip the sign test
# nodes per slab of the grid build (_grid_arrays): its float64 temporaries, ~0.3 kB a node at
# most, scale with a slab rather than the grid (a memory budget, not a protocol constant)
_SLAB_NODES = 1 << 19
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def _to_numpy(points: np.ndarray | torch.Tensor) -> tuple[np.ndarray, tuple[int, ...], callable]:
    """Flatten ``(..., 3)`` numpy / torch points to float64 ``(N, 3)``, plus a converter back."""
    if isinstance(points, torch.Tensor):
        dtype, device = points.dtype, points.device
        p = points.detach().cpu().numpy()

        def back(x: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(x)).to(device=device, dtype=dtype)

    else:
        p = np.asarray(points)
        dtype = p.dtype if p.dtype in (np.float32, np.float64) else np.float64

        def back(x: np.ndarray) -> np.ndarray:
            return np.ascontiguousarray(x, dtype=dtype)

    if p.shape[-1:] != (3,):
        raise ValueError(f"points: expected shape (..., 3), got {tuple(p.shape)}")
    lead = p.shape[:-1]
    return np.ascontiguousarray(p.reshape(-1, 3), dtype=np.float64), lead, back


def _angle_weighted_normals(mesh: trimesh.Trimesh) -> np.ndarray:
    """Vertex pseudonormals ``(V, 3)``: face normals summed with incident angle weights."""
    normals = np.zeros((len(mesh.vertices), 3))
    weighted = mesh.face_angles[:, :, None] * mesh.face_normals[:, None, :]
    np.add.at(normals, mesh.faces.ravel(), weighted.reshape(-1, 3))
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)


def _edge_normals(mesh: trimesh.Trimesh) -> np.ndarray:
    """Edge pseudonormals per face edge ``(F, 3, 3)``; edge k joins face vertices k and k+1."""
    per_edge = np.zeros((len(mesh.edges_unique), 3))
    np.add.at(per_edge, mesh.faces_unique_edges.ravel(), np.repeat(mesh.face_normals, 3, axis=0))
    return per_edge[mesh.faces_unique_edges]


class DistanceField:
    """Signed distance field of a (watertight) mesh in its own frame.

    ``spacing`` (m) is the grid cell size and ``padding`` (m) the margin around the
    mesh bounds the grid covers. All query methods take ``(..., 3)`` numpy (float32 /
    float64) or torch points and return the same array type and float dtype.
    Results are not differentiable through torch autograd; use ``gradient``.
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        spacing: float = constants.SDF_GRID_SPACING,
        padding: float = constants.SDF_GRID_PADDING,
    ):
        self.mesh = mesh
        self.spacing = float(spacing)
        self.padding = float(padding)
        self._V = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        self._F = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        self._tree = igl.AABB()
        self._tree.init(self._V, self._F)
        self._face_normals = np.asarray(mesh.face_normals, dtype=np.float64)
        self._vertex_normals = _angle_weighted_normals(mesh)
        self._edge_normals = _edge_normals(mesh)
        self._build_grid()

    # --- exact path -------------------------------------------------------------

    def _exact(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Exact signed distance ``(N,)``, closest points ``(N, 3)``, faces ``(N,)``,
        pseudonormals ``(N, 3)``."""
        if len(p) == 0:
            return np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3))
        sqd, face, closest = self._tree.squared_distance(self._V, self._F, p)
        normal = self._pseudonormal(face, closest)
        side = np.einsum("ij,ij->i", p - closest, normal)
        dist = np.where(side < 0, -1.0, 1.0) * np.sqrt(sqd)
        return dist, closest, face, normal

    def _exact_values(self, p: np.ndarray) -> np.ndarray:
        """``_exact(p)[0]`` alone: the signed distances ``(N,)``.

        Points more than ``_BOX_MARGIN`` outside the mesh's bounding box are outside the
        object, so their sign test (the pseudonormal of the closest feature, ~10% of an exact
        query) is skipped: the same values, as the test would give +1 there.
        """
        if len(p) == 0:
            return np.zeros(0)
        sqd, face, closest = self._tree.squared_distance(self._V, self._F, p)
        dist = np.sqrt(sqd)
        lo, hi = self._V.min(0) - _BOX_MARGIN, self._V.max(0) + _BOX_MARGIN
        near = np.ones(len(p), dtype=bool)
        for k in range(3):
            near &= p[:, k] >= lo[k]
            near &= p[:, k] <= hi[k]
        if near.any():
            normal = self._pseudonormal(face[near], closest[near])
            side = np.einsum("ij,ij->i", p[near] - closest[near], normal)
            dist[near] = np.where(side < 0, -1.0, 1.0) * dist[near]
        return dist

    def _pseudonormal(self, face: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Angle-weighted pseudonormal of the face, edge or vertex that holds each closest point."""
        tri = self._V[self._F[face]]  # (N, 3, 3)
        e0, e1, w = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], c - tri[:, 0]
        d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
        d20, d21 = (w * e0).sum(1), (w * e1).sum(1)
        den = np.maximum(d00 * d11 - d01 * d01, 1e-300)
        b1 = (d11 * d20 - d01 * d21) / den
        b2 = (d00 * d21 - d01 * d20) / den
        bary = np.stack([1.0 - b1 - b2, b1, b2], 1)
        on = bary < constants.SDF_BARY_TOL  # closest point lies on the edge opposite vertex k
        n_on = on.sum(1)
        normal = self._face_normals[face].copy()
        edge = n_on == 1
        k = np.argmax(on[edge], 1)
        normal[edge] = self._edge_normals[face[edge], (k + 1) % 3]
        vert = n_on >= 2
        corner = self._F[face[vert], np.argmax(bary[vert], 1)]
        normal[vert] = self._vertex_normals[corner]
        return normal

    def exact_signed_distance(
        self, points: np.ndarray | torch.Tensor
    ) -> np.ndarray | torch.Tensor:
        """Exact signed distance ``(...)`` (m, negative inside) of points ``(..., 3)``."""
        p, lead, back = _to_numpy(points)
        return back(self._exact_values(p).reshape(lead))

    def exact_contacts(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact signed distances ``(N,)`` m, closest surface points ``(N, 3)`` and the
        outward angle-weighted pseudonormals ``(N, 3)`` there (unit on faces; a sum of unit
        normals on edges and vertices, so normalise before use) of points ``(N, 3)``."""
        dist, closest, _, normal = self._exact(np.ascontiguousarray(points, np.float64))
        return dist, closest, normal

    def closest_points(
        self, points: np.ndarray | torch.Tensor
    ) -> tuple[np.ndarray | torch.Tensor, np.ndarray | torch.Tensor, np.ndarray | torch.Tensor]:
        """Closest surface points ``(..., 3)``, signed distances ``(...)`` (m), face ids ``(...)``.

        Shapes follow the input: ``(N, 3)`` points give ``(N, 3), (N,), (N,)``.
        Face ids are int64 (numpy or torch).
        """
        p, lead, back = _to_numpy(points)
        dist, closest, face, _ = self._exact(p)
        faces = face.reshape(lead)
        faces = torch.from_numpy(faces) if isinstance(points, torch.Tensor) else faces
        return back(closest.reshape(*lead, 3)), back(dist.reshape(lead)), faces

    # --- grid -----------------------------------------------------------------------

    def _node_coords(
        self, shape: tuple[int, ...], origin: np.ndarray, spacing: float
    ) -> np.ndarray:
        axes = [origin[a] + spacing * np.arange(shape[a]) for a in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)

    def _build_grid(self) -> None:
        """The grid of ``_grid_arrays``, read from the geometry cache when it holds it.

        The cache keeps the grid_sample layouts themselves: ``sdf_grid`` (values and the
        unreliable-cell flags) and ``sdf_grad`` (node gradients, 70% of the bytes, written and
        read only once ``gradient`` is used: the sensors and the evaluation never need them).
        """
        from .cache import load_arrays, mesh_key, package_version, save_arrays

        params = {"spacing": self.spacing, "padding": self.padding,
                  "exact_depth": constants.SDF_EXACT_DEPTH, "coarse": constants.SDF_COARSE_FACTOR,
                  "kink": constants.SDF_KINK_TOL, "bary": constants.SDF_BARY_TOL,
                  "igl": package_version("libigl")}
        self._grid_key = mesh_key("sdf_grid", self._V, self._F, params)
        self._gvol_data, self._gvol_saved = None, True
        a = load_arrays("sdf_grid", self._grid_key, ("origin", "shape", "vol", "unreliable"),
                        _grid_entry_ok)
        if a is None:
            built = self._grid_arrays()
            shape = tuple(int(x) for x in built["shape"])
            a = {"origin": built["origin"], "shape": built["shape"],
                 "vol": _vol_layout(built["values"], shape), "unreliable": built["unreliable"]}
            save_arrays("sdf_grid", self._grid_key, a)
            self._gvol_data = torch.from_numpy(_gvol_layout(built["grad"], shape))[None]
            self._gvol_saved = False
        self.origin, self.shape = a["origin"], tuple(int(x) for x in a["shape"])
        self._unreliable = a["unreliable"]
        self._to_torch_volumes(a["vol"], self._unreliable)

    @property
    def _gvol(self) -> torch.Tensor:
        """Node gradients ``(1, 3, z, y, x)`` for grid_sample, loaded (or rebuilt) on first use."""
        from .cache import load_arrays, save_arrays

        if self._gvol_data is None:
            n = (3, *self.shape[::-1])
            g = load_arrays("sdf_grad", self._grid_key, ("gvol",), lambda a: a["gvol"].shape == n)
            if g is None:
                g = {"gvol": _gvol_layout(self._grid_arrays()["grad"], self.shape)}
                self._gvol_saved = False
            self._gvol_data = torch.from_numpy(g["gvol"])[None]
        if not self._gvol_saved:
            save_arrays("sdf_grad", self._grid_key, {"gvol": self._gvol_data[0].numpy()})
            self._gvol_saved = True
        return self._gvol_data

    def _grid_arrays(self) -> dict[str, np.ndarray]:
        """Exact values near the surface, coarse values beyond, and the unreliable-cell mask.

        Values and gradients are returned as float32, the precision the grid is sampled in:
        ``values (N,)``, ``grad (N, 3)`` (unit), ``unreliable (N,)`` bool, nodes in x-major
        order. Built in slabs of ``_SLAB_NODES`` nodes along the first axis, so the float64
        temporaries scale with a slab, not the grid; every node gets the same values as a
        whole-grid build (each step is per node, or reads whole rows with one row of overlap).
        """
        h = self.spacing
        lo = self._V.min(0) - self.padding
        n = np.ceil((self._V.max(0) + self.padding - lo) / h).astype(int) + 1
        self.origin, self.shape = lo, tuple(int(x) for x in n)
        band = constants.SDF_EXACT_DEPTH + h * math.sqrt(3.0)
        n0, n1, n2 = self.shape
        rows = max(1, _SLAB_NODES // (n1 * n2))
        x = lo[0] + h * np.arange(n0)  # each row's x, as _node_coords computes it
        coarse = self._coarse_grid()
        values = np.empty(self.shape, np.float32)
        grad = np.empty((*self.shape, 3), np.float32)
        flags = np.zeros(self.shape, dtype=bool)
        # window of built rows [w0, w0 + len): float64 values, band mask, near-node gradients;
        # a slab's gradients read one row on each side, so two rows carry over to the next slab
        win_v = np.empty((0, n1, n2))
        win_near = np.empty((0, n1, n2), dtype=bool)
        win_g = np.empty((0, n1, n2, 3))
        w0 = 0
        prev = None  # the float64 unit gradients and band mask of the row before the slab
        for i0 in range(0, n0, rows):
            i1 = min(i0 + rows, n0)
            built = w0 + len(win_v)
            if built < min(i1 + 1, n0):
                v, near, g = self._band_rows(x[built : i1 + 1], band, coarse)
                win_v = np.concatenate([win_v, v])
                win_near = np.concatenate([win_near, near])
                win_g = np.concatenate([win_g, g])
            # np.gradient over the window: the slab's rows get the whole grid's central
            # differences, and the grid's first/last rows (window ends) its one-sided ones
            far_grad = np.gradient(win_v, h)
            s = slice(i0 - w0, i1 - w0)
            g = win_g[s].reshape(-1, 3)  # a view: the slab's rows of win_g are not read again
            far = ~win_near[s].reshape(-1)
            g[far] = np.stack([d[s] for d in far_grad], -1).reshape(-1, 3)[far]
            g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
            g = g.reshape(i1 - i0, n1, n2, 3)
            values[i0:i1] = win_v[s]
            grad[i0:i1] = g
            # kink cells of rows [c0, i1 - 1): their corners lie in rows [c0, i1)
            block_g, block_near = g, win_near[s]
            if prev is not None:
                block_g = np.concatenate([prev[0], g])
                block_near = np.concatenate([prev[1], block_near])
            c0 = i1 - len(block_g)
            flags[c0 : i1 - 1, :-1, :-1] = self._kink_cells(block_g, block_near)
            prev = (g[-1:].copy(), win_near[i1 - 1 - w0 : i1 - w0].copy())
            keep = max(i1 - 1, 0) - w0  # rows before i1 - 1 are no longer read
            win_v, win_near, win_g = win_v[keep:], win_near[keep:], win_g[keep:]
            w0 += keep
        return {"origin": np.asarray(lo, np.float64), "shape": np.array(self.shape, np.int64),
                "values": values.reshape(-1), "grad": grad.reshape(-1, 3),
                "unreliable": flags.reshape(-1)}

    def _band_rows(
        self, x: np.ndarray, band: float, coarse: tuple[np.ndarray, tuple[int, int, int]]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grid rows at x-coordinates ``x (m,)`` (m): float64 values ``(m, n1, n2)`` (exact
        within ``band``, coarse-filled beyond), the within-band mask ``(m, n1, n2)`` and the
        within-band nodes' gradients ``(m, n1, n2, 3)`` (``(x - c) / d``, or the pseudonormal
        on the surface; not yet normalised; zero beyond the band)."""
        _, n1, n2 = self.shape
        h, lo = self.spacing, self.origin
        nodes = np.empty((len(x), n1, n2, 3))
        nodes[..., 0] = x[:, None, None]
        nodes[..., 1] = (lo[1] + h * np.arange(n1))[None, :, None]
        nodes[..., 2] = (lo[2] + h * np.arange(n2))[None, None, :]
        nodes = nodes.reshape(-1, 3)
        s, _, c, normal = igl.signed_distance(
            nodes, self._V, self._F,
            sign_type=igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL,
            lower_bound=-band, upper_bound=band,
        )  # fmt: skip
        near = np.isfinite(s)
        values = np.array(s, dtype=np.float64)
        far = ~near
        values[far] = self._coarse_fill(nodes[far], band, coarse)
        grad = np.zeros_like(nodes)
        off = nodes[near] - c[near]
        dn = values[near][:, None]
        # (x - c) / d is the SDF gradient; on the surface itself use the pseudonormal
        grad[near] = np.where(np.abs(dn) > 1e-9, off / np.where(dn == 0, 1.0, dn), normal[near])
        m = len(x)
        return values.reshape(m, n1, n2), near.reshape(m, n1, n2), grad.reshape(m, n1, n2, 3)

    def _coarse_grid(self) -> tuple[np.ndarray, tuple[int, int, int]]:
        """Exact values ``(Nc,)`` (x-major) of the coarse grid (``SDF_COARSE_FACTOR`` x the
        spacing, same origin) and its shape; queried in chunks of ``_CHUNK`` nodes."""
        factor = constants.SDF_COARSE_FACTOR
        shape_c = tuple(int(np.ceil((s - 1) / factor)) + 1 for s in self.shape)
        coarse_nodes = self._node_coords(shape_c, self.origin, self.spacing * factor)
        vals = np.concatenate([self._exact(coarse_nodes[i : i + _CHUNK])[0]
                               for i in range(0, len(coarse_nodes), _CHUNK)])
        return vals, shape_c

    def _coarse_fill(
        self, nodes: np.ndarray, band: float, coarse: tuple[np.ndarray, tuple[int, int, int]]
    ) -> np.ndarray:
        """Values ``(N,)`` for nodes ``(N, 3)`` beyond the exact band (|d| >= band).

        Trilinear from the exact coarse grid ``coarse`` (``_coarse_grid``).
        """
        vals, shape_c = coarse
        H = self.spacing * constants.SDF_COARSE_FACTOR
        u = (nodes - self.origin) / H
        i = np.clip(np.floor(u), 0, np.array(shape_c) - 2)
        strides = np.array([shape_c[1] * shape_c[2], shape_c[2], 1])
        base = (i * strides).sum(1).astype(np.intp)
        out = _trilinear(vals, base, u - i, _CORNERS @ strides)
        return np.where(out < 0, -1.0, 1.0) * np.maximum(np.abs(out), band)

    def _kink_cells(self, grad: np.ndarray, near: np.ndarray) -> np.ndarray:
        """Cells whose corner gradients spread too much, in a block of ``m`` grid rows.

        ``grad (m, n1, n2, 3)`` float64 unit node gradients, ``near (m, n1, n2)`` the
        within-band mask; returns the flags ``(m - 1, n1 - 1, n2 - 1)`` of the cells with
        their lowest corner in the block's rows ``0 .. m - 2``.

        A cell whose gradients differ by ``dg`` holds a trilinear error of about
        ``spacing * dg / 4``; cells where that exceeds ``SDF_KINK_TOL`` are sent to the
        exact path. Cells with a coarse-filled corner are > SDF_EXACT_DEPTH
        from the surface and keep their (approximate) grid values.
        """
        limit = 4.0 * constants.SDF_KINK_TOL / self.spacing
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
        return all_near & (spread > limit)

    def _to_torch_volumes(self, vol: np.ndarray, flags: np.ndarray) -> None:
        """grid_sample layouts: the ``(1, 1, z, y, x)`` value volume (from ``_vol_layout``) and
        the cell-flag volume, plus the coordinate transforms."""
        self._vol = torch.from_numpy(vol)[None, None]
        # 1 where the cell's trilinear value is trusted; zero padding makes outside points 0 too
        trusted = ~flags.reshape(self.shape)[:-1, :-1, :-1]
        self._trusted = torch.from_numpy(trusted.astype(np.float32).T.copy())[None, None]
        n = np.array(self.shape, dtype=np.float64)
        extent = self.spacing * (n - 1)
        self._scale = torch.tensor(2.0 / extent, dtype=torch.float32)
        self._shift = torch.tensor(-1.0 - 2.0 * self.origin / extent, dtype=torch.float32)
        # cell centres span the same box shrunk by half a cell on each side
        self._cell_scale = torch.tensor((n - 1) / (n - 2), dtype=torch.float32)

    def _grid(self, p: np.ndarray, vol: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """Interpolated channels ``(N, C)`` and exact-path mask ``(N,)`` of points ``(N, 3)``."""
        u = torch.from_numpy(p).to(torch.float32).mul_(self._scale).add_(self._shift)
        vals = F.grid_sample(vol, u.view(1, 1, 1, -1, 3), align_corners=True)
        # nearest cell centre = the cell holding the point; outside the grid reads 0
        trusted = F.grid_sample(
            self._trusted, u.mul_(self._cell_scale).view(1, 1, 1, -1, 3),
            mode="nearest", padding_mode="zeros", align_corners=True,
        )  # fmt: skip
        return vals.view(vol.shape[1], -1).T.numpy(), trusted.view(-1).numpy() < 0.5

    def interpolated(self, q: np.ndarray) -> np.ndarray:
        """The grid's trilinear values ``(N,)`` float64 at points ``(N, 3)`` inside it, without
        the exact path of unreliable cells (errors up to ~spacing / 4 across a kink): for
        features that tolerate a millimetre, at a third of ``signed_distance``'s cost."""
        return _read(self._vol, self._scale, self._shift, q)

    def signed_distance(
        self, points: np.ndarray | torch.Tensor, far: str = "exact", exact_cells: bool = True
    ) -> np.ndarray | torch.Tensor:
        """Signed distance ``(...)`` (m, negative inside) of points ``(..., 3)``.

        Grid values, with an exact fallback.

        Points beyond the fine grid (more than ``padding`` from the object) are answered by
        ``far``: ``"exact"`` (libigl, ~1 us a point); ``"bound"``, their distance to the
        object's bounding box, a lower bound of the true distance that is exact enough for
        contact tests and safe for sphere tracing; ``"coarse"``, the first of the
        ``SDF_FAR_TIERS`` grids (exact node values, built lazily and cached) that holds the
        point, exact beyond the last: ~10x cheaper than exact, sub-mm error beyond the fine
        grid (trilinear over cells at least 3 cm from the surface), for the sensor features.
        ``exact_cells=False`` (with ``"coarse"`` only) also reads the fine grid's unreliable
        cells by interpolation (errors up to ~spacing / 4 there, 3x cheaper). ``"coarse"`` runs
        compiled (``geometry.gridread``); points given in moving frames:
        :meth:`moved_signed_distance` (the same values).
        """
        if far not in ("exact", "bound", "coarse"):
            raise ValueError(f"far must be 'exact', 'bound' or 'coarse', got {far!r}")
        if not exact_cells and far != "coarse":
            raise ValueError("exact_cells=False needs far='coarse'")
        p, lead, back = _to_numpy(points)
        out = np.empty(len(p))
        for s in range(0, len(p), _CHUNK):
            q = p[s : s + _CHUNK]
            out[s : s + _CHUNK] = (self._tiered(q, exact_cells) if far == "coarse"
                                   else self._near_first(q, far))
        return back(out.reshape(lead))

    def _near_first(self, q: np.ndarray, far: str) -> np.ndarray:
        """``signed_distance`` of ``q (N, 3)`` for far ``"exact"`` or ``"bound"``."""
        d, exact = self._grid(q, self._vol)
        d = d[:, 0].astype(np.float64)
        if far == "bound" and exact.any():
            outside = self._outside_grid(q)
            d[outside] = self._box_distance(q[outside])
            exact &= ~outside
        if exact.any():
            d[exact] = self._exact_values(q[exact])
        return d

    def _tiered(self, q: np.ndarray, exact_cells: bool) -> np.ndarray:
        """``signed_distance(q, far="coarse")`` ``(N,)``: one compiled pass decides each
        point's grid and reads it (``geometry.gridread``), then the exact path answers the
        points it flagged."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        out, exact, _ = self._read_grids(q, exact_cells)
        if exact.any():
            out[exact] = self._exact_values(q[exact])
        return out

    def _read_grids(self, q: np.ndarray, exact_cells: bool
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grid values ``(N,)``, exact-path flags ``(N,)`` and levels ``(N,)`` int8 of
        float64 points ``q (N, 3)`` (``gridread.read_points``)."""
        from .gridread import read_points

        n = len(q)
        out, exact, levels = np.empty(n), np.empty(n, np.bool_), np.empty(n, np.int8)
        read_points(q, *self.grid_stack().args(), exact_cells, out, exact, levels)
        return out, exact, levels

    def moved_signed_distance(
        self, local: np.ndarray, rot: np.ndarray, transl: np.ndarray, obj_rot: np.ndarray,
        obj_transl: np.ndarray, exact_cells: bool = True,
    ) -> np.ndarray:
        """``signed_distance(sensors.hand_points_in_object(local, rot, transl, obj_rot,
        obj_transl), far="coarse", exact_cells)`` ``(T, N)`` (m) bit for bit, in one
        compiled pass: frame-local points ``local (N, 3)``, their frames ``rot (T, 3, 3)``,
        ``transl (T, 3)`` (``world = rot p + transl``), GRAB's row-vector object rotations
        ``obj_rot (T, 3, 3)`` and translations ``obj_transl (T, 3)``, all float64."""
        from .gridread import read_moved_points

        args = [np.ascontiguousarray(a, dtype=np.float64)
                for a in (local, rot, transl, obj_rot, obj_transl)]
        T, N = len(args[1]), len(args[0])
        out, exact, levels = np.empty(T * N), np.empty(T * N, np.bool_), np.empty(T * N, np.int8)
        q = np.empty((T * N, 3))
        read_moved_points(*args, *self.grid_stack().args(), exact_cells, out, exact, levels, q)
        if exact.any():
            out[exact] = self._exact_values(q[exact])
        return out.reshape(T, N)

    def grid_stack(self) -> GridStack:
        """This field's grids in the compiled reads' layout (``gridread.GridStack``), built
        once; it shares the fine grid's memory."""
        if getattr(self, "_stack", None) is None:
            from .gridread import GridStack

            tiers = self._far_tiers()
            lo, hi = self._box_arrays()
            vols = [self._vol] + [t._vol for t in tiers]
            flat = [t._vol.reshape(-1).numpy() for t in tiers]
            self._stack = GridStack(
                lo=lo, hi=hi, fine=self._vol.reshape(-1).numpy(),
                tiers=np.concatenate(flat) if flat else np.zeros(0, np.float32),
                offsets=np.cumsum([0] + [len(f) for f in flat]).astype(np.int64),
                dims=np.array([v.shape[2:] for v in vols], np.int64),
                scale=np.stack([self._scale.numpy()] + [t._scale.numpy() for t in tiers]),
                shift=np.stack([self._shift.numpy()] + [t._shift.numpy() for t in tiers]),
                trusted=self._trusted.reshape(-1).numpy(),
                tdims=np.array(self._trusted.shape[2:], np.int64),
                cell=self._cell_scale.numpy())
        return self._stack

    def _boxes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The node boxes ``(lo (3,), hi (3,))`` of the fine grid, then of each far tier: a
        point's level is the first of them that holds it (``len`` of the list: none, exact)."""
        if getattr(self, "_level_boxes", None) is None:
            fine = (self.origin, self.origin + self.spacing * (np.array(self.shape) - 1))
            self._level_boxes = [fine] + [(t.origin, t._hi) for t in self._far_tiers()]
        return self._level_boxes

    def _levels(self, q: np.ndarray) -> np.ndarray:
        """Each point's level ``(N,)`` int8: the index in ``_boxes`` of the first box that
        holds it (0: the fine grid, k: far tier k), ``len(_boxes)`` beyond all of them."""
        return self._read_grids(np.ascontiguousarray(q, dtype=np.float64), False)[2]

    def _box_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``_boxes`` as two ``(nb, 3)`` arrays of lower and upper corners."""
        if getattr(self, "_level_box_arrays", None) is None:
            boxes = self._boxes()
            self._level_box_arrays = (np.stack([b[0] for b in boxes]),
                                      np.stack([b[1] for b in boxes]))
        return self._level_box_arrays

    def _far_tiers(self) -> list[_FarGrid]:
        """The far-field grids of ``SDF_FAR_TIERS``, built on first use (~1 s per object)."""
        if getattr(self, "_far", None) is None:
            self._far = [_FarGrid.build(self, h, pad) for h, pad in constants.SDF_FAR_TIERS]
        return self._far

    def grid_signed_distance(self, points: torch.Tensor) -> torch.Tensor:
        """Differentiable signed distance ``(...)`` of torch points ``(..., 3)`` from the grid
        alone (trilinear, no exact fallback; beyond the grid the border value), float32.

        For losses: its gradient is the trilinear field's, and its values agree with
        :meth:`signed_distance` wherever that one trusts the grid.
        """
        vol, scale, shift = self._grid_on(points.device)
        u = points.to(torch.float32) * scale + shift
        v = F.grid_sample(vol, u.reshape(1, 1, 1, -1, 3), align_corners=True,
                          padding_mode="border")
        return v.reshape(points.shape[:-1])

    def _grid_on(self, device: torch.device) -> tuple[torch.Tensor, ...]:
        """The value volume and its coordinate transform on ``device``: the CPU tensors
        themselves there, elsewhere a copy made on first use and kept (a GPU loss reads
        the grid where its points are, without a transfer per batch)."""
        if device == self._vol.device:
            return self._vol, self._scale, self._shift
        copies = self.__dict__.setdefault("_device_grids", {})
        if device not in copies:
            copies[device] = tuple(t.to(device) for t in (self._vol, self._scale, self._shift))
        return copies[device]

    def within_grid(self, points: np.ndarray) -> np.ndarray:
        """Bool ``(...)``: points ``(..., 3)`` inside the fine grid's nodes. A point outside is
        more than ``padding`` from the mesh's bounding box, hence from the mesh."""
        p = np.asarray(points, np.float64)
        return ~self._outside_grid(p.reshape(-1, 3)).reshape(p.shape[:-1])

    def _outside_grid(self, q: np.ndarray) -> np.ndarray:
        """Points ``(N, 3)`` beyond the grid's nodes ``(N,)`` bool."""
        return _outside_box(q, self.origin, self.origin + self.spacing * (np.array(self.shape) - 1))

    def _box_distance(self, q: np.ndarray) -> np.ndarray:
        """Distance ``(N,)`` from points to the mesh's bounding box (an SDF lower bound outside).

        ``norm(max(lo - q, q - hi, 0), axis=1)`` computed column by column, summing the squares
        in the same order (x, y, z): the same values, 8x faster.
        """
        lo, hi = self.mesh.bounds
        total = None
        for k in range(3):
            c = np.ascontiguousarray(q[:, k])
            x = lo[k] - c
            np.maximum(x, c - hi[k], out=x)
            np.maximum(x, 0.0, out=x)
            x *= x
            if total is None:
                total = x
            else:
                total += x
        return np.sqrt(total, out=total)

    def gradient(self, points: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        """Unit SDF gradient ``(..., 3)`` (outward surface normal direction) at points ``(..., 3)``.

        Grid points interpolate node gradients; fallback points use ``(p - closest) / d``.
        """
        p, lead, back = _to_numpy(points)
        out = np.empty((len(p), 3))
        for s in range(0, len(p), _CHUNK):
            q = p[s : s + _CHUNK]
            g, exact = self._grid(q, self._gvol)
            g = g.astype(np.float64)
            if exact.any():
                d, c, _, normal = self._exact(q[exact])
                off = (q[exact] - c) / np.where(d == 0, 1.0, d)[:, None]
                g[exact] = np.where(np.abs(d)[:, None] > 1e-9, off, normal)
            g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
            out[s : s + _CHUNK] = g
        return back(out.reshape(*lead, 3))

    @property
    def unreliable_fraction(self) -> float:
        """Share of grid cells answered by the exact path (diagnostic)."""
        return float(1.0 - self._trusted.mean())


def _vol_layout(values: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """Node values ``(N,)`` (x-major) as the contiguous float32 ``(z, y, x)`` grid_sample volume."""
    return values.reshape(shape).astype(np.float32, copy=False).T.copy()


def _gvol_layout(grad: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """Node gradients ``(N, 3)`` as the contiguous float32 ``(3, z, y, x)`` grid_sample volume."""
    g = grad.reshape(*shape, 3).astype(np.float32, copy=False)  # no copy of float32 input
    return np.ascontiguousarray(g.transpose(3, 2, 1, 0))


def _grid_entry_ok(a: dict) -> bool:
    """Consistent shapes of a cached ``sdf_grid`` entry."""
    shape = tuple(int(x) for x in a["shape"])
    if len(shape) != 3 or min(shape) < 2:
        return False
    return (a["origin"].shape == (3,) and a["vol"].shape == shape[::-1]
            and a["vol"].dtype == np.float32 and a["vol"].flags.c_contiguous
            and a["unreliable"].shape == (int(np.prod(shape)),) and a["unreliable"].dtype == bool)


def _outside_box(q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Points ``(N, 3)`` outside the box ``[lo, hi]`` ``(N,)`` bool (column by column: 7x
    faster than comparing whole rows)."""
    cols = q.T
    out = cols[0] < lo[0]
    out |= cols[0] > hi[0]
    for k in (1, 2):
        out |= cols[k] < lo[k]
        out |= cols[k] > hi[k]
    return out


def _read(vol: torch.Tensor, scale: torch.Tensor, shift: torch.Tensor, q: np.ndarray) -> np.ndarray:
    """Trilinear values ``(N,)`` float64 of a ``(1, 1, z, y, x)`` volume at points ``(N, 3)``
    (``u = q * scale + shift`` in grid_sample's [-1, 1] coordinates; 0 outside)."""
    u = torch.from_numpy(np.ascontiguousarray(q)).to(torch.float32).mul_(scale).add_(shift)
    vals = F.grid_sample(vol, u.view(1, 1, 1, -1, 3), align_corners=True)
    return vals.view(-1).numpy().astype(np.float64)


def _trilinear(
    values: np.ndarray, base: np.ndarray, frac: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """Trilinear interpolation of flat node ``values`` at cells ``base (N,)``, ``frac (N, 3)``."""
    v = values[base[:, None] + offsets].astype(np.float64)  # (N, 8), corners in (i, j, k) order
    fx, fy, fz = frac[:, 0:1], frac[:, 1:2], frac[:, 2:3]
    v = v[:, :4] + fx * (v[:, 4:] - v[:, :4])  # along i
    v = v[:, :2] + fy * (v[:, 2:] - v[:, :2])  # along j
    return v[:, 0] + fz[:, 0] * (v[:, 1] - v[:, 0])  # along k


class _FarGrid:
    """A coarse exact-valued grid far around an object, for decaying far-field features."""

    def __init__(self, origin: np.ndarray, shape: tuple[int, int, int], spacing: float,
                 values: np.ndarray):
        self.origin, self.shape, self.spacing = origin, shape, spacing
        self._vol = torch.from_numpy(values.reshape(shape).astype(np.float32).T.copy())[None, None]
        extent = spacing * (np.array(shape, dtype=np.float64) - 1)
        self._hi = origin + extent
        self._scale = torch.tensor(2.0 / extent, dtype=torch.float32)
        self._shift = torch.tensor(-1.0 - 2.0 * origin / extent, dtype=torch.float32)

    @classmethod
    def build(cls, field: DistanceField, spacing: float, padding: float) -> _FarGrid:
        from .cache import cached_arrays, mesh_key, package_version

        lo = field._V.min(0) - padding
        n = np.ceil((field._V.max(0) + padding - lo) / spacing).astype(int) + 1
        shape = tuple(int(x) for x in n)

        def values() -> dict[str, np.ndarray]:
            nodes = field._node_coords(shape, lo, spacing)
            v = np.concatenate([field._exact(nodes[i : i + 65536])[0]
                                for i in range(0, len(nodes), 65536)])
            return {"values": v.astype(np.float32)}  # the precision the grid is sampled in

        params = {"spacing": float(spacing), "padding": float(padding),
                  "bary": constants.SDF_BARY_TOL, "igl": package_version("libigl")}
        key = mesh_key("sdf_far", field._V, field._F, params)
        def ok(a: dict) -> bool:
            return a["values"].shape == (int(np.prod(shape)),)

        return cls(lo, shape, spacing,
                   cached_arrays("sdf_far", key, values, names=("values",), validate=ok)["values"])


def grid_signed_distance_many(
    fields: list, which: torch.Tensor, points: torch.Tensor
) -> torch.Tensor:
    """:meth:`DistanceField.grid_signed_distance` of samples on several objects.

    fields: the objects' fields; which (B,) int: each sample's field; points (B, ..., 3) in
    that object's frame. Returns (B, ...), differentiable in the points: one grid read per
    object, the samples grouped by object and put back in batch order.
    """
    order = torch.argsort(which, stable=True)
    ids, counts = torch.unique_consecutive(which[order], return_counts=True)
    # the group sizes are needed on the host: one small read (a sync on a GPU) per call
    groups = torch.stack([ids, counts]).tolist()
    parts = [
        fields[k].grid_signed_distance(x)
        for k, x in zip(groups[0], torch.split(points[order], groups[1]), strict=True)
    ]
    return torch.cat(parts)[torch.argsort(order)]
