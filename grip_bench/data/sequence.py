"""One GRAB-style sequence at the suite's working rate (30 fps), with validation.

A :class:`Sequence` mirrors one GRAB ``.npz`` after reading: the parameter dicts
(``body``, ``rhand``, ``lhand``, ``object``, ``table``) hold ``(T, k)`` float arrays
keyed exactly as GRAB's ``<part>['params']``, hand poses are always full axis-angle
(``(T, 45)``, MANO joint order, flat hand mean = zero pose), and ``contact`` holds
GRAB's per-vertex contact labels.

Contact labels follow GRAB: ``0`` is no contact, otherwise the SMPL-X joint index of
the touching body part **plus one** (1 = pelvis/"Body", 21 = left wrist "L_Hand",
22 = right wrist "R_Hand", 26-40 left fingers, 41-55 right fingers).

Units: metres and radians. Validation errors are :class:`InputError` with
``where = "<file>: <part>.params.<key>"`` (the key path as stored on disk).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from ..bodies.layouts import SMPLX_INDEX, SMPLX_JOINTS
from ..core import constants as C
from ..core.errors import InputError
from ..core.frames import SIDES

# Width of every (T, k) parameter array, per part, in GRAB's key names.
BODY_DIMS = {
    "global_orient": 3, "body_pose": 63, "transl": 3, "right_hand_pose": 45,
    "left_hand_pose": 45, "jaw_pose": 3, "leye_pose": 3, "reye_pose": 3,
    "expression": 10, "fullpose": 165,
}
HAND_DIMS = {"global_orient": 3, "hand_pose": 45, "transl": 3, "fullpose": 48}
RIGID_DIMS = {"global_orient": 3, "transl": 3}
PART_DIMS = {"body": BODY_DIMS, "rhand": HAND_DIMS, "lhand": HAND_DIMS,
             "object": RIGID_DIMS, "table": RIGID_DIMS}
# Keys holding axis-angle rotations (checked against MAX_AXIS_ANGLE per joint).
ROTATION_KEYS = frozenset(k for dims in PART_DIMS.values() for k in dims
                          if k not in ("transl", "expression"))

GENDERS = ("male", "female", "neutral")
BODY_MODELS = ("procedural", "smplx")
HAND_PART = {"right": "rhand", "left": "lhand"}

# GRAB contact label = SMPL-X joint index + 1 (0 = no contact).
CONTACT_HAND_LABELS = {
    side: frozenset(
        i + 1 for i, name in enumerate(SMPLX_JOINTS)
        if name == f"{side}_wrist" or (name.startswith(f"{side}_") and name[-1] in "123")
    )
    for side in SIDES
}


def contact_label(joint_name: str) -> int:
    """GRAB contact label of an SMPL-X joint's body part (``"right_index1"`` -> 42)."""
    return SMPLX_INDEX[joint_name] + 1


def hand_fullpose(global_orient: np.ndarray, hand_pose: np.ndarray) -> np.ndarray:
    """MANO full pose ``(T, 48)``: wrist orientation (T, 3) then finger pose (T, 45)."""
    return np.concatenate([global_orient, hand_pose], axis=-1)


def body_fullpose(p: dict[str, np.ndarray]) -> np.ndarray:
    """SMPL-X full pose ``(T, 165)`` = 55 joints x 3, in SMPL-X joint order, from body params."""
    keys = ("global_orient", "body_pose", "jaw_pose", "leye_pose", "reye_pose",
            "left_hand_pose", "right_hand_pose")
    return np.concatenate([p[k] for k in keys], axis=-1)


def make_body_params(
    global_orient: ArrayLike,
    body_pose: ArrayLike,
    transl: ArrayLike,
    left_hand_pose: ArrayLike,
    right_hand_pose: ArrayLike,
    jaw_pose: ArrayLike | None = None,
    leye_pose: ArrayLike | None = None,
    reye_pose: ArrayLike | None = None,
    expression: ArrayLike | None = None,
) -> dict[str, np.ndarray]:
    """Body params dict with face terms defaulting to zero and ``fullpose`` filled in.

    Shapes: (T, 3), (T, 63), (T, 3), (T, 45), (T, 45); optional (T, 3) x3, (T, 10).
    """
    T = np.shape(transl)[0]
    dtype = np.asarray(transl).dtype
    z = lambda k: np.zeros((T, k), dtype=dtype)  # noqa: E731
    p = {"global_orient": global_orient, "body_pose": body_pose, "transl": transl,
         "right_hand_pose": right_hand_pose, "left_hand_pose": left_hand_pose,
         "jaw_pose": z(3) if jaw_pose is None else jaw_pose,
         "leye_pose": z(3) if leye_pose is None else leye_pose,
         "reye_pose": z(3) if reye_pose is None else reye_pose,
         "expression": z(10) if expression is None else expression}
    p = {k: np.asarray(v) for k, v in p.items()}
    p["fullpose"] = body_fullpose(p)
    return p


