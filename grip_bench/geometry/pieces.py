"""Convex pieces of a closed surface with a measured bound on how far they stick out.

MuJoCo collides every mesh geom as its convex hull, so a hand or an object enters the
simulation as convex pieces. Pieces that overfill the true shape start contacts deep inside
the other body and push it away at t = 0 (measured with CoACD pieces: up to 2.7 mm out,
about five times the object's weight sideways). These pieces are built so that their
**outward error**, the largest signed distance of a piece's hull surface from the true
surface, is measured and at most ``max_error``:

- the faces are cut into small compact patches (recursive median splits of the face
  centroids along their widest axis; a ``labels`` array keeps patches within one label,
  e.g. one hand bone), and each patch becomes the hull of its own vertices plus the same
  vertices moved ``depth`` inward along their normals: a thin prism under the surface;
- each hull is sampled (its vertices, face centroids and edge midpoints) and the samples'
  exact signed distances to the mesh give its outward error; a patch whose surface alone
  (at the smallest depth) is too concave is split in two, a patch whose inner layer pokes
  through a thin wall gets half the depth, until the bound holds;
- a mesh whose own hull is within the bound is one piece (a cube, a sphere, a can).

So a concave shape stays concave: a ball in a bowl rests on the bowl's inner prisms
instead of inside the bowl's hull. Deterministic: no random initialisation anywhere.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass

import numpy as np

from ..core import constants as C


@dataclass(frozen=True)
class SurfacePieces:
    """Pieces of one surface: per piece the patch's vertex ids, inner-layer depth and the
    measured outward error. ``depth`` NaN marks the whole-hull piece (no inner layer)."""

    vertex_ids: tuple[np.ndarray, ...]
    depth: np.ndarray
    error: np.ndarray

    def __len__(self) -> int:
        return len(self.vertex_ids)

    def points(self, vertices: np.ndarray, normals: np.ndarray) -> list[np.ndarray]:
        """Each piece's hull points (n_i, 3) for a (possibly re-posed) surface.

        vertices, normals: (V, 3), the same vertex order the pieces were built on.
        """
        if not len(self):
            return []
        ids, ends = self._flat
        v = np.asarray(vertices, dtype=np.float64)[ids]
        inner = v - np.repeat(self.depth, np.diff(ends, prepend=0))[:, None] * np.asarray(
            normals, dtype=np.float64)[ids]  # one gather: a call per piece cost ~5 us each
        out, start = [], 0
        for end, d in zip(ends, self.depth, strict=True):
            out.append(np.concatenate([v[start:end], inner[start:end]]) if np.isfinite(d)
                       else v[start:end].copy())
            start = end
        return out

    @functools.cached_property
    def _flat(self) -> tuple[np.ndarray, np.ndarray]:
        """All pieces' vertex ids end to end (N,) and each piece's end offset (P,)."""
        return (np.concatenate(self.vertex_ids).astype(np.int64),
                np.cumsum([len(i) for i in self.vertex_ids]))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat arrays for the on-disk geometry cache (inverse: :meth:`from_arrays`)."""
        sizes = np.array([len(i) for i in self.vertex_ids], np.int64)
        return {"ids": np.concatenate(self.vertex_ids).astype(np.int64), "sizes": sizes,
                "depth": self.depth.astype(np.float64), "error": self.error.astype(np.float64)}

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray]) -> SurfacePieces:
        ids = np.split(np.asarray(a["ids"], np.int64), np.cumsum(a["sizes"])[:-1])
        return cls(tuple(ids), np.asarray(a["depth"], np.float64),
                   np.asarray(a["error"], np.float64))


def piece_points(vertices: np.ndarray, normals: np.ndarray, ids: np.ndarray,
                 depth: float) -> np.ndarray:
    """Hull points of one piece: the patch vertices and, unless ``depth`` is NaN, the same
    vertices ``depth`` m inward along their unit ``normals`` -> (n or 2n, 3)."""
    v = vertices[ids]
    if not np.isfinite(depth):
        return np.ascontiguousarray(v, dtype=np.float64)
    return np.ascontiguousarray(np.concatenate([v, v - depth * normals[ids]]), dtype=np.float64)


