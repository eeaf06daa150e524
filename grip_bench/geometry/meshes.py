"""Object meshes: load, repair what is safe, reject what is not; the ObjectAsset record.

Meshes leaving this module are watertight, consistently wound, outward-facing
``trimesh.Trimesh`` in float64 metres (docs/architecture.md). ``mesh.metadata`` keeps
``source`` (path), ``repairs`` (list of what was changed) and ``n_components``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import manifold3d
import numpy as np
import trimesh

from grip_bench.core import constants
from grip_bench.core.errors import InputError

__all__ = ["ObjectAsset", "load_object_mesh", "to_manifold", "from_manifold", "repair_mesh"]

SUPPORTED_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")


# --- manifold3d bridge ------------------------------------------------------------


def to_manifold(mesh: trimesh.Trimesh) -> manifold3d.Manifold:
    """Trimesh -> manifold3d.Manifold (float64); InputError if it is not an oriented 2-manifold."""
    m = manifold3d.Manifold(
        manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
            tri_verts=np.ascontiguousarray(mesh.faces, dtype=np.uint64),
        )
    )
    status = m.status()
    if status != manifold3d.Error.NoError:
        where = mesh.metadata.get("source") if mesh.metadata else None
        raise InputError(f"mesh is not a closed oriented 2-manifold ({status.name})", where=where)
    return m


def from_manifold(m: manifold3d.Manifold) -> trimesh.Trimesh:
    """manifold3d.Manifold -> Trimesh (float64 vertices, int64 faces, no processing)."""
    mesh = m.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


# --- loading -----------------------------------------------------------------------


def _read(path: Path) -> trimesh.Trimesh:
    """Read any supported file into one raw Trimesh (scenes flattened with their transforms)."""
    if not path.is_file():
        raise InputError("mesh file not found", where=path)
    if path.stat().st_size == 0:
        raise InputError("mesh file is empty (0 bytes)", where=path)
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise InputError(
            f"unsupported mesh format {path.suffix!r} "
            f"(expected one of {', '.join(SUPPORTED_SUFFIXES)})",
            where=path,
        )
    try:
        scene = trimesh.load_scene(str(path), process=False)
        geoms = [g for g in scene.dump() if isinstance(g, trimesh.Trimesh)]
    except (UnicodeDecodeError, ModuleNotFoundError) as exc:
        # trimesh falls back to text decoding (via an optional charset detector) when
        # the binary layout does not match: the bytes are neither
        kind = path.suffix.lower().lstrip(".").upper()
        raise InputError(f"not a valid {kind} file (undecodable bytes)", where=path) from exc
    except Exception as exc:  # parsers raise anything from ValueError to struct.error
        raise InputError(f"could not read mesh ({type(exc).__name__}: {exc})", where=path) from exc
    if not geoms or sum(len(g.faces) for g in geoms) == 0:
        raise InputError("file holds no triangles (empty, truncated or not a mesh)", where=path)
    mesh = trimesh.util.concatenate(geoms) if len(geoms) > 1 else geoms[0]
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if not np.isfinite(verts).all():
        raise InputError("mesh has NaN or infinite vertex coordinates", where=path)
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        raise InputError("face indices point past the vertex list (truncated file?)", where=path)
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def _unit_hint(extent: float) -> str:
    """Name the unit an out-of-range extent (m) most likely came from, with the factor to apply."""
    typical = 0.15  # m; GRAB objects are 5-30 cm
    candidates = {"millimetres": 1e-3, "centimetres": 1e-2, "metres read as mm": 1e3}
    fits = {
        k: f
        for k, f in candidates.items()
        if constants.MIN_OBJECT_EXTENT <= extent * f <= constants.MAX_OBJECT_EXTENT
    }
    if not fits:
        return "no unit factor brings it to a plausible size"
    unit = min(fits, key=lambda k: abs(math.log(extent * fits[k] / typical)))
    return f"looks like {unit}; pass scale={fits[unit]:g}"


def _check_extent(mesh: trimesh.Trimesh, where: str | os.PathLike | None) -> None:
    extent = float(np.ptp(mesh.vertices, axis=0).max())
    if extent > constants.MAX_OBJECT_EXTENT:
        raise InputError(
            f"object extent {extent:.4g} m is over {constants.MAX_OBJECT_EXTENT} m "
            f"({_unit_hint(extent)})",
            where=where,
        )
    if extent < constants.MIN_OBJECT_EXTENT:
        raise InputError(
            f"object extent {extent:.4g} m is under {constants.MIN_OBJECT_EXTENT * 1e3:g} mm "
            f"({_unit_hint(extent)})",
            where=where,
        )


def _check_not_flat(mesh: trimesh.Trimesh, where: str | os.PathLike | None) -> None:
    centred = mesh.vertices - mesh.vertices.mean(0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[-1] <= constants.FLAT_TOL * sv[0]:
        raise InputError("mesh is flat (all vertices in one plane): zero volume", where=where)


def _check_edge_manifold(mesh: trimesh.Trimesh, where: str | os.PathLike | None) -> None:
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    n_bad = int((counts > 2).sum())
    if n_bad:
        raise InputError(
            f"non-manifold: {n_bad} edges are shared by more than two faces", where=where
        )


def _boundary_loops(faces: np.ndarray) -> list[list[tuple[int, int]]]:
    """Directed boundary edges of an oriented mesh, chained into loops (lists of (a, b))."""
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = directed[counts[inverse.ravel()] == 1]
    nxt: dict[int, list[int]] = {}
    for a, b in boundary.tolist():
        nxt.setdefault(a, []).append(b)
    loops = []
    while nxt:
        a = next(iter(nxt))
        path: list[tuple[int, int]] = []
        seen = {a: 0}
        while a in nxt:
            b = nxt[a].pop()
            if not nxt[a]:
                del nxt[a]
            path.append((a, b))
            if b in seen:  # closed a simple loop (pinch vertices give figure-eights: split them)
                loops.append(path[seen[b] :])
                del path[seen[b] :]
                seen = {e[0]: i for i, e in enumerate(path)}
            seen[b] = len(path)
            a = b
        if path:
            loops.append(path)  # an unclosed chain: reported as open by the caller
    return loops


def _close_small_holes(
    mesh: trimesh.Trimesh, where: str | os.PathLike | None, repairs: list[str]
) -> trimesh.Trimesh:
    """Fan-fill each boundary loop from its centroid; reject loops too large to guess over."""
    loops = _boundary_loops(np.asarray(mesh.faces))
    if not loops:
        return mesh
    diag = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    limit = constants.MAX_HOLE_FRACTION * diag
    verts, faces = [np.asarray(mesh.vertices)], [np.asarray(mesh.faces)]
    n = len(mesh.vertices)
    for loop in loops:
        idx = np.array(loop)
        seg = mesh.vertices[idx[:, 1]] - mesh.vertices[idx[:, 0]]
        perimeter = float(np.linalg.norm(seg, axis=1).sum())
        if perimeter > limit or idx[0, 0] != idx[-1, 1]:
            raise InputError(
                f"mesh is open: a hole with perimeter {perimeter * 1e3:.1f} mm "
                f"({len(loop)} edges) is too large to close safely (limit {limit * 1e3:.1f} mm)",
                where=where,
            )
        verts.append(mesh.vertices[idx[:, 0]].mean(0, keepdims=True))
        # the fan triangle (b, a, c) runs the boundary edge a->b backwards, as its neighbour needs
        faces.append(np.column_stack([idx[:, 1], idx[:, 0], np.full(len(idx), n)]))
        n += 1
    repairs.append(f"closed {len(loops)} small hole(s)")
    return trimesh.Trimesh(np.vstack(verts), np.vstack(faces), process=False)


def _clean(mesh: trimesh.Trimesh, repairs: list[str]) -> trimesh.Trimesh:
    """Merge duplicate vertices, drop degenerate and duplicate faces."""
    nv, nf = len(mesh.vertices), len(mesh.faces)
    mesh.merge_vertices(digits_vertex=round(-math.log10(constants.MERGE_TOL)))
    mesh.update_faces(mesh.nondegenerate_faces(height=constants.MERGE_TOL))
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.vertices) != nv:
        repairs.append(f"merged/removed {nv - len(mesh.vertices)} vertices")
    if len(mesh.faces) != nf:
        repairs.append(f"dropped {nf - len(mesh.faces)} degenerate or duplicate faces")
    return mesh


def _union_components(
    mesh: trimesh.Trimesh, where: str | os.PathLike | None, repairs: list[str]
) -> trimesh.Trimesh:
    """Several closed shells: union them (overlaps would double-count volume and contact)."""
    parts = mesh.split(only_watertight=False)
    if len(parts) <= 1:
        return mesh
    ms = [to_manifold(p) for p in parts]
    union = manifold3d.Manifold.batch_boolean(ms, manifold3d.OpType.Add)
    if union.status() != manifold3d.Error.NoError or union.is_empty():
        raise InputError(f"could not union {len(parts)} components ({union.status().name})", where)
    repairs.append(f"united {len(parts)} watertight components")
    return from_manifold(union)


def repair_mesh(
    mesh: trimesh.Trimesh, where: str | os.PathLike | None = None
) -> trimesh.Trimesh:
    """Repair a raw mesh into a watertight outward-facing solid, or raise InputError.

    Safe repairs only: merge duplicate vertices, drop degenerate / duplicate faces,
    make winding consistent and outward, fan-close holes smaller than
    ``MAX_HOLE_FRACTION`` of the bounding-box diagonal, union overlapping shells.
    """
    repairs: list[str] = []
    mesh = _clean(mesh.copy(), repairs)
    if len(mesh.faces) == 0:
        raise InputError("mesh has no non-degenerate faces", where=where)
    _check_not_flat(mesh, where)
    _check_edge_manifold(mesh, where)
    trimesh.repair.fix_winding(mesh)
    mesh = _close_small_holes(mesh, where, repairs)
    trimesh.repair.fix_normals(mesh, multibody=True)
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        raise InputError("mesh is not watertight after repair (non-manifold vertices?)", where)
    mesh = _union_components(mesh, where, repairs)
    volume = float(mesh.volume)
    extent = float(np.ptp(mesh.vertices, axis=0).max())
    if not volume > constants.FLAT_TOL * extent**3:
        raise InputError(f"mesh encloses no volume ({volume:.3g} m^3)", where=where)
    n_components = len(mesh.split(only_watertight=False))
    mesh.metadata.update(repairs=repairs, n_components=n_components)
    return mesh


def load_object_mesh(path: str | os.PathLike, scale: float = 1.0) -> trimesh.Trimesh:
    """Load an object mesh (OBJ, PLY, STL, GLB/glTF, OFF) as a watertight solid in metres.

    ``scale`` multiplies coordinates first (e.g. 0.001 for a file in millimetres).
    Raises InputError naming the file and the problem when it cannot be used.
    """
    path = Path(path)
    mesh = _read(path)
    if scale != 1.0:
        mesh.apply_scale(scale)
    _check_extent(mesh, path)
    mesh = repair_mesh(mesh, where=path)
    mesh.metadata["source"] = str(path)
    return mesh


# --- ObjectAsset ---------------------------------------------------------------------


def even_surface_samples(
    mesh: trimesh.Trimesh, count: int = constants.N_SURFACE_SAMPLES, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Evenly spread surface points: area-uniform oversampling thinned by farthest-point sampling.

    Returns points ``(count, 3)`` (m) and their outward face normals ``(count, 3)``;
    deterministic for a given seed.
    """
    rng = np.random.default_rng(seed)
    pool, face_ids = trimesh.sample.sample_surface(mesh, 4 * count, seed=rng)
    chosen = np.empty(count, dtype=np.int64)
    chosen[0] = rng.integers(len(pool))
    d2 = ((pool - pool[chosen[0]]) ** 2).sum(1)
    for i in range(1, count):
        chosen[i] = int(np.argmax(d2))
        np.minimum(d2, ((pool - pool[chosen[i]]) ** 2).sum(1), out=d2)
    return pool[chosen], np.asarray(mesh.face_normals)[face_ids[chosen]]


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectAsset:
    """A rigid object ready for the suite: mesh, surface samples and mass properties.

    ``samples``/``normals`` are ``(2048, 3)``; ``volume`` m^3; ``density`` kg/m^3;
    ``mass`` kg; ``center`` ``(3,)`` and ``radius`` (m) of the minimum bounding sphere.
    """

    name: str
    mesh: trimesh.Trimesh
    samples: np.ndarray
    normals: np.ndarray
    volume: float
    density: float
    mass: float
    center: np.ndarray
    radius: float

    @classmethod
    def from_mesh(
        cls,
        mesh: trimesh.Trimesh,
        name: str = "object",
        density: float = constants.DEFAULT_DENSITY,
        seed: int = 0,
    ) -> ObjectAsset:
        """Build from a watertight mesh (as returned by ``load_object_mesh``)."""
        where = mesh.metadata.get("source", name) if mesh.metadata else name
        if not mesh.is_watertight:
            raise InputError("object mesh must be watertight (use load_object_mesh)", where=where)
        if not density > 0:
            raise InputError(f"density must be positive, got {density}", where=where)
        volume = float(mesh.volume)
        if not volume > 0:
            raise InputError(f"object mesh has non-positive volume {volume:.3g} m^3", where=where)
        samples, normals = even_surface_samples(mesh, constants.N_SURFACE_SAMPLES, seed)
        center, radius = trimesh.nsphere.minimum_nsphere(mesh)
        return cls(
            name=name,
            mesh=mesh,
            samples=samples,
            normals=normals,
            volume=volume,
            density=float(density),
            mass=volume * float(density),
            center=np.asarray(center, dtype=np.float64),
            radius=float(radius),
        )

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        name: str | None = None,
        density: float = constants.DEFAULT_DENSITY,
        seed: int = 0,
        scale: float = 1.0,
    ) -> ObjectAsset:
        """Load, repair and wrap a mesh file; ``name`` defaults to the file stem."""
        mesh = load_object_mesh(path, scale=scale)
        return cls.from_mesh(mesh, name=name or Path(path).stem, density=density, seed=seed)