def make_hand_params(
    global_orient: ArrayLike, hand_pose: ArrayLike, transl: ArrayLike
) -> dict[str, np.ndarray]:
    """Hand params dict of one hand.

    ``{global_orient (T,3), hand_pose (T,45), transl (T,3), fullpose (T,48)}``.
    """
    go, hp, tr = (np.asarray(a) for a in (global_orient, hand_pose, transl))
    hp = hp.reshape(hp.shape[0], -1)
    return {"global_orient": go, "hand_pose": hp, "transl": tr, "fullpose": hand_fullpose(go, hp)}


def make_rigid_params(global_orient: ArrayLike, transl: ArrayLike) -> dict[str, np.ndarray]:
    """Object / table params ``{global_orient (T,3), transl (T,3)}``."""
    return {"global_orient": np.asarray(global_orient), "transl": np.asarray(transl)}


def _where(source: str | Path | None, key: str) -> str:
    return f"{source}: {key}" if source else key


@dataclass(eq=False)
class Sequence:
    """One GRAB-layout sequence at ``fps`` (the suite's 30 fps); see the module docstring.

    ``object_mesh`` (and the ``*_vtemp`` / ``table_mesh`` paths) are stored as in GRAB:
    relative to the data root (the folder holding ``grab/`` and ``tools/``).
    """

    name: str  # "s1/mug_lift_1"
    sbj_id: str
    gender: str
    obj_name: str
    motion_intent: str
    body: dict[str, np.ndarray]
    rhand: dict[str, np.ndarray]
    lhand: dict[str, np.ndarray]
    object: dict[str, np.ndarray]
    table: dict[str, np.ndarray]
    contact: dict[str, np.ndarray] = field(default_factory=dict)  # 'object' (T,N) int, 'body'?
    fps: float = C.FPS
    body_model: str = "procedural"
    height: float | None = None  # m, subject stature where known
    hand_scale: float | None = None  # multiplier of the default hand size where known
    object_mesh: str | None = None
    table_mesh: str | None = None
    body_vtemp: str | None = None
    rhand_vtemp: str | None = None
    lhand_vtemp: str | None = None
    source: Path | None = None  # the file it was read from (not written)

    # --- basic properties -------------------------------------------------
    @property
    def n_frames(self) -> int:
        return int(np.shape(self.object["transl"])[0])

    @property
    def duration(self) -> float:
        """Seconds covered by the frames (T / fps)."""
        return self.n_frames / self.fps

    def __len__(self) -> int:
        return self.n_frames

    def parts(self) -> dict[str, dict[str, np.ndarray]]:
        """The five parameter dicts by part name (body, rhand, lhand, object, table)."""
        return {"body": self.body, "rhand": self.rhand, "lhand": self.lhand,
                "object": self.object, "table": self.table}

    def hand_params(self, side: str) -> dict[str, np.ndarray]:
        """Params of one hand (``"right"`` or ``"left"``).

        Keys: global_orient, hand_pose (T,45), transl, fullpose.
        """
        if side not in SIDES:
            raise InputError(f"side must be 'right' or 'left', got {side!r}", "side")
        return self.rhand if side == "right" else self.lhand

    # --- geometry -------------------------------------------------------------
    def object_rotations(self) -> np.ndarray:
        """Rotation matrices ``R_t`` (T, 3, 3) of the object's axis-angle ``global_orient``."""
        return Rotation.from_rotvec(np.asarray(self.object["global_orient"], float)).as_matrix()

    def object_vertices(self, v_template: np.ndarray) -> np.ndarray:
        """Object vertices per frame (T, N, 3), metres, GRAB's row-vector convention.

        ``verts_t = v_template @ R_t + transl_t`` -- the template rows are multiplied on
        the LEFT of ``R_t`` (equivalently ``R_t^T v`` per column vector), as GRAB does.
        """
        v = np.asarray(v_template, dtype=float)
        if v.ndim != 2 or v.shape[1] != 3:
            raise InputError(f"object template shape {v.shape} should be (N, 3)", "v_template")
        rot = self.object_rotations()
        return np.einsum("nj,tjk->tnk", v, rot) + np.asarray(self.object["transl"], float)[:, None]

    # --- contact --------------------------------------------------------------
    def contact_frames(self, side: str | None = None) -> np.ndarray:
        """Frames (T,) bool where the object touches the body (or one hand, by GRAB's labels).

        All False when the sequence has no ``contact['object']`` labels.
        """
        labels = self.contact.get("object")
        if labels is None:
            return np.zeros(self.n_frames, dtype=bool)
        labels = np.asarray(labels)
        if side is None:
            return (labels > 0).any(axis=1)
        ids = np.fromiter(CONTACT_HAND_LABELS[side], dtype=labels.dtype)
        return np.isin(labels, ids).any(axis=1)

    # --- slicing --------------------------------------------------------------
    def __getitem__(self, index: slice) -> Sequence:
        """Frames ``index`` (a slice) of every per-frame array, as a new Sequence."""
        if not isinstance(index, slice):
            raise TypeError("Sequence supports slicing by frames only (seq[a:b:step])")
        if index.step not in (None, 1):
            raise ValueError("slice steps change the frame rate; use resample-aware code instead")
        return self.frames(index.start, index.stop)

    def frames(self, start: int | None = None, stop: int | None = None) -> Sequence:
        """Copy with frames ``[start, stop)`` (Python slice semantics) of every (T, ...) array."""
        return self.take(slice(start, stop))

    def take(self, index: slice | ArrayLike) -> Sequence:
        """Copy with frames ``index`` (a slice, integer indices or a boolean mask over T)
        of every (T, ...) array."""
        cut = lambda d: {k: np.array(v[index]) for k, v in d.items()}  # noqa: E731
        return replace(self, body=cut(self.body), rhand=cut(self.rhand), lhand=cut(self.lhand),
                       object=cut(self.object), table=cut(self.table), contact=cut(self.contact))

    def copy(self) -> Sequence:
        """Deep copy (arrays included)."""
        return copy.deepcopy(self)

    def with_hands(self, **sides: dict) -> Sequence:
        """Copy with new hands: ``with_hands(right={"hand_pose": (T,15,3)|(T,45), ...}, left=...)``.

        Any of ``global_orient`` (T, 3), ``hand_pose``, ``transl`` (T, 3) may be given per
        side; the rest is kept. The body's hand poses and both ``fullpose`` arrays follow,
        so the file stays self-consistent for every reader.
        """
        out = self.copy()
        for side, new in sides.items():
            if side not in ("right", "left"):
                raise InputError(f"expected 'right' or 'left', got {side!r}", "side")
            part = out.rhand if side == "right" else out.lhand
            merged = {k: np.asarray(new.get(k, part[k]), dtype=part[k].dtype)
                      for k in ("global_orient", "hand_pose", "transl")}
            part.update(
                make_hand_params(merged["global_orient"], merged["hand_pose"], merged["transl"])
            )
            out.body[f"{side}_hand_pose"] = part["hand_pose"].astype(out.body["body_pose"].dtype)
        out.body["fullpose"] = body_fullpose(out.body)
        return out

    # --- validation -----------------------------------------------------------
    def validate(self, source: str | Path | None = None) -> Sequence:
        """Check types, shapes, frame counts, finiteness and units; return ``self``.

        Raises :class:`InputError` naming ``source`` (a file, if any) and the offending key.
        """
        source = source if source is not None else self.source
        self._validate_meta(source)
        T = self.n_frames if _is_2d(self.object.get("transl")) else None
        for part, dims in PART_DIMS.items():
            params = getattr(self, part)
            if not isinstance(params, dict):
                raise InputError(f"should be a dict of arrays, got {type(params).__name__}",
                                 _where(source, f"{part}.params"))
            for key, width in dims.items():
                where = _where(source, f"{part}.params.{key}")
                if key not in params:
                    raise InputError("missing", where)
                T = _check_param(params[key], width, T, where)
                _check_units(params[key], key, where)
        self._validate_contact(T, source)
        return self

    def _validate_meta(self, source: str | Path | None) -> None:
        for key in ("name", "sbj_id", "obj_name", "motion_intent"):
            value = getattr(self, key)
            if not isinstance(value, str) or not value:
                raise InputError(
                    f"should be a non-empty string, got {value!r}", _where(source, key)
                )
        if "/" in self.obj_name or "\\" in self.obj_name:
            raise InputError(f"object name {self.obj_name!r} must not contain path separators",
                             _where(source, "obj_name"))
        if self.gender not in GENDERS:
            raise InputError(
                f"gender {self.gender!r} should be one of {GENDERS}", _where(source, "gender")
            )
        if self.body_model not in BODY_MODELS:
            raise InputError(f"body model {self.body_model!r} should be one of {BODY_MODELS}",
                             _where(source, "body_model"))
        if not (isinstance(self.fps, int | float) and np.isfinite(self.fps) and self.fps == C.FPS):
            raise InputError(
                f"frame rate {self.fps!r} should be {C.FPS:g} fps (the suite's working "
                f"rate; read_grab subsamples GRAB's {C.GRAB_FPS:g} fps)",
                _where(source, "framerate"),
            )
        _check_optional_range(
            self.height, C.SUBJECT_HEIGHT_RANGE, "m", _where(source, "body.height")
        )
        _check_optional_range(self.hand_scale, C.HAND_SCALE_RANGE, "",
                              _where(source, "body.hand_scale"))

    def _validate_contact(self, T: int, source: str | Path | None) -> None:
        if not isinstance(self.contact, dict):
            raise InputError("should be a dict of arrays", _where(source, "contact"))
        if "object" not in self.contact:
            raise InputError("missing (per-frame object contact labels, (T, N_obj_verts))",
                             _where(source, "contact.object"))
        for key, labels in self.contact.items():
            where = _where(source, f"contact.{key}")
            if not isinstance(labels, np.ndarray) or labels.ndim != 2 or labels.shape[1] < 1:
                raise InputError(f"shape {np.shape(labels)} should be (T, N_verts)", where)
            if labels.shape[0] != T:
                raise InputError(f"{labels.shape[0]} frames, but the parameters have {T}", where)
            if not (np.issubdtype(labels.dtype, np.integer) or labels.dtype == bool):
                raise InputError(f"dtype {labels.dtype} should be integer contact labels", where)
            if labels.size and labels.min() < 0:
                raise InputError("contact labels must be >= 0", where)


