"""Read and write GRAB-layout ``.npz`` sequences (docs/contract.md, "Data on disk"), safely.

On-disk layout written by :func:`write_grab` (every dict is a 0-d object array, read
back with ``.item()`` exactly like GRAB's files)::

    gender, sbj_id, obj_name, motion_intent, body_model   0-d str arrays
    framerate (float), n_frames (int), n_comps (int = 45)  0-d arrays
    body    = {'params': {global_orient (T,3), body_pose (T,63), transl (T,3),
                          right_hand_pose (T,45), left_hand_pose (T,45), jaw_pose (T,3),
                          leye_pose (T,3), reye_pose (T,3), expression (T,10),
                          fullpose (T,165)},
               'vtemp': str | None, 'flat_hand_mean': True,
               ['height': float], ['hand_scale': float]}
    rhand/lhand = {'params': {global_orient (T,3), hand_pose (T,45), transl (T,3),
                              fullpose (T,48)}, 'vtemp': str | None, 'flat_hand_mean': True}
    object  = {'params': {global_orient (T,3), transl (T,3)}, 'object_mesh': str | None}
    table   = {'params': {global_orient (T,3), transl (T,3)}, 'table_mesh': str | None}
    contact = {'object': (T, N_obj_verts) int, ['body': (T, N_body_verts) int]}

Mesh paths are relative to the data root (the folder holding ``grab/`` and ``tools/``),
as in GRAB. Reading never executes pickled code (:func:`grip_bench.core.safe_pickle.load_npz`).

Real GRAB files differ from what we write in four ways that :func:`read_grab` handles:
- ``framerate`` 120: subsampled to the working 30 fps by keeping every 4th frame
  (frames 0, 4, 8, ...; ``ceil(T / 4)`` frames remain).
- ``n_comps`` 24: hand poses are MANO PCA coefficients; they are expanded to full
  axis-angle through a :class:`ManoBackend` that the caller passes (the real MANO
  components are licensed, so there is no built-in fallback).
- hand means: a pose stored with ``flat_hand_mean=False`` is an offset from MANO's mean
  hand. GRAB's public code builds its MANO hands (``rhand``/``lhand``) with
  ``flat_hand_mean=True`` (the expanded pose is the full pose) and its SMPL-X bodies
  with smplx's default ``False`` (``body.params.*_hand_pose`` are offsets from the
  mean), so for files without a marker that is what is assumed, and the backend's
  ``hands_mean`` is added to the body's hand poses. A :class:`Sequence` always holds
  absolute poses (zero = flat hand), and :func:`write_grab` marks every part with
  ``'flat_hand_mean': True``, so our own files never need the mean.
  ``read_grab(..., flat_hand_mean=True|False)`` overrides the convention for unmarked files.
- hand ``transl``: MANO rotates a hand about its REST wrist joint ``J0 = J_regressor[0] @
  v_template`` (the subject's hand template ``rhand``/``lhand`` ``vtemp``), so in GRAB's
  files the world wrist is ``J0 + transl``. Inside the suite ``transl`` is the wrist itself
  (docs/architecture.md, "Conventions"), so the reader adds ``J0`` (float32-rounded, in
  float64: the hand ``transl`` of such a sequence is float64) and the writer subtracts it
  again. The header member ``hand_transl`` says which a file holds: ``"wrist"`` (the
  suite's; no conversion) or ``"mano"`` (GRAB's; each hand dict then also stores the
  ``rest_wrist`` J0 (3,) it was written with, so reading it back needs no model). A file
  without the member is a real GRAB file: ``"mano"`` for SMPL-X/MANO bodies, needing the
  MANO model (``mano_backend.rest_wrist``). Procedural files are never converted (their
  template wrist is at the origin, both conventions agree) and carry no marker.
  docs/real_grab.md has the details.

120 fps files are subsampled while they are read: the per-frame arrays inside the pickled
dicts are streamed from the zip member keeping only the working-rate rows
(:class:`_SubsamplingUnpickler`), so the peak memory is about the kept data, not twice the
unpacked file. PCA poses are expanded on the kept frames only.
"""

from __future__ import annotations

import hashlib
import io
import math
import os
import pickle
import re
import struct
import sys
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any, Protocol, runtime_checkable

import numpy as np

from ..core import constants as C
from ..core.errors import GripBenchError, InputError, MissingModelError
from ..core.io import atomic_file
from ..core.safe_pickle import RestrictedUnpickler, load_npz
from .sequence import PART_DIMS, Sequence, hand_fullpose

REQUIRED_KEYS = ("gender", "sbj_id", "obj_name", "motion_intent", "framerate", "n_frames",
                 "n_comps", "body", "lhand", "rhand", "object", "table", "contact")
# The hand-transl convention marker (module docstring): header member and its values.
HAND_TRANSL_KEY = "hand_transl"
TRANSL_WRIST, TRANSL_MANO = "wrist", "mano"
REST_WRIST_KEY = "rest_wrist"  # in a hand dict of a "mano" file written here: J0 (3,) m
OPTIONAL_HEADER_KEYS = ("body_model", HAND_TRANSL_KEY)
HEADER_KEYS = ("gender", "sbj_id", "obj_name", "motion_intent", "framerate", "n_frames",
               "n_comps", *OPTIONAL_HEADER_KEYS)
OBJECT_MESH_DIR = "tools/object_meshes/contact_meshes"
# Which mesh-path entry each part's dict carries (GRAB's names).
_MESH_KEY = {"body": "vtemp", "rhand": "vtemp", "lhand": "vtemp", "object": "object_mesh",
             "table": "table_mesh"}
