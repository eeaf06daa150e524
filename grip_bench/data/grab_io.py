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

Real GRAB files differ from what we write in three ways that :func:`read_grab` handles:
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
"""

from __future__ import annotations

import hashlib
import os
import re
import sys
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..core import constants as C
from ..core.errors import InputError, MissingModelError
from ..core.io import atomic_file
from ..core.safe_pickle import load_npz
from .sequence import PART_DIMS, Sequence, hand_fullpose

REQUIRED_KEYS = ("gender", "sbj_id", "obj_name", "motion_intent", "framerate", "n_frames",
                 "n_comps", "body", "lhand", "rhand", "object", "table", "contact")
HEADER_KEYS = ("gender", "sbj_id", "obj_name", "motion_intent", "framerate", "n_frames",
               "n_comps", "body_model")
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


# --- paths ---------------------------------------------------------------------
def object_mesh_relpath(obj_name: str) -> str:
    """GRAB's stored object mesh path, relative to the data root."""
    return f"{OBJECT_MESH_DIR}/{obj_name}.ply"


def object_mesh_path(data_dir: str | os.PathLike, obj_name: str) -> Path:
    """``DATA/tools/object_meshes/contact_meshes/<obj_name>.ply``."""
    return Path(data_dir) / object_mesh_relpath(obj_name)


def data_root_of(seq_path: str | os.PathLike) -> Path | None:
    """The data root of ``DATA/grab/s<k>/<file>.npz``, or None when the file is elsewhere."""
    p = Path(seq_path).resolve()
    return p.parents[2] if len(p.parents) > 2 and p.parents[1].name == "grab" else None


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


def write_grab(seq: Sequence, path: str | os.PathLike) -> Path:
    """Validate ``seq`` and write it as a GRAB-layout ``.npz`` atomically (temp file + rename).

    Returns the written path. A crash mid-write leaves any previous file untouched.
    """
    path = Path(path)
    seq.validate(source=path)
    arrays = _to_arrays(seq)
    with atomic_file(path) as f:
        np.savez_compressed(f, **arrays)
    return path


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
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise InputError(f"not a readable .npz archive ({e})", path) from e
    return out


def _parse_header(raw: dict[str, Any], path: Path) -> dict[str, Any]:
    """Typed scalar fields of a GRAB file; raises InputError naming the key."""
    w = lambda k: f"{path}: {k}"  # noqa: E731
    for key in HEADER_KEYS[:-1]:
        if key not in raw:
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
    return hdr


def _subsample_step(framerate: float, where: str) -> int:
    """Frames to skip to reach the working rate (4 for GRAB's 120 fps, 1 for 30 fps)."""
    step = round(framerate / C.FPS) if framerate > 0 else 0
    if step < 1 or abs(step * C.FPS - framerate) > 1e-6 * framerate:
        raise InputError(f"frame rate {framerate:g} fps is not a whole multiple of the working "
                         f"rate {C.FPS:g} fps", where)
    return step


def read_grab_header(path: str | os.PathLike) -> dict[str, Any]:
    """Scalar fields of a GRAB file (object, subject, intent, framerate, n_frames at source
    rate, n_comps, body_model) without reading the motion: cheap, for listings and splits."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    return _parse_header(_read_header_members(path), path)


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


def _params(entry: dict, part: str, hdr: dict, path: Path) -> dict[str, np.ndarray]:
    """The ``params`` arrays of one part, checked for presence, dtype, shape and finiteness
    (before any model is needed, so a malformed file fails on its own terms)."""
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
        if a.ndim != 2 or a.shape[0] != n_frames or a.shape[1] not in widths:
            want = " or ".join(f"(n_frames={n_frames}, {w})" for w in widths)
            raise InputError(f"shape {a.shape} should be {want}", where)
        bad = ~np.isfinite(a)
        if bad.any():
            raise InputError(f"{int(bad.sum())} non-finite values (first at frame "
                             f"{int(np.argwhere(bad)[0, 0])})", where)
        out[key] = a if a.dtype.kind == "f" else a.astype(np.float64)
    return out


def _optional_path(entry: dict, key: str, where: str) -> str | None:
    value = entry.get(key)
    if value is None:
        return None
    return _as_str(value, where)


def _optional_float(entry: dict, key: str, where: str) -> float | None:
    return None if entry.get(key) is None else _as_number(entry[key], where)


def _contact(raw: dict[str, Any], n_frames: int, path: Path) -> dict[str, np.ndarray]:
    entry = raw["contact"]
    if not isinstance(entry, dict):
        raise InputError(f"should hold a dict, got {_describe(entry)}", f"{path}: contact")
    out = {}
    for key, labels in entry.items():
        where = f"{path}: contact.{key}"
        if not isinstance(labels, np.ndarray) or labels.ndim != 2 or labels.shape[0] != n_frames:
            raise InputError(
                f"shape {np.shape(labels)} should be (n_frames={n_frames}, N_verts)", where
            )
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


# --- reading: the whole file ---------------------------------------------------------------
def read_grab(path: str | os.PathLike, *, mano_backend: ManoBackend | None = None,
              flat_hand_mean: bool | None = None) -> Sequence:
    """Read a GRAB-layout ``.npz`` into a validated :class:`Sequence` at 30 fps.

    See the module docstring for subsampling, PCA expansion and ``flat_hand_mean``
    (None: each part's marker, else GRAB's convention; a bool overrides unmarked parts).
    Every malformed input raises a one-line :class:`InputError` (or
    :class:`UnsafeFileError` for pickled code, :class:`MissingModelError` for PCA poses
    without ``mano_backend``) naming the file and key.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    raw = load_npz(path)
    for key in REQUIRED_KEYS:
        if key not in raw:
            raise InputError("missing key", f"{path}: {key}")
    hdr = _parse_header(raw, path)
    entries = {part: _part_dict(raw, part, path) for part in PART_DIMS}
    parts = {part: _params(entries[part], part, hdr, path) for part in PART_DIMS}
    contact = _contact(raw, hdr["n_frames"], path)
    flat = _flat_flags(entries, flat_hand_mean, path)
    _full_hand_poses(parts, hdr["n_comps"], mano_backend, flat, path)
    # copies when subsampling, so the 120 fps arrays are not kept alive by strided views
    sub = (lambda v: v) if hdr["step"] == 1 else (lambda v: v[:: hdr["step"]].copy())
    parts = {part: {k: sub(v) for k, v in p.items()} for part, p in parts.items()}
    contact = {k: sub(v) for k, v in contact.items()}
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
    """:class:`ManoBackend` from the licensed MANO files (PCA components and mean only).

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

            path = sb.find_model_file(self.model_path, "mano", side)
            self._data[side] = sb.load_model_data(path, {"hands_components": (45,),
                                                         "hands_mean": None})
        return self._data[side]

    def expand_pca(self, side: str, coeffs: np.ndarray) -> np.ndarray:
        comps = self._side(side)["hands_components"].reshape(-1, C.N_HAND_POSE)
        if coeffs.shape[1] > comps.shape[0]:
            raise InputError(f"{coeffs.shape[1]} PCA coefficients, the model has {comps.shape[0]}",
                             "hand_pose")
        return np.asarray(coeffs, float) @ comps[: coeffs.shape[1]]

    def hands_mean(self, side: str) -> np.ndarray:
        return self._side(side)["hands_mean"].reshape(C.N_HAND_POSE)


def load_mano_backend(model_path: str | os.PathLike | None) -> ManoBackend:
    """The MANO backend for ``model_path`` (or ``$GRIP_BENCH_MODEL_PATH`` when None)."""
    return MANOModelBackend(model_path)