def _is_2d(a: object) -> bool:
    return isinstance(a, np.ndarray) and a.ndim == 2


def _check_param(a: object, width: int, T: int | None, where: str) -> int:
    """Check one (T, width) float array; return T (the first array fixes it)."""
    if not isinstance(a, np.ndarray):
        raise InputError(f"should be an array, got {type(a).__name__}", where)
    if a.ndim != 2 or a.shape[1] != width:
        raise InputError(f"shape {a.shape} should be (T, {width})", where)
    if not np.issubdtype(a.dtype, np.floating):
        raise InputError(f"dtype {a.dtype} should be floating point", where)
    if T is None:
        T = a.shape[0]
    if a.shape[0] != T:
        raise InputError(f"{a.shape[0]} frames, but object.params.transl has {T}", where)
    if T < 1:
        raise InputError("has no frames", where)
    bad = ~np.isfinite(a)
    if bad.any():
        frame = int(np.argwhere(bad)[0, 0])
        raise InputError(f"{int(bad.sum())} non-finite values (first at frame {frame})", where)
    return T


def _check_units(a: np.ndarray, key: str, where: str) -> None:
    """Catch millimetres and degrees: both are plausible-looking numbers in the wrong unit."""
    if key == "transl":
        peak = float(np.abs(a).max())
        if peak > C.MAX_ABS_TRANSL:
            raise InputError(f"translation up to {peak:.4g} m (> {C.MAX_ABS_TRANSL:g} m): "
                             "are the units millimetres? the suite expects metres", where)
    elif key in ROTATION_KEYS:
        peak = float(np.linalg.norm(a.reshape(a.shape[0], -1, 3), axis=-1).max())
        if peak > C.MAX_AXIS_ANGLE:
            raise InputError(
                f"rotation angle up to {peak:.4g} rad (> {C.MAX_AXIS_ANGLE:g}): "
                "are the angles in degrees? the suite expects axis-angle radians",
                where,
            )


def _check_optional_range(
    value: object, bounds: tuple[float, float], unit: str, where: str
) -> None:
    if value is None:
        return
    lo, hi = bounds
    if not isinstance(value, int | float) or not np.isfinite(value) or not lo <= value <= hi:
        raise InputError(
            f"{value!r} is outside the plausible range "
            f"[{lo:g}, {hi:g}]{' ' + unit if unit else ''}",
            where,
        )