_MESH_FIELD = {"body": "body_vtemp", "rhand": "rhand_vtemp", "lhand": "lhand_vtemp",
               "object": "object_mesh", "table": "table_mesh"}
# GRAB's hand-mean convention for files without a 'flat_hand_mean' marker (see above).
_FLAT_DEFAULT = {"body": False, "rhand": True, "lhand": True}
# Hand-pose arrays that may hold PCA coefficients, with their side.
_HAND_POSE_KEYS = (("rhand", "hand_pose", "right"), ("lhand", "hand_pose", "left"),
                   ("body", "right_hand_pose", "right"), ("body", "left_hand_pose", "left"))


@runtime_checkable
class ManoBackend(Protocol):
    """What :func:`read_grab` needs from a MANO model (implemented by the smplx backend).

    ``expand_pca(side, coeffs (T, n_comps)) -> (T, 45)``: ``coeffs @ components[:n_comps]``
    in MANO joint order, WITHOUT the mean pose. ``hands_mean(side) -> (45,)``: MANO's
    mean hand pose, used only for data fitted with ``flat_hand_mean=False``.
    """

    def expand_pca(self, side: str, coeffs: np.ndarray) -> np.ndarray: ...

    def hands_mean(self, side: str) -> np.ndarray: ...

    def rest_wrist(self, side: str, v_template: np.ndarray | None) -> np.ndarray:
        """MANO's rest wrist joint ``J_regressor[0] @ v_template`` (3,) m, of the subject
        template ``v_template (V, 3)`` or of the model's own template when None."""
        ...


# --- paths ---------------------------------------------------------------------
def object_mesh_relpath(obj_name: str) -> str:
    """GRAB's stored object mesh path, relative to the data root."""
    return f"{OBJECT_MESH_DIR}/{obj_name}.ply"


def object_mesh_path(data_dir: str | os.PathLike, obj_name: str) -> Path:
    """``DATA/tools/object_meshes/contact_meshes/<obj_name>.ply``."""
    return Path(data_dir) / object_mesh_relpath(obj_name)


def data_root_of(seq_path: str | os.PathLike) -> Path | None:
    """The data root of ``DATA/grab/s<k>/<file>.npz``, or None when the file is elsewhere.

    The path as given is tried first, without following symbolic links, so a subject folder
    ``grab/s1`` that links elsewhere still belongs to ``DATA``; then the fully resolved
    path (the file itself may link into a GRAB tree).
    """
    for p in (Path(os.path.abspath(seq_path)), Path(seq_path).resolve()):
        if len(p.parents) > 2 and p.parents[1].name == "grab":
            return p.parents[2]
    return None


def hand_template_path(rel: str | None, roots: Iterable[Path | None], where: str) -> Path | None:
    """The subject hand template a file names (``rhand``/``lhand`` ``vtemp``, relative to the
    data root as in GRAB), looked up under each data root in ``roots``; None when the file
    names none. Raises :class:`InputError` naming ``where`` when it is missing."""
    if not rel:
        return None
    roots = [Path(r) for r in roots if r is not None]
    if Path(rel).is_absolute() or not roots:
        candidates = [Path(rel)]
    else:
        candidates = [r / rel for r in roots]
    for c in candidates:
        if c.is_file():  # follows links: tools/subject_meshes may be a symbolic link
            return c
    raise InputError(f"subject hand template not found: {', '.join(map(str, candidates))}",
                     where)


def load_hand_template(rel: str | None, roots: Iterable[Path | None],
                       where: str) -> np.ndarray | None:
    """Vertices ``(V, 3)`` float32 (m) of the subject hand template ``rel`` (see
    :func:`hand_template_path`), or None when the file names none (the model's own)."""
    path = hand_template_path(rel, roots, where)
    if path is None:
        return None
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # noqa: BLE001 - trimesh raises many types for malformed files
        raise InputError(f"not a readable mesh ({type(e).__name__}: {e})", path) from e
    verts = np.asarray(mesh.vertices, np.float32)
    if verts.ndim != 2 or verts.shape[1] != 3 or len(verts) == 0:
        raise InputError(f"template vertices of shape {verts.shape}, expected (V, 3)", path)
    return verts


def resolve_object_mesh(seq: Sequence, data_dir: str | os.PathLike | None = None) -> Path:
    """Find the object mesh file of ``seq``: its stored path under the data root, else the
    standard location for ``obj_name``. Raises :class:`InputError` when none exists."""
    roots = [Path(r) for r in (data_dir, seq.source and data_root_of(seq.source)) if r]
    candidates = []
    if seq.object_mesh and Path(seq.object_mesh).is_absolute():
        candidates.append(Path(seq.object_mesh))
    for root in roots:
        if seq.object_mesh:
            candidates.append(root / seq.object_mesh)
        candidates.append(object_mesh_path(root, seq.obj_name))
    for c in candidates:
        if c.is_file():
            return c
    looked = ", ".join(str(c) for c in candidates) or "no data root known"
    raise InputError(f"object mesh not found (looked in: {looked})",
                     f"{seq.source or seq.name}: object.object_mesh")


def _natural_key(p: Path) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.as_posix())]


# GRAB's own ``save_grab_vertices.py`` writes ``<seq>_verts_{body,object,rhand,lhand}.npz``
# beside the sequences by default: vertex arrays, not sequences.
NOT_SEQUENCE_MARK = "_verts_"
_noted: set[str] = set()


