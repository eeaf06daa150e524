"""Exact intersection volume of two closed meshes with manifold3d (metric ``iv``).

Definition: docs/contract.md, "Definitions".

Why not the usual recipes: trimesh's ``voxelized()`` keeps only the surface shell of voxels
(volumes 3-10x too low) and an open hand (MANO's wrist hole) makes manifold3d return an empty
result whose volume reads as 0. Here an invalid mesh gives NaN and is counted, never 0.
Vertices go to manifold3d in float64 (``Mesh64``) after a shift to a local origin, so neither
float32 rounding nor far-from-origin coordinates affect the volume.
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # trimesh costs 0.5 s to import; `grip-bench ls` should not pay it
    import manifold3d
    import trimesh


@dataclass
class FailureCounter:
    """Counts metric evaluations that could not be computed, by reason; the aggregator owns it."""

    count: int = 0
    reasons: Counter = field(default_factory=Counter)

    def add(self, reason: str, n: int = 1) -> None:
        self.count += n
        self.reasons[reason] += n


def _fail(failures: FailureCounter | None, reason: str, n: int = 1) -> float:
    if failures is not None:
        failures.add(reason, n)
    return float("nan")


def is_closed_manifold(faces: np.ndarray) -> bool:
    """Topology test: every directed edge occurs once and its reverse once (closed, oriented).

    faces: (F, 3) int. Cheap (numpy only), so it runs before the early-outs: an open mesh is a
    failure even when it happens to lie far from the other mesh.
    """
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[0] < 4 or f.shape[1] != 3:
        return False
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n = int(f.max()) + 1
    key, rev = e[:, 0] * n + e[:, 1], e[:, 1] * n + e[:, 0]
    key_sorted = np.sort(key)
    if np.any(key_sorted[1:] == key_sorted[:-1]) or np.any(e[:, 0] == e[:, 1]):
        return False
    pos = np.clip(np.searchsorted(key_sorted, rev), 0, len(key_sorted) - 1)
    return bool(np.all(key_sorted[pos] == rev))


def to_manifold(
    vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray | None = None
) -> manifold3d.Manifold | None:
    """A manifold3d ``Manifold`` of a closed mesh, or ``None`` when manifold3d rejects it.

    vertices: (V, 3) m; faces: (F, 3); origin: (3,) subtracted first (local coordinates).
    """
    import manifold3d as m3

    v = np.asarray(vertices, dtype=np.float64)
    if origin is not None:
        v = v - origin
    if not np.isfinite(v).all():
        return None
    v = np.ascontiguousarray(v)
    if hasattr(m3, "Mesh64"):
        mesh = m3.Mesh64(vert_properties=v, tri_verts=np.ascontiguousarray(faces, dtype=np.uint64))
    else:  # older manifold3d: float32, made precise by the local origin above
        mesh = m3.Mesh(
            vert_properties=v.astype(np.float32),
            tri_verts=np.ascontiguousarray(faces, dtype=np.uint32),
        )
    man = m3.Manifold(mesh)
    if man.status() != m3.Error.NoError and mesh.merge():
        man = m3.Manifold(mesh)  # duplicated seam vertices: merging them often repairs it
    return man if man.status() == m3.Error.NoError else None


_CLOSED_CACHE: dict[bytes, bool] = {}


def _closed_cached(faces: np.ndarray) -> bool:
    """``is_closed_manifold`` remembered by face-array content: a sequence reuses one topology."""
    import hashlib

    f = np.ascontiguousarray(faces, dtype=np.int64)
    key = hashlib.sha1(f.tobytes()).digest() + bytes(str(f.shape), "ascii")
    if key not in _CLOSED_CACHE:
        if len(_CLOSED_CACHE) > 256:
            _CLOSED_CACHE.clear()
        _CLOSED_CACHE[key] = is_closed_manifold(f)
    return _CLOSED_CACHE[key]


def _aabb(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return v.min(axis=0), v.max(axis=0)


def _disjoint(va: np.ndarray, vb: np.ndarray) -> bool:
    """Early-out: bounding boxes, then bounding spheres (about the box centres), do not meet."""
    return _disjoint_from(va, _Bounds(vb))


class _Bounds:
    """The box ``lo, hi`` (3,) of points (N, 3) and, when first asked, the sphere about the
    box centre ``c`` holding them (radius ``r``): one mesh's side of ``_disjoint``, computed
    once for a mesh tested against many others (the object of ``intersection_volume_batch``)."""

    def __init__(self, v: np.ndarray):
        self.v = v
        self.lo, self.hi = _aabb(v)
        self._sphere: tuple[np.ndarray, float] | None = None

    def sphere(self) -> tuple[np.ndarray, float]:
        if self._sphere is None:
            c = 0.5 * (self.lo + self.hi)
            self._sphere = c, np.sqrt(((self.v - c) ** 2).sum(axis=1).max())
        return self._sphere


def _disjoint_from(va: np.ndarray, b: _Bounds) -> bool:
    """``_disjoint(va, b.v)``: the same tests on the same values, ``b``'s side computed once."""
    lo_a, hi_a = _aabb(va)
    if np.any(lo_a > b.hi) or np.any(b.lo > hi_a):
        return True
    ca = 0.5 * (lo_a + hi_a)
    ra = np.sqrt(((va - ca) ** 2).sum(axis=1).max())
    cb, rb = b.sphere()
    return bool(np.linalg.norm(ca - cb) > ra + rb)


