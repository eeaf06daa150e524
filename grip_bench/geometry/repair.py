"""Explicit, measured repair of object meshes into watertight solids (docs/meshes.md).

Exact intersection volume (manifold3d), signed distances (libigl) and the sensors need a
closed, consistently wound surface. :func:`repair` makes one from whatever came in, in
order, stopping at the first step that gives a watertight solid:

1. weld vertices by position (texture seams split them), drop degenerate / duplicate faces;
2. surface repair: consistent outward winding, fan-close holes smaller than
   ``MAX_HOLE_FRACTION`` of the bounding-box diagonal, union overlapping closed shells;
3. otherwise (open beyond that, non-manifold, self-intersecting): rebuild the surface as the
   0.5 level set of the input's generalized winding number, signed distance magnitudes,
   marching cubes on a sparse octree grid of cell ``tolerance x MESH_REPAIR_CELL_FRACTION``
   (coarser only when ``MESH_REPAIR_MAX_NODES`` would be exceeded), and drop shells holding
   less than ``MESH_REPAIR_MIN_SHELL`` of the volume.

Every repair is measured: the two-sided distance between the input and the repaired
surface from ``MESH_REPAIR_SAMPLES`` area-uniform samples each way (input samples covered
by another part of the input, i.e. walls inside the solid such as the inner halves of
overlapping shells, are counted apart: a union removes them by design). A repair whose
largest distance exceeds the tolerance is an :class:`InputError` naming ``--accept-repair``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time

import numpy as np
import trimesh

from ..core import constants
from ..core.errors import InputError

__all__ = ["MeshOptions", "RepairReport", "repair", "surface_distances"]

Where = str | os.PathLike | None

# igl.marching_cubes corner order of a cube (x fastest), as its dense version uses
_CORNERS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                     [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=np.int64)
_CHILDREN = np.indices((2, 2, 2)).reshape(3, -1).T.astype(np.int64)


@dataclasses.dataclass(frozen=True)
class MeshOptions:
    """How object meshes are taken in (``--mesh-scale``, ``--accept-repair``).

    scale: coordinates are multiplied by it; None = not given, then the units check refuses
    meshes whose size suggests millimetres or centimetres. accept_repair_mm: the largest
    repair distance accepted (mm).
    """

    scale: float | None = None
    accept_repair_mm: float = constants.MESH_REPAIR_TOLERANCE_MM

    def __post_init__(self) -> None:
        if self.scale is not None and not (math.isfinite(self.scale) and self.scale > 0):
            raise InputError(f"must be a positive number, got {self.scale}", "--mesh-scale")
        if not (math.isfinite(self.accept_repair_mm) and self.accept_repair_mm > 0):
            raise InputError(f"must be a positive number of mm, got {self.accept_repair_mm}",
                             "--accept-repair")

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass
class RepairReport:
    """What a repair did and how far it moved the surface (distances in mm).

    method: "none" (already watertight), "welded" (seams / degenerate faces only),
    "surface" (winding, small holes, union of shells) or "winding-number" (rebuilt).
    max_mm / mean_mm: two-sided surface distance (largest of both directions / mean of all
    samples); input_to_repaired_max_mm and repaired_to_input_max_mm: each direction;
    hidden_input_fraction: share of input samples inside the solid (not measured).
    """

    source: str
    method: str
    faces_in: int
    faces_out: int
    welded_vertices: int = 0
    dropped_faces: int = 0
    closed_holes: int = 0
    shells_in: int = 0
    shells_out: int = 0
    dropped_shells: int = 0
    cell_mm: float | None = None
    max_mm: float = 0.0
    mean_mm: float = 0.0
    input_to_repaired_max_mm: float = 0.0
    repaired_to_input_max_mm: float = 0.0
    hidden_input_fraction: float = 0.0
    tolerance_mm: float = constants.MESH_REPAIR_TOLERANCE_MM
    seconds: float = 0.0
    reason: str = ""
    cached: bool = False

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    def line(self) -> str:
        """One stderr line: ``mesh <file>: <method> ...``."""
        parts = [f"mesh {self.source}: {self.method}"]
        if self.reason:
            parts.append(f"({self.reason})")
        counts = [f"{n} {what}" for n, what in (
            (self.welded_vertices, "welded vertices"), (self.dropped_faces, "dropped faces"),
            (self.closed_holes, "closed holes"), (self.dropped_shells, "dropped shells")) if n]
        if counts:
            parts.append(", ".join(counts) + ";")
        parts.append(f"shells {self.shells_in} -> {self.shells_out};")
        if self.cell_mm is not None:
            parts.append(f"grid cell {self.cell_mm:.3g} mm;")
        parts.append(f"distance max {self.max_mm:.3f} mm, mean {self.mean_mm:.4f} mm "
                     f"(tolerance {self.tolerance_mm:g} mm); {self.seconds:.2f} s"
                     + (" (cached)" if self.cached else ""))
        return " ".join(parts)


# --- distances ---------------------------------------------------------------------


def _samples(mesh: trimesh.Trimesh, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform surface points (N, 3) and their face normals (N, 3), deterministic."""
    pts, face = trimesh.sample.sample_surface(mesh, count, seed=np.random.default_rng(seed))
    return np.asarray(pts, np.float64), np.asarray(mesh.face_normals)[face]


