"""Object meshes: load, check units and size, repair (measured), cache; the ObjectAsset record.

Meshes leaving this module are watertight, consistently wound, outward-facing
``trimesh.Trimesh`` in float64 metres (docs/architecture.md). ``mesh.metadata`` keeps
``source`` (path), ``repairs`` (list of what was changed), ``repair`` (the
:class:`~grip_bench.geometry.repair.RepairReport` as a dict) and ``n_components``.
docs/meshes.md describes what is accepted.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from pathlib import Path

import manifold3d
import numpy as np
import trimesh

from grip_bench.core import constants
from grip_bench.core.errors import InputError

from . import cache as gcache
from .repair import MeshOptions, RepairReport, repair

__all__ = ["ObjectAsset", "MeshOptions", "load_object_mesh", "to_manifold", "from_manifold",
           "repair_mesh"]

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


def _check_file(path: Path) -> None:
    """The file exists, is not empty and has a supported suffix."""
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


def _read(path: Path) -> trimesh.Trimesh:
    """Read any supported file into one raw Trimesh (scenes flattened with their transforms)."""
    _check_file(path)
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


def _check_size(path: Path) -> None:
    """Refuse files declaring more than MESH_MAX_FACES faces before reading them whole."""
    faces = _declared_faces(path)
    if faces is not None and faces > constants.MESH_MAX_FACES:
        raise InputError(
            f"mesh has {faces} faces, over the {constants.MESH_MAX_FACES} this suite loads "
            "(memory guard, core.constants.MESH_MAX_FACES): decimate it first", where=path)
    size = path.stat().st_size
    if faces is None and size > constants.MESH_MAX_FILE_BYTES:
        raise InputError(
            f"mesh file is {size / 2**20:.0f} MiB, over the "
            f"{constants.MESH_MAX_FILE_BYTES / 2**20:.0f} MiB this suite loads (memory guard, "
            "core.constants.MESH_MAX_FILE_BYTES): decimate it first", where=path)


def _declared_faces(path: Path) -> int | None:
    """Face count from the header (PLY, OFF, binary STL) or a streaming count of face
    records (OBJ, ASCII STL) in constant memory; None for formats without one."""
    suffix = path.suffix.lower()
    with open(path, "rb") as f:
        head = f.read(4096)
        if suffix == ".ply":
            m = re.search(rb"element\s+face\s+(\d+)", head)
            return int(m.group(1)) if m else None
        if suffix == ".off":
            lines = [ln for ln in head.splitlines()[1:] if ln.strip() and not ln.startswith(b"#")]
            fields = lines[0].split() if lines else []
            return int(fields[1]) if len(fields) >= 2 and fields[1].isdigit() else None
        if suffix == ".stl" and not head.lstrip().startswith(b"solid"):
            return int.from_bytes(head[80:84], "little") if len(head) >= 84 else None
        if suffix not in (".obj", ".stl"):
            return None
        token = b"\nf " if suffix == ".obj" else b"facet"
        count, tail = head.startswith(token.lstrip(b"\n")), b""
        f.seek(0)
        for chunk in iter(lambda: f.read(1 << 20), b""):
            data = tail + chunk
            count += data.count(token)
            tail = data[-(len(token) - 1):]
        return int(count)


def _unit_hint(diag: float) -> str:
    """Name the unit a bounding-box diagonal (m) out of range most likely came from."""
    candidates = {"millimetres": 1e-3, "centimetres": 1e-2, "metres read as millimetres": 1e3}
    fits = {k: f for k, f in candidates.items()
            if constants.MIN_OBJECT_DIAG <= diag * f <= constants.MAX_OBJECT_DIAG}
    if not fits:
        return "no unit factor brings it to a hand-held size; pass --mesh-scale S to set one"
    unit = min(fits, key=lambda k: abs(math.log(diag * fits[k] / constants.TYPICAL_OBJECT_DIAG)))
    return f"looks like {unit}: pass --mesh-scale {fits[unit]:g}"


def _check_units(mesh: trimesh.Trimesh, where: str | os.PathLike | None) -> None:
    """Refuse a bounding-box diagonal outside [MIN_OBJECT_DIAG, MAX_OBJECT_DIAG] (m)."""
    diag = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    if diag > constants.MAX_OBJECT_DIAG:
        raise InputError(f"bounding-box diagonal {diag:.4g} (as metres) is over "
                         f"{constants.MAX_OBJECT_DIAG:g} m for a hand-held object; "
                         f"{_unit_hint(diag)}", where=where)
    if diag < constants.MIN_OBJECT_DIAG:
        raise InputError(f"bounding-box diagonal {diag:.4g} (as metres) is under "
                         f"{constants.MIN_OBJECT_DIAG * 1e3:g} mm for a hand-held object; "
                         f"{_unit_hint(diag)}", where=where)


def _check_not_flat(mesh: trimesh.Trimesh, where: str | os.PathLike | None) -> None:
    centred = mesh.vertices - mesh.vertices.mean(0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[-1] <= constants.FLAT_TOL * sv[0]:
        raise InputError("mesh is flat (all vertices in one plane): zero volume", where=where)


def _repairs(report: RepairReport) -> list[str]:
    """The report as short phrases (``mesh.metadata["repairs"]``)."""
    out = []
    if report.welded_vertices:
        out.append(f"merged/removed {report.welded_vertices} vertices")
    if report.dropped_faces:
        out.append(f"dropped {report.dropped_faces} degenerate or duplicate faces")
    if report.closed_holes:
        out.append(f"closed {report.closed_holes} small hole(s)")
    if report.method == "surface" and report.shells_out < report.shells_in:
        out.append(f"united {report.shells_in} watertight components")
    if report.method == "winding-number":
        out.append(f"rebuilt from the winding number ({report.reason})")
    return out


def repair_mesh(
    mesh: trimesh.Trimesh, where: str | os.PathLike | None = None,
    accept_repair_mm: float = constants.MESH_REPAIR_TOLERANCE_MM,
) -> trimesh.Trimesh:
    """Repair a raw mesh into a watertight outward-facing solid, or raise InputError.

    :func:`grip_bench.geometry.repair.repair` (weld, surface repair, else winding-number
    rebuild; measured against ``accept_repair_mm``), then the volume check.
    ``mesh.metadata``: ``repair`` (the report), ``repairs``, ``n_components``.
    """
    if len(mesh.faces) == 0:
        raise InputError("mesh has no faces", where=where)
    _check_not_flat(mesh, where)
    mesh, report = repair(mesh, where, accept_repair_mm)
    volume = float(mesh.volume)
    extent = float(np.ptp(mesh.vertices, axis=0).max())
    if not volume > constants.FLAT_TOL * extent**3:
        raise InputError(f"mesh encloses no volume ({volume:.3g} m^3)", where=where)
    mesh.metadata.update(repairs=_repairs(report), repair=report.as_dict(),
                         n_components=len(mesh.split(only_watertight=False)))
    return mesh


def _code_digest() -> bytes:
    """The source of the code a repaired mesh depends on (part of its cache key)."""
    from . import repair as repair_module

    files = (__file__, repair_module.__file__, constants.__file__)
    return b"".join(Path(f).read_bytes() for f in files)


def load_object_mesh(
    path: str | os.PathLike, scale: float = 1.0, options: MeshOptions | None = None
) -> trimesh.Trimesh:
    """Load an object mesh (OBJ, PLY, STL, GLB/glTF, OFF) as a watertight solid in metres.

    ``options`` (:class:`MeshOptions`): ``scale`` multiplies coordinates first (e.g. 0.001
    for a file in millimetres; without it the units check refuses implausible sizes),
    ``accept_repair_mm`` bounds the repair distance. ``scale`` != 1 is a shorthand for
    ``MeshOptions(scale=scale)``. The result is cached (file bytes, options, code); the
    report is ``mesh.metadata["repair"]`` (``cached`` True when read back). Raises
    InputError naming the file and the problem when it cannot be used.
    """
    path = Path(path)
    if options is None:
        options = MeshOptions(scale=None if scale == 1.0 else float(scale))
    _check_file(path)
    _check_size(path)
    key = gcache.bytes_key("repaired-mesh", (path.read_bytes(), _code_digest()),
                           options.as_dict())
    names = ("vertices", "faces", "metadata")
    arrays = gcache.load_arrays("repaired-mesh", key, names)
    cached = arrays is not None
    if arrays is None:
        arrays = _load_arrays(path, options)
        gcache.save_arrays("repaired-mesh", key, arrays)
    meta = json.loads(bytes(arrays["metadata"]).decode())
    mesh = trimesh.Trimesh(np.asarray(arrays["vertices"], np.float64),
                           np.asarray(arrays["faces"], np.int64), process=False)
    meta["repair"]["cached"] = cached
    mesh.metadata.update(meta, source=str(path))
    return mesh


def _load_arrays(path: Path, options: MeshOptions) -> dict[str, np.ndarray]:
    """Read, scale, check and repair ``path``: the arrays the cache keeps."""
    mesh = _read(path)
    if options.scale is not None:
        mesh.apply_scale(options.scale)
    else:
        _check_units(mesh, path)
    mesh = repair_mesh(mesh, where=path, accept_repair_mm=options.accept_repair_mm)
    meta = {k: mesh.metadata[k] for k in ("repairs", "repair", "n_components")}
    return {"vertices": np.asarray(mesh.vertices, np.float64),
            "faces": np.asarray(mesh.faces, np.int64),
            "metadata": np.frombuffer(json.dumps(meta).encode(), np.uint8)}


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
