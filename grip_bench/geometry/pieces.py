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


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3) of a closed, outward-oriented mesh."""
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 area
    out = np.zeros_like(v)
    for k in range(3):
        np.add.at(out, faces[:, k], fn)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.where(norm > 0, norm, 1.0)


class ExactDistance:
    """Exact signed distance to a closed mesh (negative inside), libigl AABB tree with
    pseudonormal signs; built once per surface."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import igl

        self.V = np.ascontiguousarray(vertices, dtype=np.float64)
        self.F = np.ascontiguousarray(faces, dtype=np.int64)
        self._igl = igl

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """points (N, 3) m -> (N,) m."""
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0:
            return np.zeros(0)
        d = self._igl.signed_distance(
            p, self.V, self.F, sign_type=self._igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0]
        return np.asarray(d, dtype=np.float64)


def hull_samples(points: np.ndarray) -> np.ndarray:
    """Points on the convex hull's surface (M, 3): its vertices, face centroids and edge
    midpoints, where a hull bridging a concavity sticks out furthest. Flat or degenerate
    point sets return the points themselves."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):
        return np.asarray(points, dtype=np.float64)
    tri = hull.points[hull.simplices]  # (K, 3, 3)
    mids = 0.5 * (tri + np.roll(tri, 1, axis=1))
    return np.concatenate([hull.points[hull.vertices], tri.mean(1), mids.reshape(-1, 3)])


def outward_errors(point_sets: list[np.ndarray], sdf: ExactDistance) -> np.ndarray:
    """Measured outward error (P,) m of each point set's hull against the surface of
    ``sdf``: the largest signed distance of its hull samples, 0 when none is outside."""
    samples = [hull_samples(p) for p in point_sets]
    if not samples:
        return np.zeros(0)
    d = sdf(np.concatenate(samples))
    ends = np.cumsum([len(s) for s in samples])
    return np.maximum(np.maximum.reduceat(d, np.r_[0, ends[:-1]]), 0.0)


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
                   sdf: ExactDistance | None = None) -> SurfacePieces:
    """Convex pieces of a closed mesh with measured outward error <= ``max_error`` (m).

    vertices (V, 3) m, faces (F, 3), labels (V,) optional: no patch spans two labels (and no
    whole-hull shortcut is taken). ``depth`` (m): the inner layer's depth, halved where it
    pokes through a thin wall, never below ``C.PIECE_MIN_DEPTH``. A single face that still
    exceeds the bound there is kept and its error recorded (read ``error`` for the truth).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    sdf = sdf or ExactDistance(v, f)
    if labels is None:
        whole = outward_errors([v], sdf)[0]
        if whole <= max_error:
            return SurfacePieces((np.arange(len(v)),), np.array([np.nan]), np.array([whole]))
    normals = vertex_normals(v, f)
    centroids = v[f].mean(1)
    todo = [(p, depth) for p in _initial_patches(f, centroids, labels, patch_faces)]
    done: list[tuple[np.ndarray, float, float]] = []
    while todo:
        ids = [np.unique(f[p]) for p, _ in todo]
        full = outward_errors([piece_points(v, normals, i, d) for i, (_, d) in
                               zip(ids, todo, strict=True)], sdf)
        thin = outward_errors([piece_points(v, normals, i, C.PIECE_MIN_DEPTH) for i in ids],
                              sdf)
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