def _point_mesh_distance(points: np.ndarray, mesh: trimesh.Trimesh) -> np.ndarray:
    """Unsigned distance (N,) (m) of points (N, 3) to the triangles of ``mesh``."""
    import igl

    d2, _, _ = igl.point_mesh_squared_distance(
        np.ascontiguousarray(points, np.float64),
        np.ascontiguousarray(mesh.vertices, np.float64),
        np.ascontiguousarray(mesh.faces, np.int64))
    return np.sqrt(np.maximum(d2, 0.0))


def _covered(mesh: trimesh.Trimesh, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N,) bool: surface points of ``mesh`` that lie inside another part of it.

    Just off its own sheet a point's winding number is 0 and 1 on the two sides (1/2 on
    average); inside another closed part both gain ~1 (walls inside a union, duplicated
    inner shells). Exactly on a triangle igl counts that triangle as 0, hence the offsets.
    """
    import igl

    eps = 1e-3 * constants.MESH_REPAIR_TOLERANCE_MM * 1e-3
    q = np.concatenate([points + eps * normals, points - eps * normals])
    w = igl.fast_winding_number(np.ascontiguousarray(mesh.vertices, np.float64),
                                np.ascontiguousarray(mesh.faces, np.int64),
                                np.ascontiguousarray(q))
    return np.abs(w[: len(points)] + w[len(points):]) / 2 > 1.0


def surface_distances(
    source: trimesh.Trimesh, repaired: trimesh.Trimesh,
    count: int = constants.MESH_REPAIR_SAMPLES, seed: int = 0,
) -> dict[str, float]:
    """Two-sided distance (m) between an input surface and its repair, from samples.

    Returns ``max``, ``mean`` (over the samples of both directions), ``in_max``
    (input -> repaired, input samples inside the solid left out), ``out_max``
    (repaired -> input) and ``hidden`` (share of input samples left out).
    """
    p_in, n_in = _samples(source, count, seed)
    # the repaired vertices too: a fan's centre, the farthest point of a closed hole
    p_out = np.vstack([_samples(repaired, count, seed + 1)[0], repaired.vertices])
    hidden = _covered(source, p_in, n_in)
    d_in = _point_mesh_distance(p_in[~hidden], repaired)
    d_out = _point_mesh_distance(p_out, source)
    both = np.concatenate([d_in, d_out])
    in_max = float(d_in.max()) if d_in.size else 0.0
    return {"max": max(in_max, float(d_out.max())), "mean": float(both.mean()),
            "in_max": in_max, "out_max": float(d_out.max()), "hidden": float(hidden.mean())}


# --- step 1: weld ------------------------------------------------------------------


def _weld(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int, int]:
    """Merge vertices by position, drop degenerate and duplicate faces.

    Returns the mesh, the number of vertices welded or removed and of faces dropped.
    """
    nv, nf = len(mesh.vertices), len(mesh.faces)
    mesh = trimesh.Trimesh(mesh.vertices.copy(), mesh.faces.copy(), process=False)
    # position only: the mesh carries no normals or UVs, so seams weld
    mesh.merge_vertices(digits_vertex=round(-math.log10(constants.MERGE_TOL)))
    mesh.update_faces(mesh.nondegenerate_faces(height=constants.MERGE_TOL))
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    return mesh, nv - len(mesh.vertices), nf - len(mesh.faces)


# --- step 2: surface repair --------------------------------------------------------


class _NotSurfaceRepairable(Exception):
    """The mesh needs the volumetric rebuild; the message says why."""


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
                loops.append(path[seen[b]:])
                del path[seen[b]:]
                seen = {e[0]: i for i, e in enumerate(path)}
            seen[b] = len(path)
            a = b
        if path:
            loops.append(path)  # an unclosed chain: not a hole a fan can close
    return loops


def _close_small_holes(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int]:
    """Fan-fill each boundary loop from its centroid when all are small; else give up."""
    loops = _boundary_loops(np.asarray(mesh.faces))
    if not loops:
        return mesh, 0
    diag = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    limit = constants.MAX_HOLE_FRACTION * diag
    verts, faces = [np.asarray(mesh.vertices)], [np.asarray(mesh.faces)]
    n = len(mesh.vertices)
    for loop in loops:
        idx = np.array(loop)
        seg = mesh.vertices[idx[:, 1]] - mesh.vertices[idx[:, 0]]
        perimeter = float(np.linalg.norm(seg, axis=1).sum())
        if perimeter > limit or idx[0, 0] != idx[-1, 1]:
            raise _NotSurfaceRepairable(
                f"open: a hole with perimeter {perimeter * 1e3:.1f} mm ({len(loop)} edges) is over "
                f"the {limit * 1e3:.1f} mm a fan may close")
        verts.append(mesh.vertices[idx[:, 0]].mean(0, keepdims=True))
        # the fan triangle (b, a, c) runs the boundary edge a->b backwards, as its neighbour needs
        faces.append(np.column_stack([idx[:, 1], idx[:, 0], np.full(len(idx), n)]))
        n += 1
    return trimesh.Trimesh(np.vstack(verts), np.vstack(faces), process=False), len(loops)


def _union_shells(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Several closed shells: their union (overlaps would double-count volume and contact).

    Shells nested inside others (voids) stay: manifold3d keeps them as cavities.
    """
    import manifold3d

    from .meshes import from_manifold, to_manifold

    parts = mesh.split(only_watertight=False)
    if len(parts) <= 1:
        return mesh
    try:
        ms = [to_manifold(p) for p in parts]
    except InputError as e:
        raise _NotSurfaceRepairable(f"a shell is not a closed 2-manifold ({e.what})") from e
    union = manifold3d.Manifold.batch_boolean(ms, manifold3d.OpType.Add)
    if union.status() != manifold3d.Error.NoError or union.is_empty():
        raise _NotSurfaceRepairable(f"union of {len(parts)} shells failed")
    return from_manifold(union)