def scatter_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """``out[index[i]] += values[i]`` for i in order -> (n, 3): the sums ``np.add.at`` gives,
    bit for bit (each row's terms are added in the same order, starting from 0), ten to
    twenty times faster (``np.bincount`` per coordinate). index (N,), values (N, 3)."""
    return np.stack([np.bincount(index, weights=values[:, c], minlength=n)
                     for c in range(3)], axis=1)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3) of a closed, outward-oriented mesh."""
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 area
    f = np.asarray(faces)
    out = scatter_sum(f.T.ravel(), np.concatenate([fn, fn, fn]), len(v))
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.where(norm > 0, norm, 1.0)


def _edge_ids(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Per (face, edge opposite corner k), face-major, the index of that undirected edge among
    the mesh's edges in sorted order (F * 3,): what ``np.unique(edges, axis=0,
    return_inverse=True)`` gives, from one integer key per edge (a row-wise unique sorts
    structured rows: ~10 ms on a hand, most of a surface's set-up). Cached per topology (a
    hand keeps its faces across poses)."""
    key = hashlib.sha256(np.ascontiguousarray(faces, np.int64).tobytes()).hexdigest()
    if key not in _EDGE_IDS:
        f = np.asarray(faces, np.int64)
        edges = np.stack([np.sort(f[:, [(k + 1) % 3, (k + 2) % 3]], axis=1)
                          for k in range(3)], axis=1).reshape(-1, 2)
        _, inv = np.unique(edges[:, 0] * n_vertices + edges[:, 1], return_inverse=True)
        _EDGE_IDS[key] = inv.reshape(-1)
        while len(_EDGE_IDS) > 8:  # a few topologies per process: hands and objects
            _EDGE_IDS.pop(next(iter(_EDGE_IDS)))
    return _EDGE_IDS[key]


_EDGE_IDS: dict[str, np.ndarray] = {}


class ExactDistance:
    """Exact signed distance to a closed mesh (negative inside): libigl's AABB tree for the
    closest point, the sign from the pseudonormal of the closest feature (face, edge or
    vertex, angle-weighted; Baerentzen & Aanaes 2005), as ``igl.signed_distance`` does. The
    tree and the pseudonormals are built once per surface, at the first query (rebuilding
    them took ~20 ms of every ``igl.signed_distance`` call on a hand: most of a piece
    refinement's time)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.V = np.ascontiguousarray(vertices, dtype=np.float64)
        self.F = np.ascontiguousarray(faces, dtype=np.int64)
        self._tree = None

    def _build(self) -> None:
        import igl

        tri = self.V[self.F]  # (F, 3 corners, 3)
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        weighted = []
        for k in range(3):  # angle-weighted vertex pseudonormals
            a = tri[:, (k + 1) % 3] - tri[:, k]
            b = tri[:, (k + 2) % 3] - tri[:, k]
            cos = np.einsum("ij,ij->i", a, b) / np.maximum(
                np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
            weighted.append(fn * np.arccos(np.clip(cos, -1.0, 1.0))[:, None])
        vn = scatter_sum(self.F.T.ravel(), np.concatenate(weighted), len(self.V))
        # edge pseudonormals: the sum of the two faces' normals, per (face, edge opposite k)
        inv = _edge_ids(self.F, len(self.V))
        esum = scatter_sum(inv, np.repeat(fn, 3, axis=0), int(inv.max()) + 1)
        self._fn, self._vn, self._en = fn, vn, esum[inv].reshape(-1, 3, 3)
        self._tree = igl.AABB()
        self._tree.init(self.V, self.F)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """points (N, 3) m -> (N,) m."""
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0:
            return np.zeros(0)
        if self._tree is None:
            self._build()
        sq, face, closest = self._tree.squared_distance(self.V, self.F, p)
        tri = self.V[self.F[face]]  # (N, 3, 3)
        bary = _barycentric(closest, tri)
        eps = 1e-9  # of the barycentric coordinates: on a vertex / an edge
        normal = self._fn[face].copy()
        on_edge = bary < eps  # the coordinate of the corner opposite the edge is 0
        for k in range(3):
            e = on_edge[:, k]
            normal[e] = self._en[face[e], k]
            v = bary[:, k] > 1.0 - eps
            normal[v] = self._vn[self.F[face[v], k]]
        sign = np.where(np.einsum("ij,ij->i", p - closest, normal) < 0.0, -1.0, 1.0)
        return sign * np.sqrt(np.maximum(sq, 0.0))


def _barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (N, 3) of points p (N, 3) in triangles tri (N, 3, 3)."""
    v0, v1 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    v2 = p - tri[:, 0]
    d00, d01, d11 = (np.einsum("ij,ij->i", a, b) for a, b in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
    den = np.where(np.abs(d00 * d11 - d01 * d01) > 0, d00 * d11 - d01 * d01, 1.0)
    b1 = (d11 * d20 - d01 * d21) / den
    b2 = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - b1 - b2, b1, b2], axis=1)