def list_sequences(data_dir: str | os.PathLike) -> list[Path]:
    """All ``DATA/grab/s<k>/*.npz`` sequence files, in natural order (s2 before s10).

    Files GRAB's tools write beside the sequences (``*_verts_*.npz``) are skipped, with a
    one-line note on stderr per folder. A ``grab/`` folder passed instead of its parent is
    an error that names the folder to pass.
    """
    data_dir = Path(data_dir)
    root = data_dir / "grab"
    if not root.is_dir():
        if data_dir.name == "grab" and any(data_dir.glob("s*/*.npz")):
            raise InputError(f"this is the grab/ folder itself: pass its parent, "
                             f"{data_dir.resolve().parent}", data_dir)
        raise InputError("no grab/ folder (expected DATA/grab/s<k>/*.npz)", data_dir)
    found = [p for p in root.glob("s*/*.npz") if p.is_file()]
    files = [p for p in found if NOT_SEQUENCE_MARK not in p.stem]
    if len(files) < len(found) and str(root) not in _noted:
        _noted.add(str(root))
        print(f"note: {root}: skipped {len(found) - len(files)} file(s) that are not sequences "
              f"(GRAB's *{NOT_SEQUENCE_MARK}*.npz vertex files)", file=sys.stderr)
    return sorted(files, key=lambda p: _natural_key(p.relative_to(root)))


def dataset_hash(data_dir: str | os.PathLike, exclude: Iterable[str] = ("manifest.json",)) -> str:
    """sha256 hex digest over sorted relative paths and file bytes (streamed) of ``data_dir``.

    Each file contributes ``path \\0 size(8 bytes) bytes``, so renames and content changes
    both change the hash. Top-level names in ``exclude`` and hidden files are skipped
    (the manifest records this hash and cannot include itself).
    """
    root = Path(data_dir)
    if not root.is_dir():
        raise InputError("not a directory", data_dir)
    skip = set(exclude)
    files = sorted((p for p in root.rglob("*") if p.is_file()),
                   key=lambda p: p.relative_to(root).as_posix())
    h = hashlib.sha256()
    for p in files:
        rel = p.relative_to(root)
        if rel.as_posix() in skip or any(part.startswith(".") for part in rel.parts):
            continue
        h.update(rel.as_posix().encode() + b"\0" + p.stat().st_size.to_bytes(8, "little"))
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


# --- writing ---------------------------------------------------------------------
def _object_array(value: Any) -> np.ndarray:
    """0-d object array holding ``value`` (GRAB's way of storing dicts in an npz)."""
    a = np.empty((), dtype=object)
    a[()] = value
    return a


def _to_arrays(seq: Sequence) -> dict[str, np.ndarray]:
    """The npz members of ``seq`` (see the module docstring for the layout)."""
    out = {k: np.array(getattr(seq, k)) for k in ("gender", "sbj_id", "obj_name", "motion_intent")}
    out.update(framerate=np.array(float(seq.fps)), n_frames=np.array(seq.n_frames, dtype=np.int64),
               n_comps=np.array(C.N_HAND_POSE, dtype=np.int64), body_model=np.array(seq.body_model))
    for part, params in seq.parts().items():
        entry = {"params": dict(params), _MESH_KEY[part]: getattr(seq, _MESH_FIELD[part])}
        if part in _FLAT_DEFAULT:
            entry["flat_hand_mean"] = True  # a Sequence's hand poses are absolute
        if part == "body":
            entry.update({k: float(getattr(seq, k)) for k in ("height", "hand_scale")
                          if getattr(seq, k) is not None})
        out[part] = _object_array(entry)
    out["contact"] = _object_array(dict(seq.contact))
    return out


def write_grab(seq: Sequence, path: str | os.PathLike, *,
               mano_backend: ManoBackend | None = None) -> Path:
    """Validate ``seq`` and write it as a GRAB-layout ``.npz`` atomically (temp file + rename).

    Hands of a MANO-backed (SMPL-X) sequence are written in the suite's convention
    (``transl`` = wrist, header ``hand_transl = "wrist"``), or, with ``mano_backend``, in
    GRAB's own (``transl = wrist - J0``, header ``"mano"``, each hand dict holding the
    ``rest_wrist`` J0 used) for tools that read real GRAB files. Procedural sequences are
    written as they are, without a marker. Either way :func:`read_grab` gives back the same
    sequence (bit for bit for hands read from float32 files). Returns the written path; a
    crash mid-write leaves any previous file untouched.
    """
    path = Path(path)
    seq.validate(source=path)
    arrays = _to_arrays(seq)
    if seq.body_model != "procedural":
        arrays[HAND_TRANSL_KEY] = np.array(TRANSL_WRIST)
        if mano_backend is not None:
            _to_mano_transl(arrays, seq, path, mano_backend)
    with atomic_file(path) as f:
        np.savez_compressed(f, **arrays)
    return path


def _to_mano_transl(arrays: dict[str, np.ndarray], seq: Sequence, path: Path,
                    backend: ManoBackend) -> None:
    """Rewrite the hand members of ``arrays`` in GRAB's convention (``transl - J0``).

    The difference is taken in float64 and stored in the dtype of the hand's other
    parameters: for a hand read from a float32 GRAB file that gives back its exact bytes.
    """
    roots = (seq.source and data_root_of(seq.source), data_root_of(path))
    for part, side in (("rhand", "right"), ("lhand", "left")):
        entry = dict(arrays[part].item())
        where = f"{path}: {part}.vtemp"
        j0 = _model_rest_wrist(backend, side, getattr(seq, _MESH_FIELD[part]), roots, where)
        params = dict(entry["params"])
        dtype = params["global_orient"].dtype
        params["transl"] = (np.asarray(params["transl"], np.float64) - j0).astype(dtype)
        entry.update(params=params, **{REST_WRIST_KEY: j0})
        arrays[part] = _object_array(entry)
    arrays[HAND_TRANSL_KEY] = np.array(TRANSL_MANO)