def _surface_repair(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int]:
    """Winding, small holes, union; (mesh, holes closed) or _NotSurfaceRepairable."""
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if (counts > 2).any():
        raise _NotSurfaceRepairable(f"{int((counts > 2).sum())} edges shared by more than two "
                                    "faces (non-manifold)")
    mesh = mesh.copy()
    trimesh.repair.fix_winding(mesh)
    mesh, holes = _close_small_holes(mesh)
    trimesh.repair.fix_normals(mesh, multibody=True)
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        raise _NotSurfaceRepairable("not watertight after closing holes (non-manifold vertices)")
    return _union_shells(mesh), holes


# --- step 3: winding-number rebuild ------------------------------------------------


def _grid_cell(mesh: trimesh.Trimesh, tolerance: float) -> float:
    """Finest cell (m): tolerance x MESH_REPAIR_CELL_FRACTION, coarser if the surface band
    (~3 area / cell^2 nodes) would exceed MESH_REPAIR_MAX_NODES."""
    # fit for the metrics whatever repair the caller accepts: never coarser than the default
    tolerance = min(tolerance, constants.MESH_REPAIR_TOLERANCE_MM * 1e-3)
    cell = tolerance * constants.MESH_REPAIR_CELL_FRACTION
    band_cell = math.sqrt(3.0 * float(mesh.area) / constants.MESH_REPAIR_MAX_NODES)
    return max(cell, band_cell)