def _volume(man_a: manifold3d.Manifold, man_b: manifold3d.Manifold) -> float:
    return float(max((man_a ^ man_b).volume(), 0.0))


def intersection_volume(
    a: trimesh.Trimesh, b: trimesh.Trimesh, failures: FailureCounter | None = None
) -> float:
    """Exact ``vol(a & b)`` in m^3 of two closed meshes in the same frame.

    0.0 when they do not overlap; NaN (and ``failures`` incremented) when either mesh is open
    or manifold3d rejects it.
    """
    va, vb = np.asarray(a.vertices, np.float64), np.asarray(b.vertices, np.float64)
    if not (_closed_cached(a.faces) and _closed_cached(b.faces)):
        return _fail(failures, "open mesh")
    if _disjoint(va, vb):
        return 0.0
    origin = 0.5 * (va.min(axis=0) + va.max(axis=0))
    man_a, man_b = to_manifold(va, a.faces, origin), to_manifold(vb, b.faces, origin)
    if man_a is None or man_b is None:
        return _fail(failures, "not a manifold")
    return _volume(man_a, man_b)


def to_object_frame(
    vertices: np.ndarray, rotations: np.ndarray | None, translations: np.ndarray | None
) -> np.ndarray:
    """World points into the object's own frame, where ``world = R @ local + t``.

    vertices: (T, V, 3); rotations: (T, 3, 3) or None; translations: (T, 3) or None -> (T, V, 3).
    """
    v = np.asarray(vertices, dtype=np.float64)
    if translations is not None:
        v = v - np.asarray(translations, dtype=np.float64)[:, None, :]
    if rotations is not None:
        v = np.einsum("tvi,tij->tvj", v, np.asarray(rotations, dtype=np.float64))  # R^T v
    return v


def intersection_volume_batch(
    hand_vertices: np.ndarray,
    hand_faces: np.ndarray,
    obj: trimesh.Trimesh,
    obj_rotations: np.ndarray | None = None,
    obj_translations: np.ndarray | None = None,
    failures: FailureCounter | None = None,
) -> np.ndarray:
    """Per-frame exact intersection volume of a hand sequence with one rigid object.

    hand_vertices: (T, V, 3) m world; hand_faces: (F, 3); obj: mesh in its own frame;
    obj_rotations (T, 3, 3), obj_translations (T, 3): object pose per frame (None: identity)
    -> (T,) m^3. The hand is moved into the object's frame, so the object's Manifold is built
    once. Failed frames are NaN and each counts once in ``failures``.
    """
    v = to_object_frame(hand_vertices, obj_rotations, obj_translations)
    out = np.zeros(v.shape[0])
    if not (_closed_cached(hand_faces) and _closed_cached(obj.faces)):
        out[:] = _fail(failures, "open mesh", v.shape[0])
        return out
    vo = np.asarray(obj.vertices, np.float64)
    origin = 0.5 * (vo.min(axis=0) + vo.max(axis=0))
    man_obj = _object_manifold(vo, obj.faces, origin)
    if man_obj is None:
        out[:] = _fail(failures, "not a manifold", v.shape[0])
        return out
    hands = _PosedManifolds(hand_faces, origin)
    bounds = _Bounds(vo)
    for t, vt in enumerate(v):
        if _disjoint_from(vt, bounds):
            continue
        man_hand = hands.at(vt)
        out[t] = (
            _fail(failures, "not a manifold") if man_hand is None else _volume(man_hand, man_obj)
        )
    return out