def hull_samples(point_sets: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Points on each set's convex hull surface, all sets at once: samples (M, 3) and the
    set each belongs to, owner (M,). Per hull: its vertices, face centroids and edge
    midpoints (each edge once), where a hull bridging a concavity sticks out furthest; a
    flat or degenerate set gives its points themselves. One gather for every set (building
    the samples hull by hull cost about as much as Qhull itself, ~0.1 ms a piece)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in point_sets]
    starts = np.cumsum([0] + [len(p) for p in pts[:-1]])
    ids, owner, tris, tri_owner = [], [], [], []
    for i, (p, s0) in enumerate(zip(pts, starts, strict=True)):
        try:
            hull = ConvexHull(p)
        except (QhullError, ValueError):
            ids.append(s0 + np.arange(len(p)))
        else:
            ids.append(s0 + hull.vertices)
            tris.append(s0 + hull.simplices)
            tri_owner.append(np.full(len(hull.simplices), i))
        owner.append(np.full(len(ids[-1]), i))
    every = np.concatenate(pts) if pts else np.zeros((0, 3))
    samples, owners = [every[np.concatenate(ids)]], [np.concatenate(owner)]
    if tris:
        tri, tri_own = np.concatenate(tris), np.concatenate(tri_owner)
        edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        _, once = np.unique(edges[:, 0] * len(every) + edges[:, 1], return_index=True)
        edges = edges[once]
        samples += [every[tri].mean(1), 0.5 * (every[edges[:, 0]] + every[edges[:, 1]])]
        owners += [tri_own, np.tile(tri_own, 3)[once]]
    return np.concatenate(samples), np.concatenate(owners)


def outward_errors(point_sets: list[np.ndarray], sdf: ExactDistance) -> np.ndarray:
    """Measured outward error (P,) m of each point set's hull against the surface of
    ``sdf``: the largest signed distance of its hull samples, 0 when none is outside."""
    if not len(point_sets):
        return np.zeros(0)
    samples, owner = hull_samples(point_sets)
    err = np.zeros(len(point_sets))
    np.maximum.at(err, owner, sdf(samples))
    return err