# --- reading: scalars ------------------------------------------------------------------
def _as_str(value: Any, where: str) -> str:
    if isinstance(value, np.ndarray) and value.shape == () and value.dtype.kind in "US":
        value = value.item()
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if not isinstance(value, str):
        raise InputError(f"should be a string, got {_describe(value)}", where)
    return value


def _as_number(value: Any, where: str, integer: bool = False) -> float | int:
    if isinstance(value, np.ndarray) and value.size == 1 and value.dtype.kind in "iuf":
        value = value.reshape(()).item()
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise InputError(f"should be a finite number, got {_describe(value)}", where)
    if integer:
        if float(value) != int(value):
            raise InputError(f"should be an integer, got {value!r}", where)
        return int(value)
    return float(value)


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape} and dtype {value.dtype}"
    return f"{type(value).__name__} {value!r}"[:80]


def _read_header_members(path: Path) -> dict[str, Any]:
    """Read only the small scalar members, without unpickling anything."""
    out: dict[str, Any] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            for key in HEADER_KEYS:
                if f"{key}.npy" in names:
                    with zf.open(f"{key}.npy") as f:
                        out[key] = np.lib.format.read_array(f, allow_pickle=False)
    except ValueError:
        # an object-dtype scalar: let the restricted unpickler handle the whole file
        raw = load_npz(path)
        return {k: raw[k] for k in HEADER_KEYS if k in raw}
    except Exception as e:  # noqa: BLE001 - BadZipFile, OSError, EOFError, zlib.error...
        raise InputError(f"not a readable .npz archive ({type(e).__name__}: {e})", path) from e
    return out


def _parse_header(raw: dict[str, Any], path: Path) -> dict[str, Any]:
    """Typed scalar fields of a GRAB file; raises InputError naming the key."""
    w = lambda k: f"{path}: {k}"  # noqa: E731
    for key in HEADER_KEYS:
        if key not in raw and key not in OPTIONAL_HEADER_KEYS:
            raise InputError("missing key", w(key))
    hdr: dict[str, Any] = {k: _as_str(raw[k], w(k)) for k in ("gender", "sbj_id", "obj_name",
                                                             "motion_intent")}
    hdr["framerate"] = _as_number(raw["framerate"], w("framerate"))
    hdr["n_frames"] = _as_number(raw["n_frames"], w("n_frames"), integer=True)
    hdr["n_comps"] = _as_number(raw["n_comps"], w("n_comps"), integer=True)
    # Real GRAB files have no body_model key: they are SMPL-X fits.
    hdr["body_model"] = (
        _as_str(raw["body_model"], w("body_model")) if "body_model" in raw else "smplx"
    )
    if hdr["n_frames"] < 1:
        raise InputError(f"should be >= 1, got {hdr['n_frames']}", w("n_frames"))
    if not 1 <= hdr["n_comps"] <= C.N_HAND_POSE:
        raise InputError(f"should be in 1..{C.N_HAND_POSE}, got {hdr['n_comps']}", w("n_comps"))
    hdr["step"] = _subsample_step(hdr["framerate"], w("framerate"))
    hdr[HAND_TRANSL_KEY] = _transl_convention(raw, hdr["body_model"], w(HAND_TRANSL_KEY))
    return hdr


def _transl_convention(raw: dict[str, Any], body_model: str, where: str) -> str:
    """What a file's hand ``transl`` is: ``"wrist"`` or ``"mano"`` (GRAB's, J0 + transl).

    Unmarked SMPL-X files are real GRAB files (``"mano"``); procedural hands have their
    template wrist at the origin, where both conventions agree (``"wrist"``).
    """
    value = _as_str(raw[HAND_TRANSL_KEY], where) if HAND_TRANSL_KEY in raw else None
    if value is not None and value not in (TRANSL_WRIST, TRANSL_MANO):
        raise InputError(f"should be {TRANSL_WRIST!r} or {TRANSL_MANO!r}, got {value!r}", where)
    if body_model == "procedural":
        return TRANSL_WRIST
    return value or TRANSL_MANO


def _subsample_step(framerate: float, where: str) -> int:
    """Frames to skip to reach the working rate (4 for GRAB's 120 fps, 1 for 30 fps)."""
    if framerate > C.MAX_SOURCE_FPS:  # also keeps a 1e12 "multiple" from becoming one frame
        raise InputError(f"frame rate {framerate:g} fps is implausible (more than "
                         f"{C.MAX_SOURCE_FPS:g} fps)", where)
    step = round(framerate / C.FPS) if framerate > 0 else 0
    if step < 1 or abs(step * C.FPS - framerate) > 1e-6 * framerate:
        raise InputError(f"frame rate {framerate:g} fps is not a whole multiple of the working "
                         f"rate {C.FPS:g} fps", where)
    return step