# Objects' Manifolds by content (vertices, faces, origin), for the next hand of the same
# object in this process: building one from a mesh costs ~10 ms per (sequence, hand), and a
# Manifold is immutable (booleans return new ones), so a reused one gives the same volumes.
_OBJECT_MANIFOLDS: OrderedDict[bytes, object] = OrderedDict()
_OBJECT_MANIFOLDS_SIZE = 8


def _object_manifold(v: np.ndarray, faces: np.ndarray, origin: np.ndarray
                     ) -> manifold3d.Manifold | None:
    """``to_manifold(v, faces, origin)``, remembered by content (the last few objects)."""
    import hashlib

    f = np.ascontiguousarray(faces)
    h = hashlib.sha1()
    for a in (np.ascontiguousarray(v, np.float64), f, np.ascontiguousarray(origin, np.float64)):
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    key = h.digest()
    if key in _OBJECT_MANIFOLDS:
        _OBJECT_MANIFOLDS.move_to_end(key)
        return _OBJECT_MANIFOLDS[key]
    man = to_manifold(v, faces, origin)
    _OBJECT_MANIFOLDS[key] = man
    if len(_OBJECT_MANIFOLDS) > _OBJECT_MANIFOLDS_SIZE:
        _OBJECT_MANIFOLDS.popitem(last=False)
    return man


class _PosedManifolds:
    """Manifolds of one mesh topology in many poses: the first is built, the rest are warped.

    Building a Manifold from a 5k-face hand (merging, half-edge sort) costs ~3 ms; moving the
    vertices of an existing one (``warp_batch``: same topology, bounds and collider refreshed)
    ~1 ms, with identical volumes. Manifold keeps its own vertex order, so the permutation to
    it is read once from the first build. Falls back to building whenever that is not possible
    (older manifold3d, merged vertices).
    """

    def __init__(self, faces: np.ndarray, origin: np.ndarray):
        self.faces, self.origin = faces, origin
        self.base, self.perm = None, None

    def at(self, vertices: np.ndarray) -> manifold3d.Manifold | None:
        """The Manifold of the mesh at ``vertices`` (V, 3), or None when manifold3d rejects it."""
        v = np.asarray(vertices, np.float64) - self.origin
        if self.perm is None or not np.isfinite(v).all():
            man = to_manifold(v, self.faces)
            if self.base is None and man is not None:
                self._adopt(man, v)
            return man
        return self.base.warp_batch(lambda _: v[self.perm])

    def _adopt(self, man: manifold3d.Manifold, v: np.ndarray) -> None:
        """Keep ``man`` as the base when its vertices are exactly a permutation of ``v``."""
        from scipy.spatial import cKDTree

        self.base = man
        if not hasattr(man, "warp_batch") or man.num_vert() != len(v):
            return
        own: list[np.ndarray] = []
        man.warp_batch(lambda x: own.append(np.array(x, dtype=np.float64)) or x)
        dist, perm = cKDTree(v).query(own[0])
        if np.all(dist == 0.0) and len(np.unique(perm)) == len(v):
            self.perm = perm


def cap_boundary_loops(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Close each boundary loop with a fan around its centroid (e.g. MANO's open wrist).

    The IV of an open hand is undefined; capping is an explicit choice the caller makes (and
    reports), so ``intersection_volume`` never does it silently.
    """
    import trimesh
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(mesh.faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n = len(mesh.vertices)
    key, rev = e[:, 0] * n + e[:, 1], e[:, 1] * n + e[:, 0]
    boundary = e[~np.isin(key, rev)]  # directed edges whose twin is missing
    if len(boundary) == 0:
        return mesh.copy()
    graph = coo_matrix((np.ones(len(boundary)), (boundary[:, 0], boundary[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    loops = np.unique(label[boundary[:, 0]])
    verts, faces = [np.asarray(mesh.vertices)], [f]
    for i, lab in enumerate(loops):
        edges = boundary[label[boundary[:, 0]] == lab]
        centre = n + i
        verts.append(mesh.vertices[np.unique(edges)].mean(axis=0, keepdims=True))
        # the cap face walks the boundary edge backwards so orientation stays consistent
        faces.append(np.column_stack([edges[:, 1], edges[:, 0], np.full(len(edges), centre)]))
    return trimesh.Trimesh(np.vstack(verts), np.vstack(faces), process=False)