def _split(faces_idx: np.ndarray, centroids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two halves of a patch: the median of the face centroids along their widest axis."""
    c = centroids[faces_idx]
    axis = int(np.argmax(c.max(0) - c.min(0)))
    order = np.argsort(c[:, axis], kind="stable")
    half = len(order) // 2
    return faces_idx[order[:half]], faces_idx[order[half:]]


def _initial_patches(faces: np.ndarray, centroids: np.ndarray, labels: np.ndarray | None,
                     patch_faces: int) -> list[np.ndarray]:
    """Compact patches of at most ``patch_faces`` faces, each within one label."""
    if labels is None:
        groups = [np.arange(len(faces))]
    else:
        face_label = np.asarray(labels)[faces]
        # a face between two labels belongs to the label of most of its corners (else its first)
        lab = np.where(face_label[:, 1] == face_label[:, 2], face_label[:, 1], face_label[:, 0])
        groups = [np.flatnonzero(lab == g) for g in np.unique(lab)]
    out, todo = [], [g for g in groups if len(g)]
    while todo:
        p = todo.pop()
        if len(p) > patch_faces:
            todo.extend(_split(p, centroids))
        else:
            out.append(p)
    return sorted(out, key=lambda p: int(p.min()))


def surface_pieces(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray | None = None,
                   max_error: float = C.PIECE_MAX_ERROR, depth: float = C.PIECE_DEPTH,
                   patch_faces: int = C.PIECE_PATCH_FACES,
                   sdf: ExactDistance | None = None,
                   normals: np.ndarray | None = None,
                   patches: list[tuple[np.ndarray, float]] | None = None) -> SurfacePieces:
    """Convex pieces of a closed mesh with measured outward error <= ``max_error`` (m).

    vertices (V, 3) m, faces (F, 3), labels (V,) optional: no patch spans two labels (and no
    whole-hull shortcut is taken). ``depth`` (m): the inner layer's depth, halved where it
    pokes through a thin wall, never below ``C.PIECE_MIN_DEPTH``. A single face that still
    exceeds the bound there is kept and its error recorded (read ``error`` for the truth).
    ``patches``: the starting patches (face indices into ``faces``, inner depth) instead of
    ``labels``' compact ones (:func:`refine_pieces`); ``sdf`` and ``normals`` (V, 3) may be
    passed in (a surface's own are computed otherwise).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    sdf = sdf or ExactDistance(v, f)
    if labels is None and patches is None:
        whole = outward_errors([v], sdf)[0]
        if whole <= max_error:
            return SurfacePieces((np.arange(len(v)),), np.array([np.nan]), np.array([whole]))
    normals = vertex_normals(v, f) if normals is None else np.asarray(normals, np.float64)
    centroids = v[f].mean(1)
    todo = list(patches) if patches is not None else [
        (p, depth) for p in _initial_patches(f, centroids, labels, patch_faces)]
    done: list[tuple[np.ndarray, float, float]] = []
    while todo:
        ids = _patch_vertices(f, [p for p, _ in todo], len(v))
        full = outward_errors([piece_points(v, normals, i, d) for i, (_, d) in
                               zip(ids, todo, strict=True)], sdf)
        over = np.flatnonzero(full > max_error)  # only these need the thin prism's error
        thin = np.zeros(len(ids))
        thin[over] = outward_errors([piece_points(v, normals, ids[k], C.PIECE_MIN_DEPTH)
                                     for k in over], sdf)
        nxt = []
        for (p, d), i, e_full, e_thin in zip(todo, ids, full, thin, strict=True):
            if e_full <= max_error:
                done.append((i, d, e_full))
            elif e_thin > max_error and len(p) > 1:
                nxt.extend((h, d) for h in _split(p, centroids))  # the surface is too concave
            elif d > C.PIECE_MIN_DEPTH:
                nxt.append((p, max(d / 2, C.PIECE_MIN_DEPTH)))  # the inner layer pokes through
            else:
                done.append((i, d, e_full))  # one face at the smallest depth: keep, recorded
        todo = nxt
    done.sort(key=lambda x: int(x[0].min()))
    return SurfacePieces(tuple(i for i, _, _ in done), np.array([d for _, d, _ in done]),
                         np.array([e for _, _, e in done]))


def _patch_vertices(faces: np.ndarray, patches: list[np.ndarray], n_vertices: int
                    ) -> list[np.ndarray]:
    """Each patch's vertex ids, sorted and unique (one ``np.unique`` over every patch: a call
    per patch cost ~30 us each, thousands per posed hand)."""
    if not patches:
        return []
    patch = np.repeat(np.arange(len(patches)), [3 * len(p) for p in patches])
    key = np.unique(patch * n_vertices + faces[np.concatenate(patches)].ravel())
    cuts = np.searchsorted(key, np.arange(1, len(patches)) * n_vertices)
    return np.split(key - np.repeat(np.arange(len(patches)), np.diff(np.r_[0, cuts, len(key)]))
                    * n_vertices, cuts)


# a piece a pose bent past the bound restarts from parts this small (faces): fewer measuring
# rounds than halving it from PIECE_PATCH_FACES (kept here, not in constants: an algorithm
# setting of this module, and an edit of constants renews every cache key)
REFINE_FACES = 16


def refine_pieces(pieces: SurfacePieces, errors: np.ndarray, vertices: np.ndarray,
                  faces: np.ndarray, sdf: ExactDistance | None = None,
                  normals: np.ndarray | None = None) -> SurfacePieces:
    """``pieces`` whose ``errors`` (P,) m, measured on the surface ``vertices`` (V, 3) /
    ``faces`` (F, 3) (e.g. a posed hand whose bending took a piece past the bound), exceed
    ``PIECE_MAX_ERROR`` rebuilt from their own faces there: one :func:`surface_pieces` pass
    that starts from the bad pieces and splits them against the whole surface's exact
    distance, so the rebuilt pieces meet the bound (single faces excepted, their error
    recorded). The others keep ``errors`` as their recorded error."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    errors = np.asarray(errors, dtype=np.float64)
    bad = errors > C.PIECE_MAX_ERROR
    keep = [i for i in range(len(pieces)) if not bad[i]]
    centroids = v[f].mean(1)
    patches = []
    for i in np.flatnonzero(bad):
        mine = np.zeros(len(v), bool)
        mine[pieces.vertex_ids[i]] = True
        own = np.flatnonzero(mine[f].all(1))  # the faces all of whose corners are the piece's
        d = pieces.depth[i]
        if len(own) <= 1:
            keep.append(int(i))  # one face (or none): nothing to split
            continue
        depth = float(d) if np.isfinite(d) else C.PIECE_DEPTH
        todo = [own]
        while todo:  # start from parts of REFINE_FACES faces: fewer measuring rounds
            p = todo.pop()
            if len(p) > REFINE_FACES:
                todo.extend(_split(p, centroids))
            else:
                patches.append((p, depth))
    new = surface_pieces(v, f, sdf=sdf, patches=patches, normals=normals)
    keep.sort()
    return SurfacePieces(tuple(pieces.vertex_ids[i] for i in keep) + new.vertex_ids,
                         np.concatenate([pieces.depth[keep], new.depth]),
                         np.concatenate([errors[keep], new.error]))