def read_grab_header(path: str | os.PathLike) -> dict[str, Any]:
    """Scalar fields of a GRAB file (object, subject, intent, framerate, n_frames at source
    rate, n_comps, body_model, hand_transl, step) without reading the motion: cheap, for
    listings and splits."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    return _parse_header(_read_header_members(path), path)


# --- reading: members, subsampled while they stream ---------------------------------
_CHUNK_BYTES = 4 << 20  # bytes of rows read at a time from a streamed per-frame array


class _Kept:
    """Rows ``0, step, 2 step, ...`` of a C-order array payload (``data``), ``shape`` kept."""

    __slots__ = ("data", "shape")

    def __init__(self, data: bytearray, shape: tuple[int, ...]):
        self.data, self.shape = data, shape


class _SubsamplingUnpickler(pickle._Unpickler):
    """Pickle's pure-Python unpickler behind :mod:`core.safe_pickle`'s class gate (data only:
    nothing in the file runs) that subsamples per-frame arrays while reading them.

    numpy pickles an array's state as ``(1, shape, dtype, is_fortran, raw bytes)``, so when
    the raw bytes arrive the shape and dtype are already on the stack: the payload of a
    C-order array whose leading dimension is ``n_frames`` is read ``_CHUNK_BYTES`` at a time
    keeping rows ``0, step, ...`` only, and the array is rebuilt from the kept rows, so the
    source-rate array is never in memory. ``ids`` collects the ``id`` of each such array.
    Any other payload is read as pickle reads it.
    """

    dispatch = dict(pickle._Unpickler.dispatch)

    def __init__(self, file: IO[bytes], *, n_frames: int, step: int, size: int, source: str):
        super().__init__(file, encoding="latin1")
        self._gate = RestrictedUnpickler(io.BytesIO(), source=source)
        self.n_frames, self.step, self.size = n_frames, step, size
        self.ids: set[int] = set()

    def find_class(self, module: str, name: str) -> Any:
        return self._gate.find_class(module, name)  # refuses all but plain data

    def _payload(self, n: int) -> None:
        if n > self.size:  # a length no larger than the member: nothing huge is allocated
            raise pickle.UnpicklingError(f"a payload of {n} bytes in a member of {self.size}")
        rows = self._frame_rows(n)
        self.append(self.read(n) if rows is None else self._kept(rows, n // self.n_frames))

    def _frame_rows(self, n: int) -> tuple[int, ...] | None:
        """The array shape when the payload of ``n`` bytes is a per-frame array's, else None."""
        st = self.stack
        if self.step == 1 or len(st) < 4 or type(st[-4]) is not int or st[-1] is not False:
            return None
        shape, dtype = st[-3], st[-2]
        if not (isinstance(dtype, np.dtype) and not dtype.hasobject and isinstance(shape, tuple)
                and shape and all(type(k) is int and k >= 0 for k in shape)):
            return None
        ok = shape[0] == self.n_frames and math.prod(shape) * dtype.itemsize == n and n > 0
        return shape if ok else None

    def _kept(self, shape: tuple[int, ...], row: int) -> _Kept:
        """Read the ``(n_frames, ...)`` payload, keeping every ``step``-th row."""
        n_kept = len(range(0, self.n_frames, self.step))
        out = bytearray(n_kept * row)
        kept = np.frombuffer(out, np.uint8).reshape(n_kept, row)
        per_chunk = max(1, _CHUNK_BYTES // row // self.step) * self.step
        for start in range(0, self.n_frames, per_chunk):
            count = min(per_chunk, self.n_frames - start)
            data = self.read(count * row)
            if len(data) != count * row:
                raise pickle.UnpicklingError("pickle data was truncated")
            rows = np.frombuffer(data, np.uint8).reshape(count, row)[:: self.step]
            kept[start // self.step: start // self.step + len(rows)] = rows
        return _Kept(out, (n_kept, *shape[1:]))

    def load_binbytes(self) -> None:
        self._payload(struct.unpack("<I", self.read(4))[0])

    def load_binbytes8(self) -> None:
        self._payload(struct.unpack("<Q", self.read(8))[0])

    def load_build(self) -> None:
        st = self.stack
        state = st[-1]
        if not (isinstance(state, tuple) and len(state) == 5 and isinstance(state[4], _Kept)
                and len(st) > 1 and type(st[-2]) is np.ndarray):
            super().load_build()
            return
        st.pop()
        kept, dtype, old = state[4], state[2], st[-1]
        new = np.frombuffer(kept.data, dtype).reshape(kept.shape)
        st[-1] = new
        for k, v in list(self.memo.items()):  # later references to the array get it too
            if v is old:
                self.memo[k] = new
        self.ids.add(id(new))

    dispatch[pickle.BINBYTES[0]] = load_binbytes
    dispatch[pickle.BINBYTES8[0]] = load_binbytes8
    dispatch[pickle.BUILD[0]] = load_build


def _read_member(f: IO[bytes], size: int, n_frames: int, step: int, where: str,
                 ids: set[int]) -> Any:
    """One ``.npy`` member streamed from the archive (object arrays through
    :class:`_SubsamplingUnpickler`); 0-d object arrays are unwrapped (``.item()``)."""
    version = np.lib.format.read_magic(f)
    if version not in ((1, 0), (2, 0)):  # 3.0 (utf-8 field names) never holds GRAB data
        raise InputError(f".npy format version {version} is not supported", where)
    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                   else np.lib.format.read_array_header_2_0)
    shape, fortran, dtype = read_header(f)
    if dtype.hasobject:
        up = _SubsamplingUnpickler(f, n_frames=n_frames, step=step, size=size, source=where)
        arr = up.load()
        ids |= up.ids
        return arr.item() if isinstance(arr, np.ndarray) and arr.shape == () else arr
    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if nbytes > size:
        raise InputError(f"header declares shape {shape} of {dtype} ({nbytes} bytes), more "
                         f"than the member's {size} bytes", where)
    buf = bytearray(nbytes)
    if f.readinto(buf) != nbytes:
        raise InputError("array data is truncated", where)
    return np.frombuffer(buf, dtype).reshape(shape, order="F" if fortran else "C")


def _stream_members(path: Path, n_frames: int, step: int) -> tuple[dict[str, Any], set[int]]:
    """Every member of a GRAB ``.npz``, with the per-frame arrays inside its pickled dicts
    already subsampled by ``step`` (their ids are returned): peak memory ~ the kept data."""
    out: dict[str, Any] = {}
    ids: set[int] = set()
    try:
        zf = zipfile.ZipFile(path)
    except Exception as e:  # noqa: BLE001 - BadZipFile, OSError, or worse from crafted bytes
        raise InputError(f"not a readable .npz archive ({type(e).__name__}: {e})", path) from e
    with zf:
        for info in zf.infolist():
            key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            where = f"{path}: {key}"
            try:
                with zf.open(info) as f:
                    out[key] = _read_member(f, info.file_size, n_frames, step, where, ids)
                    while f.read(_CHUNK_BYTES):  # to the end, where the zip checks the CRC
                        pass
            except GripBenchError:
                raise
            except Exception as e:  # noqa: BLE001 - any parse failure of untrusted bytes
                raise InputError(f"corrupt array ({type(e).__name__}: {e})", where) from e
    return out, ids


def _load_members(path: Path, hdr: dict[str, Any]) -> tuple[dict[str, Any], set[int]]:
    """The file's members and the ids of arrays already at the working rate.

    Files at the working rate keep every byte, so they go through the shared loader
    (:func:`core.safe_pickle.load_npz`); faster ones are subsampled while streaming.
    """
    if hdr["step"] == 1:
        return load_npz(path), set()
    return _stream_members(path, hdr["n_frames"], hdr["step"])


# --- reading: parameters ----------------------------------------------------------------
def _part_dict(raw: dict[str, Any], part: str, path: Path) -> dict[str, Any]:
    entry = raw[part]
    if not isinstance(entry, dict):
        raise InputError(f"should hold a dict (a 0-d object array, as GRAB stores it), "
                         f"got {_describe(entry)}", f"{path}: {part}")
    return entry


def _widths(part: str, key: str, n_comps: int) -> tuple[int, ...]:
    """Accepted widths of one stored parameter (hand poses may be PCA, hand fullpose 45/48)."""
    if any(part == p and key == k for p, k, _ in _HAND_POSE_KEYS):
        return tuple(sorted({n_comps, C.N_HAND_POSE}))
    if part in ("rhand", "lhand") and key == "fullpose":
        return (C.N_HAND_POSE, C.N_HAND_POSE + 3)
    return (PART_DIMS[part][key],)


def _source_shape(a: np.ndarray, hdr: dict, ids: set[int]) -> tuple[int, ...]:
    """The shape ``a`` has in the file (a streamed array has lost all but its kept rows)."""
    return (hdr["n_frames"], *a.shape[1:]) if id(a) in ids else a.shape


def _working_rate(a: np.ndarray, hdr: dict, ids: set[int]) -> np.ndarray:
    """Frames ``0, step, ...`` of a per-frame array (a copy, so no strided view keeps the
    source-rate array alive); streamed arrays already are."""
    return a if id(a) in ids or hdr["step"] == 1 else a[:: hdr["step"]].copy()


def _check_finite(a: np.ndarray, step: int, where: str) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        raise InputError(f"{int(bad.sum())} non-finite values (first at frame "
                         f"{int(np.argwhere(bad)[0, 0]) * step})", where)


def _params(entry: dict, part: str, hdr: dict, path: Path,
            ids: set[int]) -> dict[str, np.ndarray]:
    """The ``params`` arrays of one part at the working rate, checked for presence, dtype,
    shape and finiteness (before any model is needed, so a malformed file fails on its own
    terms). Non-finite values in frames that subsampling drops are not looked at."""
    params = entry.get("params")
    if not isinstance(params, dict):
        what = "missing key" if params is None else f"should be a dict, got {_describe(params)}"
        raise InputError(what, f"{path}: {part}.params")
    out, n_frames = {}, hdr["n_frames"]
    for key in PART_DIMS[part]:
        where = f"{path}: {part}.params.{key}"
        if key not in params:
            raise InputError("missing key", where)
        a = params[key]
        if not isinstance(a, np.ndarray) or a.dtype.kind not in "fiu":
            raise InputError(f"should be a numeric array, got {_describe(a)}", where)
        widths = _widths(part, key, hdr["n_comps"])
        shape = _source_shape(a, hdr, ids)
        if len(shape) != 2 or shape[0] != n_frames or shape[1] not in widths:
            want = " or ".join(f"(n_frames={n_frames}, {w})" for w in widths)
            raise InputError(f"shape {shape} should be {want}", where)
        a = _working_rate(a, hdr, ids)
        _check_finite(a, hdr["step"], where)
        out[key] = a if a.dtype.kind == "f" else a.astype(np.float64)
    return out


def _optional_path(entry: dict, key: str, where: str) -> str | None:
    value = entry.get(key)
    if value is None:
        return None
    return _as_str(value, where)


def _optional_float(entry: dict, key: str, where: str) -> float | None:
    return None if entry.get(key) is None else _as_number(entry[key], where)


def _contact(raw: dict[str, Any], hdr: dict, path: Path, ids: set[int]) -> dict[str, np.ndarray]:
    """GRAB's contact labels at the working rate, ``{key: (T, N_verts) int}``."""
    entry, n_frames = raw["contact"], hdr["n_frames"]
    if not isinstance(entry, dict):
        raise InputError(f"should hold a dict, got {_describe(entry)}", f"{path}: contact")
    out = {}
    for key, labels in entry.items():
        where = f"{path}: contact.{key}"
        shape = _source_shape(labels, hdr, ids) if isinstance(labels, np.ndarray) else None
        if shape is None or len(shape) != 2 or shape[0] != n_frames:
            raise InputError(
                f"shape {shape or np.shape(labels)} should be (n_frames={n_frames}, N_verts)",
                where)
        labels = _working_rate(labels, hdr, ids)
        if labels.dtype.kind == "f":  # some exports store labels as floats: accept whole numbers
            if not (np.isfinite(labels).all() and (labels == np.round(labels)).all()):
                raise InputError("contact labels should be whole numbers", where)
            labels = labels.astype(np.int32)
        out[str(key)] = labels
    return out

# --- reading: hand poses -----------------------------------------------------------------
def _flat_flags(entries: dict[str, dict], override: bool | None, path: Path) -> dict[str, bool]:
    """Per part: are its hand poses absolute (True) or offsets from MANO's mean (False)?"""
    flags = {}
    for part, default in _FLAT_DEFAULT.items():
        marker = entries[part].get("flat_hand_mean")
        if marker is not None and not isinstance(marker, bool | np.bool_):
            raise InputError(f"should be True or False, got {_describe(marker)}",
                             f"{path}: {part}.flat_hand_mean")
        flags[part] = bool(marker) if marker is not None else (
            default if override is None else bool(override))
    return flags


def _full_hand_poses(parts: dict[str, dict], n_comps: int, backend: ManoBackend | None,
                     flat: dict[str, bool], path: Path) -> None:
    """Replace PCA hand poses by full axis-angle (T, 45) in place; add the mean where not flat."""
    changed = set()
    for part, key, side in _HAND_POSE_KEYS:
        where = f"{path}: {part}.params.{key}"
        pose = parts[part][key]
        if pose.shape[1] == C.N_HAND_POSE:
            full = pose
        elif pose.shape[1] == n_comps:
            full = _expand(backend, side, pose, where)
            changed.add(part)
        else:
            raise InputError(f"shape {pose.shape} should be (T, n_comps={n_comps}) or "
                             f"(T, {C.N_HAND_POSE})", where)
        if not flat[part]:
            full = full + _hands_mean(backend, side, where).astype(full.dtype)
            changed.add(part)
        parts[part][key] = full
    for part in ("rhand", "lhand"):
        _hand_fullpose_48(parts[part], part in changed, f"{path}: {part}.params.fullpose")


def _hand_fullpose_48(p: dict[str, np.ndarray], changed: bool, where: str) -> None:
    """Make the hand ``fullpose`` (T, 48) = wrist + fingers. GRAB files may store it
    without the wrist (T, 45); it is rebuilt whenever the finger pose was rewritten."""
    width = p["fullpose"].shape[1]
    if width not in (C.N_HAND_POSE, C.N_HAND_POSE + 3):
        raise InputError(f"shape {p['fullpose'].shape} should be (T, 48) or (T, 45)", where)
    if changed or width == C.N_HAND_POSE:
        p["fullpose"] = hand_fullpose(p["global_orient"], p["hand_pose"])


def _expand(backend: ManoBackend | None, side: str, coeffs: np.ndarray, where: str) -> np.ndarray:
    if backend is None:
        raise MissingModelError(
            f"hand poses are {coeffs.shape[1]} MANO PCA coefficients; expanding them to full "
            "axis-angle needs the MANO model: pass a MANO backend (--model-path)", where)
    full = np.asarray(backend.expand_pca(side, coeffs))
    if full.shape != (coeffs.shape[0], C.N_HAND_POSE):
        raise InputError(f"MANO backend returned shape {full.shape}, expected "
                         f"({coeffs.shape[0]}, {C.N_HAND_POSE})", where)
    return full.astype(coeffs.dtype, copy=False)


def _hands_mean(backend: ManoBackend | None, side: str, where: str) -> np.ndarray:
    if backend is None:
        raise MissingModelError("these hand poses are offsets from MANO's mean hand "
                                "(flat_hand_mean=False, GRAB's SMPL-X convention); adding the "
                                "mean needs the MANO model: pass a MANO backend (--model-path), "
                                "or flat_hand_mean=True if the poses are absolute", where)
    return np.asarray(backend.hands_mean(side)).reshape(C.N_HAND_POSE)


# --- reading: hand transl -----------------------------------------------------------------
def _model_rest_wrist(backend: ManoBackend, side: str, rel: str | None,
                      roots: Iterable[Path | None], where: str) -> np.ndarray:
    """J0 (3,) float64 of the subject template ``rel`` (or MANO's own), rounded to float32
    so that ``transl32 + J0`` and back are exact in float64."""
    template = load_hand_template(rel, roots, where)
    j0 = np.asarray(backend.rest_wrist(side, template), dtype=np.float64)
    if j0.shape != (3,) or not np.isfinite(j0).all():
        raise InputError(f"MANO backend returned a rest wrist of shape {j0.shape}, expected (3,) "
                         "finite", where)
    return j0.astype(np.float32).astype(np.float64)


def _stored_rest_wrist(entry: dict, where: str) -> np.ndarray | None:
    """The J0 a file written by :func:`write_grab` stores beside GRAB-convention hands."""
    value = entry.get(REST_WRIST_KEY)
    if value is None:
        return None
    a = np.asarray(value) if isinstance(value, np.ndarray | list | tuple) else None
    if a is None or a.shape != (3,) or a.dtype.kind not in "fiu" or not np.isfinite(a).all():
        raise InputError(f"should be 3 finite numbers (m), got {_describe(value)}", where)
    return a.astype(np.float64)


def _to_wrist_transl(parts: dict[str, dict], entries: dict[str, dict], backend: ManoBackend | None,
                     path: Path) -> None:
    """GRAB's hand ``transl`` -> the wrist position ``transl + J0`` (float64), in place."""
    for part, side in (("rhand", "right"), ("lhand", "left")):
        j0 = _stored_rest_wrist(entries[part], f"{path}: {part}.{REST_WRIST_KEY}")
        if j0 is None:
            if backend is None:
                raise MissingModelError(
                    "hand transl is GRAB's (MANO's wrist is at J0 + transl); turning it into "
                    "the wrist position needs the MANO model's rest wrist J0: pass a MANO "
                    "backend (--model-path)", f"{path}: {part}.params.transl")
            rel = _optional_path(entries[part], "vtemp", f"{path}: {part}.vtemp")
            j0 = _model_rest_wrist(backend, side, rel, [data_root_of(path)],
                                   f"{path}: {part}.vtemp")
        parts[part]["transl"] = np.asarray(parts[part]["transl"], np.float64) + j0


# --- reading: the whole file ---------------------------------------------------------------
def read_grab(path: str | os.PathLike, *, mano_backend: ManoBackend | None = None,
              flat_hand_mean: bool | None = None) -> Sequence:
    """Read a GRAB-layout ``.npz`` into a validated :class:`Sequence` at 30 fps.

    See the module docstring for subsampling, PCA expansion, ``flat_hand_mean``
    (None: each part's marker, else GRAB's convention; a bool overrides unmarked parts)
    and the hand ``transl`` convention (the returned hands' ``transl`` is the wrist).
    Every malformed input raises a one-line :class:`InputError` (or
    :class:`UnsafeFileError` for pickled code, :class:`MissingModelError` for PCA poses
    or GRAB-convention hands without ``mano_backend``) naming the file and key.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    hdr = _parse_header(_read_header_members(path), path)
    raw, ids = _load_members(path, hdr)
    for key in REQUIRED_KEYS:
        if key not in raw:
            raise InputError("missing key", f"{path}: {key}")
    entries = {part: _part_dict(raw, part, path) for part in PART_DIMS}
    parts = {part: _params(entries[part], part, hdr, path, ids) for part in PART_DIMS}
    contact = _contact(raw, hdr, path, ids)
    del raw  # members not kept (the source-rate arrays of unstreamed files) can go now
    flat = _flat_flags(entries, flat_hand_mean, path)
    _full_hand_poses(parts, hdr["n_comps"], mano_backend, flat, path)
    if hdr[HAND_TRANSL_KEY] == TRANSL_MANO:
        _to_wrist_transl(parts, entries, mano_backend, path)
    meshes = {_MESH_FIELD[part]: _optional_path(entries[part], _MESH_KEY[part],
                                                f"{path}: {part}.{_MESH_KEY[part]}")
              for part in PART_DIMS}
    seq = Sequence(
        name=f"{path.parent.name}/{path.stem}", sbj_id=hdr["sbj_id"], gender=hdr["gender"],
        obj_name=hdr["obj_name"], motion_intent=hdr["motion_intent"], fps=C.FPS,
        body_model=hdr["body_model"], contact=contact, source=path, **parts, **meshes,
        height=_optional_float(entries["body"], "height", f"{path}: body.height"),
        hand_scale=_optional_float(entries["body"], "hand_scale", f"{path}: body.hand_scale"),
    )
    return seq.validate(source=path)


class MANOModelBackend:
    """:class:`ManoBackend` from the licensed MANO files (PCA components, mean, and the rest
    wrist from the joint regressor and template).

    Reads ``<model_path>/mano/MANO_{RIGHT,LEFT}.{pkl,npz}`` through the smplx backend's
    safe loaders; the ``smplx`` package itself is not needed for this.
    """

    def __init__(self, model_path: str | os.PathLike | None):
        self.model_path = model_path
        self._data: dict[str, dict[str, np.ndarray]] = {}

    def _side(self, side: str) -> dict[str, np.ndarray]:
        """The side's arrays, loaded on first use (a file that needs no model never asks)."""
        if side not in self._data:
            from ..bodies import smplx_backend as sb

            self._data[side] = sb.load_model_data(self._path(side), {"hands_components": (45,),
                                                                    "hands_mean": None})
        return self._data[side]

    def _path(self, side: str) -> Path:
        from ..bodies import smplx_backend as sb

        return sb.find_model_file(self.model_path, "mano", side)

    def expand_pca(self, side: str, coeffs: np.ndarray) -> np.ndarray:
        comps = self._side(side)["hands_components"].reshape(-1, C.N_HAND_POSE)
        if coeffs.shape[1] > comps.shape[0]:
            raise InputError(f"{coeffs.shape[1]} PCA coefficients, the model has {comps.shape[0]}",
                             "hand_pose")
        return np.asarray(coeffs, float) @ comps[: coeffs.shape[1]]

    def hands_mean(self, side: str) -> np.ndarray:
        return self._side(side)["hands_mean"].reshape(C.N_HAND_POSE)

    def rest_wrist(self, side: str, v_template: np.ndarray | None) -> np.ndarray:
        from ..bodies import smplx_backend as sb

        return sb.mano_rest_wrist(self._side(side), v_template, self._path(side))


def load_mano_backend(model_path: str | os.PathLike | None) -> ManoBackend:
    """The MANO backend for ``model_path`` (or ``$GRIP_BENCH_MODEL_PATH`` when None)."""
    return MANOModelBackend(model_path)