class _Field:
    """The input's winding number and distance at query points (m)."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.v = np.ascontiguousarray(mesh.vertices, np.float64)
        self.f = np.ascontiguousarray(mesh.faces, np.int64)

    def inside(self, p: np.ndarray) -> np.ndarray:
        import igl

        return np.abs(igl.fast_winding_number(self.v, self.f, np.ascontiguousarray(p))) > 0.5

    def distance(self, p: np.ndarray) -> np.ndarray:
        import igl

        d2, _, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(p), self.v, self.f)
        return np.sqrt(np.maximum(d2, 0.0))


def _level(field: _Field, origin: np.ndarray, h: float, step: int, n_fine: np.ndarray,
           cubes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cubes (C, 3) of side ``step`` fine cells (integer corners in fine cells) that the
    surface or the winding-number level set may cross: corner signs differ, or the input
    surface is within half a diagonal of the centre.

    Returns the kept cubes, their corner node ids (K, 8) into the unique fine-grid nodes
    (N,) (flat indices) and the winding-number sign of those nodes (N,).
    """
    ids = np.ravel_multi_index((cubes[:, None, :] + step * _CORNERS[None]).reshape(-1, 3).T,
                               n_fine)
    nodes, inv = np.unique(ids, return_inverse=True)
    inside = field.inside(origin + h * np.stack(np.unravel_index(nodes, n_fine), 1))
    corners = inside[inv.reshape(-1, 8)]
    mixed = corners.any(1) != corners.all(1)
    centres = origin + (cubes + 0.5 * step) * h
    near = field.distance(centres) <= 0.5 * math.sqrt(3.0) * step * h * 1.01
    keep = mixed | near
    return cubes[keep], inv.reshape(-1, 8)[keep], nodes, inside


def _winding_rebuild(mesh: trimesh.Trimesh, tolerance: float
                     ) -> tuple[trimesh.Trimesh, float, int]:
    """Watertight surface at the input's winding number 1/2: (mesh, finest cell m, number of
    shells dropped).

    Octree refinement: a coarse grid (<= 32 cells a side) is split where the surface or the
    level set may pass, down to the finest cell; there the node values are the distance to
    the input signed by the winding number, so marching cubes interpolates the crossing
    within the cell.
    """
    import igl

    field = _Field(mesh)
    h = _grid_cell(mesh, tolerance)
    lo, hi = mesh.bounds[0] - 2 * h, mesh.bounds[1] + 2 * h
    levels = max(0, math.ceil(math.log2(float((hi - lo).max()) / (32 * h))))
    step = 2**levels
    n_coarse = np.ceil((hi - lo) / (h * step)).astype(np.int64)
    n_fine = n_coarse * step + 1
    cubes = np.indices(n_coarse).reshape(3, -1).T.astype(np.int64) * step
    while True:
        cubes, corner_ids, nodes, inside = _level(field, lo, h, step, n_fine, cubes)
        if step == 1:
            break
        step //= 2
        cubes = (cubes[:, None, :] + step * _CHILDREN[None]).reshape(-1, 3)
        if len(cubes) > 8 * constants.MESH_REPAIR_MAX_NODES:  # candidates: 8 per active parent
            raise InputError(f"the winding-number repair would need over "
                             f"{8 * constants.MESH_REPAIR_MAX_NODES} grid cells", None)
    used, corner_ids = np.unique(corner_ids, return_inverse=True)
    pts = lo + h * np.stack(np.unravel_index(nodes[used], n_fine), 1)
    # never exactly 0 at a node: marching cubes would emit coincident vertices there
    dist = np.maximum(field.distance(pts), 1e-9 * h)
    values = np.where(inside[used], -dist, dist)
    verts, faces, _ = igl.marching_cubes(values, pts, corner_ids.reshape(-1, 8).astype(np.int64),
                                         0.0)
    out = trimesh.Trimesh(verts, faces, process=False)
    if out.volume < 0:
        out.invert()
    out, dropped = _keep_shells(out)
    return out, h, dropped


def _keep_shells(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int]:
    """Drop shells enclosing a negligible share of the volume (specks of the level set)."""
    parts = mesh.split(only_watertight=False)
    vols = np.array([abs(p.volume) for p in parts])
    keep = vols >= constants.MESH_REPAIR_MIN_SHELL * vols.sum()
    if keep.all():
        return mesh, 0
    kept = trimesh.util.concatenate([p for p, k in zip(parts, keep, strict=True) if k])
    return kept, int((~keep).sum())


# --- the whole repair --------------------------------------------------------------


def _shell_count(mesh: trimesh.Trimesh) -> int:
    """Connected pieces (by shared vertices)."""
    return int(mesh.body_count)


def repair(mesh: trimesh.Trimesh, where: Where = None,
           tolerance_mm: float = constants.MESH_REPAIR_TOLERANCE_MM
           ) -> tuple[trimesh.Trimesh, RepairReport]:
    """Repair a raw mesh (float64 m) into a watertight outward solid; measure the change.

    Returns the mesh and its :class:`RepairReport`. Raises :class:`InputError` (naming
    ``where``) when no solid can be made or the repair moves the surface by more than
    ``tolerance_mm``.
    """
    start = time.perf_counter()
    source = str(where) if where is not None else "mesh"
    welded, n_welded, n_dropped = _weld(mesh)
    if len(welded.faces) == 0:
        raise InputError("mesh has no non-degenerate faces", where=where)
    report = RepairReport(source=source, method="none", faces_in=len(mesh.faces), faces_out=0,
                          welded_vertices=n_welded, dropped_faces=n_dropped,
                          shells_in=_shell_count(welded), tolerance_mm=tolerance_mm)
    try:
        out, report.closed_holes = _surface_repair(welded)
        changed = report.closed_holes > 0 or len(out.faces) != len(welded.faces)
        report.method = "surface" if changed else ("welded" if n_welded or n_dropped else "none")
    except _NotSurfaceRepairable as e:
        report.method, report.reason = "winding-number", str(e)
        try:
            out, cell, report.dropped_shells = _winding_rebuild(welded, tolerance_mm * 1e-3)
        except InputError as err:
            raise InputError(err.what, where=where) from err
        report.cell_mm = cell * 1e3
    if not out.is_watertight or len(out.faces) == 0:
        raise InputError(f"could not make a watertight surface ({report.reason or 'repair'})",
                         where=where)
    report.faces_out, report.shells_out = len(out.faces), _shell_count(out)
    if report.method in ("surface", "winding-number"):
        d = surface_distances(welded, out)
        report.max_mm, report.mean_mm = d["max"] * 1e3, d["mean"] * 1e3
        report.input_to_repaired_max_mm = d["in_max"] * 1e3
        report.repaired_to_input_max_mm = d["out_max"] * 1e3
        report.hidden_input_fraction = d["hidden"]
    report.seconds = time.perf_counter() - start
    if report.max_mm > tolerance_mm:
        raise InputError(
            f"repair ({report.method}{': ' + report.reason if report.reason else ''}) moves the "
            f"surface by up to {report.max_mm:.2f} mm, over the {tolerance_mm:g} mm tolerance; "
            f"to accept it pass --accept-repair {math.ceil(report.max_mm * 10) / 10:g} "
            "(predict, evaluate)", where=where)
    out.metadata["repair"] = report.as_dict()
    return out, report
