"""Real SMPL-X and MANO through the optional ``smplx`` package, loaded without pickle.

The model files are licensed (registration at https://smpl-x.is.tue.mpg.de and
https://mano.is.tue.mpg.de) and never shipped. They are found under a model path given
as an argument or in ``$GRIP_BENCH_MODEL_PATH``::

    <path>/smplx/SMPLX_{NEUTRAL,MALE,FEMALE}.npz   (or .pkl)
    <path>/mano/MANO_{RIGHT,LEFT}.pkl              (or .npz)

The official ``.pkl`` files hold chumpy arrays and scipy sparse matrices. They are read
only with :func:`grip_bench.core.safe_pickle.load_pickle` (data only, nothing in the file
runs) and the plain arrays are handed to ``smplx``: MANO takes them as ``data_struct``;
``smplx.SMPLX`` always opens a file itself, so it gets a temporary ``.npz`` that holds
numeric arrays only, which its ``np.load(allow_pickle=True)`` reads without unpickling.

Hand means (``flat_hand_mean``): GRAB's public code builds its MANO hands with
``flat_hand_mean=True`` and its SMPL-X bodies with the ``smplx`` default ``False``
(grab/save_grab_vertices.py; the GRAB paper itself does not say), so those are the
defaults here; a pose then means "offset from the flat hand" for :class:`MANOHand` and
"offset from MANO's mean hand" for the hands of :class:`SMPLXBody`. GRAB stores hand
poses as ``n_comps = 24`` PCA coefficients; :func:`expand_pca` turns them into full
axis-angle with the model's components.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
import types
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import torch
from torch import nn

from grip_bench.bodies.layouts import SMPLX_INDEX, SMPLX_PARENTS, TIP_NAMES
from grip_bench.core.errors import GripBenchError, InputError, MissingModelError
from grip_bench.core.safe_pickle import load_npz, load_pickle

if TYPE_CHECKING:
    import trimesh

__all__ = [
    "MODEL_PATH_ENV", "MANO_TIP_IDS", "MANOHand", "SMPLXBody", "SMPLXOutput",
    "expand_pca", "find_model_file", "load_model_data", "mano_rest_wrist", "resolve_model_path",
    "seal_faces",
]

MODEL_PATH_ENV = "GRIP_BENCH_MODEL_PATH"
_SOURCES = {"smplx": "https://smpl-x.is.tue.mpg.de", "mano": "https://mano.is.tue.mpg.de"}
_FILES = {"smplx": "SMPLX_{}", "mano": "MANO_{}"}
# MANO fingertip vertices (thumb, index, middle, ring, pinky: layouts.TIP_NAMES order),
# the ids used across MANO code bases for the 21-keypoint hand.
MANO_TIP_IDS: tuple[int, ...] = (744, 320, 443, 554, 671)
# Keys and trailing shapes the adapters need; V (vertices) and K (landmarks) are free.
_MANO_KEYS = {"v_template": (3,), "f": (3,), "weights": (16,), "J_regressor": None,
              "kintree_table": None, "posedirs": (3, 135), "shapedirs": None,
              "hands_components": (45,), "hands_mean": None}
_SMPLX_KEYS = {"v_template": (3,), "f": (3,), "weights": (55,), "J_regressor": None,
               "kintree_table": None, "posedirs": (3, 486), "shapedirs": None,
               "hands_componentsl": (45,), "hands_componentsr": (45,), "hands_meanl": None,
               "hands_meanr": None, "lmk_faces_idx": None, "lmk_bary_coords": (3,)}


def _import_smplx() -> types.ModuleType:
    """The ``smplx`` module, or a clear error naming the optional extra."""
    try:
        import smplx
    except ImportError as e:
        raise GripBenchError(
            "the optional 'smplx' package is not installed; install it with "
            "pip install 'grip-bench[smplx]'", "smplx") from e
    return smplx


# ----------------------------------------------------------------- files
def resolve_model_path(model_path: str | os.PathLike | None = None) -> Path:
    """The model directory: ``model_path`` or ``$GRIP_BENCH_MODEL_PATH``."""
    raw = model_path if model_path is not None else os.environ.get(MODEL_PATH_ENV)
    if not raw:
        raise MissingModelError(
            f"no model path given: pass model_path or set ${MODEL_PATH_ENV} to a folder "
            f"holding smplx/SMPLX_NEUTRAL.npz and mano/MANO_RIGHT.pkl (licensed; register at "
            f"{_SOURCES['smplx']} and {_SOURCES['mano']})", MODEL_PATH_ENV)
    return Path(raw).expanduser()


def find_model_file(model_path: str | os.PathLike | None, family: str, variant: str) -> Path:
    """Path of ``<path>/<family>/<FAMILY>_<VARIANT>.{npz,pkl}``, or :class:`MissingModelError`.

    family "smplx" (variant neutral/male/female) or "mano" (variant right/left).
    """
    if family not in _FILES:
        raise InputError(f"expected 'smplx' or 'mano', got {family!r}", "family")
    root = resolve_model_path(model_path)
    stem = _FILES[family].format(variant.upper())
    order = (".npz", ".pkl") if family == "smplx" else (".pkl", ".npz")
    candidates = [root / family / (stem + ext) for ext in order]
    for path in candidates:
        if path.is_file():
            return path
    raise MissingModelError(
        f"model file not found; expected {' or '.join(str(c) for c in candidates)}. "
        f"These files are licensed and not shipped: register and download them from "
        f"{_SOURCES[family]}, then unpack into {root / family}", candidates[0])


def load_model_data(path: str | os.PathLike, required: dict[str, tuple | None] | None = None
                    ) -> dict[str, np.ndarray]:
    """Plain numeric arrays of a model file (.npz or .pkl), read without running pickled code.

    Entries that are not numeric arrays (names, strings) are dropped; each key of
    ``required`` must be present, with the given trailing shape where one is given.
    """
    path = Path(path)
    raw = (load_npz(path) if path.suffix == ".npz"
           else load_pickle(path, allow_chumpy=True, allow_sparse=True))
    if not isinstance(raw, dict):
        raise InputError(f"expected a dict of arrays, got {type(raw).__name__}", path)
    data = {}
    for key, value in raw.items():
        arr = np.asarray(value) if not isinstance(value, str) else None
        if arr is not None and arr.dtype.kind in "biuf":
            data[str(key)] = arr
    for key, tail in (required or {}).items():
        if key not in data:
            raise InputError("missing model array", f"{path}: {key}")
        shape = data[key].shape
        if tail is not None and tuple(shape[len(shape) - len(tail):]) != tail:
            raise InputError(f"expected shape (..., {', '.join(map(str, tail))}), got {shape}",
                             f"{path}: {key}")
    return data


def mano_rest_wrist(data: dict[str, np.ndarray], v_template: np.ndarray | None = None,
                    source: str | os.PathLike = "MANO") -> np.ndarray:
    """MANO's rest wrist joint ``J0 = J_regressor[0] @ v_template`` (3,) float64, m.

    ``data``: a MANO file's arrays (:func:`load_model_data`); ``v_template (V, 3)``: a
    subject's personal template (GRAB's ``rhand_vtemp``), None for the model's own. MANO
    rotates the hand about this point, so the world wrist is ``J0 + transl`` (GRAB).
    """
    for key in ("J_regressor", "v_template"):
        if key not in data:
            raise InputError("missing model array", f"{source}: {key}")
    reg = np.asarray(data["J_regressor"], np.float64)
    verts = np.asarray(data["v_template"] if v_template is None else v_template, np.float64)
    if reg.ndim != 2 or verts.ndim != 2 or verts.shape[1] != 3 or reg.shape[1] != len(verts):
        raise InputError(f"joint regressor {reg.shape} does not fit a template of shape "
                         f"{verts.shape}", f"{source}: J_regressor")
    return reg[0] @ verts


# -------------------------------------------------------------- helpers
def expand_pca(
    pca: torch.Tensor | np.ndarray,
    components: torch.Tensor | np.ndarray,
    mean: torch.Tensor | np.ndarray | None = None,
) -> torch.Tensor:
    """PCA hand pose -> full axis-angle: ``pca (B, n) @ components[:n] (n, 45) + mean (45,)``.

    Returns ``(B, 15, 3)`` radians. ``mean`` is the model's hand mean, or ``None`` for
    ``flat_hand_mean=True`` (GRAB's MANO hands).
    """
    pca = torch.as_tensor(pca)
    comps = torch.as_tensor(np.asarray(components), dtype=pca.dtype)
    if pca.ndim != 2 or comps.ndim != 2 or comps.shape[1] != 45 or pca.shape[1] > comps.shape[0]:
        raise InputError(f"expected pca (B, n<={comps.shape[0]}) and components (n, 45), got "
                         f"{tuple(pca.shape)} and {tuple(comps.shape)}", "hand_pose")
    full = pca @ comps[: pca.shape[1]]
    if mean is not None:
        full = full + torch.as_tensor(np.asarray(mean), dtype=pca.dtype).reshape(45)
    return full.reshape(-1, 15, 3)


def seal_faces(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Close every boundary loop with a fan around a new centre vertex.

    faces (F, 3) of a consistently oriented mesh with ``n_vertices`` vertices. Returns
    (faces (F + sum(len(loop)), 3) int64, loops): loop ``k`` is ordered and gets the new
    vertex ``n_vertices + k``. Each fan triangle runs its boundary edge backwards, which
    keeps the orientation (outward stays outward).
    """
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    directed = {tuple(e) for e in edges.tolist()}
    nxt: dict[int, int] = {}
    for a, b in edges.tolist():
        if (b, a) not in directed:
            if a in nxt:
                raise InputError("the boundary is not a set of simple loops", "faces")
            nxt[a] = b
    loops, fans = [], []
    while nxt:
        start = next(iter(nxt))
        loop = [start]
        while nxt[loop[-1]] != start:
            loop.append(nxt.pop(loop[-1]))
            if loop[-1] not in nxt:
                raise InputError("an open boundary chain", "faces")
        nxt.pop(loop[-1])
        centre = n_vertices + len(loops)
        loops.append(np.array(loop, dtype=np.int64))
        fans += [(b, a, centre) for a, b in zip(loop, loop[1:] + loop[:1], strict=True)]
    sealed = np.concatenate([faces, np.array(fans, dtype=np.int64).reshape(-1, 3)])
    return sealed, loops


def _batch(
    x: torch.Tensor | np.ndarray,
    name: str,
    tail: tuple[int, ...],
    batch: int | None,
    dtype: torch.dtype,
) -> torch.Tensor:
    """``(B, *tail)`` float tensor with finite values, or :class:`InputError` naming ``name``."""
    t = torch.as_tensor(x)
    if t.ndim != 1 + len(tail) or tuple(t.shape[1:]) != tail or (
            batch is not None and t.shape[0] != batch):
        want = ", ".join([str(batch) if batch else "B", *map(str, tail)])
        raise InputError(f"expected shape ({want}), got {tuple(t.shape)}", name)
    if not bool(torch.isfinite(t).all()):
        raise InputError("contains NaN or infinite values", name)
    return t.to(dtype)


def _hand_pose(
    x: torch.Tensor | np.ndarray | None, name: str, n_comps: int, batch: int, dtype: torch.dtype
) -> torch.Tensor:
    """Hand pose as the smplx layer wants it: ``(B, n_comps)`` PCA or ``(B, 45)`` axis-angle."""
    if x is None:
        return torch.zeros(batch, n_comps, dtype=dtype)
    t = torch.as_tensor(x)
    if n_comps == 45 and t.ndim == 3:
        t = t.reshape(t.shape[0], -1)
    return _batch(t, name, (n_comps,), batch, dtype)


def _betas(
    betas: torch.Tensor | np.ndarray | None, num_betas: int, batch: int, dtype: torch.dtype
) -> torch.Tensor:
    """Shape coefficients ``(B, num_betas)``; ``None`` = the mean shape, ``(1, n)`` broadcasts."""
    if betas is None:
        return torch.zeros(batch, num_betas, dtype=dtype)
    t = torch.as_tensor(betas)
    if t.ndim == 2 and t.shape[0] == 1:
        t = t.expand(batch, -1)
    return _batch(t, "betas", (num_betas,), batch, dtype)


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence smplx's construction-time prints (shape-space warnings)."""
    with contextlib.redirect_stdout(io.StringIO()):
        yield


# ----------------------------------------------------------------- MANO
class MANOHand(nn.Module):
    """MANO through ``smplx``, with the :class:`ProceduralHand` interface and a sealed mesh.

    side "right"/"left"; model_path (or ``$GRIP_BENCH_MODEL_PATH``); n_comps 45 for full
    axis-angle hand poses, fewer for PCA (GRAB: 24); flat_hand_mean (GRAB: True);
    v_template (V, 3) an optional personal template (GRAB ships one per subject).
    ``wrist_origin=False`` keeps smplx/GRAB semantics (the wrist is at
    ``J_0(betas) + transl``); ``True`` makes ``transl`` the wrist position, as for
    :class:`ProceduralHand` and every :class:`Sequence` (``data.posing`` poses with it;
    ``data.grab_io`` converts GRAB's files at the boundary, docs/real_grab.md).
    """

    def __init__(self, side: str = "right", model_path: str | os.PathLike | None = None,
                 n_comps: int = 45, flat_hand_mean: bool = True, num_betas: int = 10,
                 v_template: torch.Tensor | np.ndarray | None = None,
                 wrist_origin: bool = False, tip_ids: tuple[int, ...] = MANO_TIP_IDS,
                 dtype: torch.dtype = torch.float32):
        super().__init__()
        if side not in ("right", "left"):
            raise InputError(f"expected 'left' or 'right', got {side!r}", "side")
        if not 1 <= n_comps <= 45:
            raise InputError(f"expected 1..45 components, got {n_comps}", "n_comps")
        smplx = _import_smplx()
        self.side, self.n_comps, self.flat_hand_mean = side, int(n_comps), bool(flat_hand_mean)
        self.wrist_origin, self.num_betas = bool(wrist_origin), int(num_betas)
        self.path = find_model_file(model_path, "mano", side)
        data = load_model_data(self.path, _MANO_KEYS)
        with _quiet():
            self.layer = smplx.MANO(
                str(self.path), is_rhand=side == "right", data_struct=smplx.utils.Struct(**data),
                use_pca=n_comps < 45, num_pca_comps=n_comps, flat_hand_mean=flat_hand_mean,
                num_betas=num_betas, v_template=v_template, dtype=dtype, create_betas=False,
                create_global_orient=False, create_hand_pose=False, create_transl=False)
        n_verts = self.layer.v_template.shape[0]
        if max(tip_ids) >= n_verts:
            raise InputError(f"fingertip ids {tip_ids} exceed the {n_verts} vertices", self.path)
        faces, self.loops = seal_faces(data["f"], n_verts)
        self.register_buffer("faces", torch.as_tensor(faces))
        self.register_buffer("fingertip_ids", torch.as_tensor(tip_ids, dtype=torch.long))
        self.register_buffer("components", torch.as_tensor(
            data["hands_components"], dtype=dtype).reshape(-1, 45))
        self.register_buffer("hand_mean", torch.as_tensor(
            np.zeros(45) if flat_hand_mean else data["hands_mean"], dtype=dtype).reshape(45))
        self.tip_names = TIP_NAMES

    def full_hand_pose(self, hand_pose: torch.Tensor | np.ndarray) -> torch.Tensor:
        """Absolute axis-angle ``(B, 15, 3)`` of a pose in this model's convention."""
        t = torch.as_tensor(hand_pose, dtype=self.components.dtype)
        if self.n_comps == 45:
            return t.reshape(t.shape[0], 15, 3) + self.hand_mean.reshape(15, 3)
        return expand_pca(t, self.components, None if self.flat_hand_mean else self.hand_mean)

    def forward(
        self,
        global_orient: torch.Tensor | np.ndarray,
        hand_pose: torch.Tensor | np.ndarray,
        transl: torch.Tensor | np.ndarray,
        betas: torch.Tensor | np.ndarray | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Posed hand.

        global_orient (B, 3), hand_pose (B, n_comps) PCA or (B, 15, 3)|(B, 45) axis-angle,
        transl (B, 3) m, betas (B, num_betas) or None. Returns vertices (B, V + loops, 3)
        of the sealed mesh and joints (B, 21, 3) (MANO's 16, then the 5 tips).
        """
        dtype = self.layer.v_template.dtype
        go = _batch(global_orient, "global_orient", (3,), None, dtype)
        b = go.shape[0]
        out = self.layer(global_orient=go, hand_pose=_hand_pose(hand_pose, "hand_pose",
                                                                self.n_comps, b, dtype),
                         betas=_betas(betas, self.num_betas, b, dtype),
                         transl=torch.zeros(b, 3, dtype=dtype))
        verts, joints = out.vertices, out.joints[:, :16]
        tr = _batch(transl, "transl", (3,), b, dtype)
        shift = tr - joints[:, 0] if self.wrist_origin else tr
        verts = self._with_centres(verts) + shift[:, None]
        tips = verts[:, self.fingertip_ids]
        return verts, torch.cat([joints + shift[:, None], tips], dim=1)

    @property
    def template_vertices(self) -> torch.Tensor:
        """The sealed rest template (V + loops, 3): the model's (or the subject's) template
        with its sealing centres, vertex for vertex the posed meshes' layout (the articulated
        hold test builds its collision pieces on it)."""
        return self._with_centres(self.layer.v_template[None])[0]

    @property
    def parents(self) -> tuple[int, ...]:
        """Parent of each of MANO's 16 joints (-1 for the wrist), MANO order."""
        return tuple(int(p) for p in self.layer.parents)

    def _with_centres(self, verts: torch.Tensor) -> torch.Tensor:
        """Append each sealing centre: the mean of its posed loop.

        MANO skins the wrist opening to the wrist, so the centre follows the wrist while
        staying inside the opening for any pose (the fan never folds over).
        """
        centres = [verts[:, torch.as_tensor(loop)].mean(dim=1, keepdim=True) for loop in self.loops]
        return torch.cat([verts, *centres], dim=1)

    def mesh(self, vertices: torch.Tensor | np.ndarray) -> trimesh.Trimesh:
        """A :class:`trimesh.Trimesh` (float64) of one posed hand ``(V, 3)``."""
        import trimesh

        v = vertices.detach().cpu().numpy() if torch.is_tensor(vertices) else vertices
        return trimesh.Trimesh(np.asarray(v, dtype=np.float64), self.faces.cpu().numpy(),
                               process=False)


# ---------------------------------------------------------------- SMPL-X
class SMPLXOutput(NamedTuple):
    """Posed SMPL-X: joints (B, 55, 3), rotations (B, 55, 3, 3) world, vertices (B, V, 3)."""

    joints: torch.Tensor
    rotations: torch.Tensor
    vertices: torch.Tensor


class SMPLXBody(nn.Module):
    """SMPL-X through ``smplx`` with the :class:`ProceduralBody` joint interface.

    gender neutral/male/female; n_comps 45 (full axis-angle hands) or fewer for PCA
    (GRAB: 24); flat_hand_mean (GRAB's body: False); v_template (V, 3) optional.
    ``transl`` follows SMPL-X: the pelvis is at ``J_0(betas) + transl``.
    Only the 55 skeleton joints are returned (smplx's extra vertex keypoints are off).
    """

    def __init__(self, model_path: str | os.PathLike | None = None, gender: str = "neutral",
                 n_comps: int = 45, flat_hand_mean: bool = False, num_betas: int = 10,
                 num_expression_coeffs: int = 10,
                 v_template: torch.Tensor | np.ndarray | None = None,
                 dtype: torch.dtype = torch.float32):
        super().__init__()
        if gender not in ("neutral", "male", "female"):
            raise InputError(f"expected neutral, male or female, got {gender!r}", "gender")
        if not 1 <= n_comps <= 45:
            raise InputError(f"expected 1..45 components, got {n_comps}", "n_comps")
        smplx = _import_smplx()
        self.n_comps, self.num_betas = int(n_comps), int(num_betas)
        self.num_expression_coeffs = int(num_expression_coeffs)
        self.path = find_model_file(model_path, "smplx", gender)
        data = load_model_data(self.path, _SMPLX_KEYS)
        self.layer = self._build(smplx, data, gender, dict(
            use_pca=n_comps < 45, num_pca_comps=n_comps, flat_hand_mean=flat_hand_mean,
            num_betas=num_betas, num_expression_coeffs=num_expression_coeffs,
            v_template=v_template, dtype=dtype))
        # The extra keypoints index fixed vertices of the official topology; we use none.
        sel = self.layer.vertex_joint_selector
        sel.extra_joints_idxs = sel.extra_joints_idxs[:0]
        self.faces = np.asarray(data["f"], dtype=np.int64)

    @staticmethod
    def _build(
        smplx: types.ModuleType, data: dict[str, np.ndarray], gender: str, kwargs: dict[str, Any]
    ) -> Any:
        """``smplx.SMPLX`` from a temporary numeric-only ``.npz`` (it cannot take arrays)."""
        with tempfile.TemporaryDirectory(
            prefix="grip_bench_smplx_", ignore_cleanup_errors=True
        ) as tmp:
            path = Path(tmp) / f"SMPLX_{gender.upper()}.npz"
            np.savez(path, **data)
            with _quiet():
                layer = smplx.SMPLX(
                    str(path), ext="npz", gender=gender, create_global_orient=False,
                    create_body_pose=False, create_left_hand_pose=False,
                    create_right_hand_pose=False, create_jaw_pose=False, create_leye_pose=False,
                    create_reye_pose=False, create_betas=False, create_expression=False,
                    create_transl=False, **kwargs)
        return layer

    def forward(
        self,
        global_orient: torch.Tensor | np.ndarray,
        body_pose: torch.Tensor | np.ndarray,
        transl: torch.Tensor | np.ndarray,
        left_hand_pose: torch.Tensor | np.ndarray | None = None,
        right_hand_pose: torch.Tensor | np.ndarray | None = None,
        jaw_pose: torch.Tensor | np.ndarray | None = None,
        leye_pose: torch.Tensor | np.ndarray | None = None,
        reye_pose: torch.Tensor | np.ndarray | None = None,
        expression: torch.Tensor | np.ndarray | None = None,
        betas: torch.Tensor | np.ndarray | None = None,
    ) -> SMPLXOutput:
        """Posed body: poses axis-angle (hands PCA when n_comps < 45), transl (B, 3) m.

        global_orient (B, 3), body_pose (B, 21, 3)|(B, 63), hand poses (B, n_comps) or
        (B, 15, 3)|(B, 45), jaw/eye poses (B, 3), expression (B, E), betas (B, num_betas).
        """
        dtype = self.layer.v_template.dtype
        go = _batch(global_orient, "global_orient", (3,), None, dtype)
        b = go.shape[0]
        bp = torch.as_tensor(body_pose)
        bp = bp.reshape(bp.shape[0], -1) if bp.ndim == 3 else bp
        zeros3 = torch.zeros(b, 3, dtype=dtype)
        out = self.layer(
            global_orient=go, body_pose=_batch(bp, "body_pose", (63,), b, dtype),
            left_hand_pose=_hand_pose(left_hand_pose, "left_hand_pose", self.n_comps, b, dtype),
            right_hand_pose=_hand_pose(right_hand_pose, "right_hand_pose", self.n_comps, b, dtype),
            **{n: zeros3 if p is None else _batch(p, n, (3,), b, dtype) for n, p in
               (("jaw_pose", jaw_pose), ("leye_pose", leye_pose), ("reye_pose", reye_pose))},
            expression=(torch.zeros(b, self.num_expression_coeffs, dtype=dtype)
                        if expression is None else _batch(expression, "expression",
                                                          (self.num_expression_coeffs,), b, dtype)),
            betas=_betas(betas, self.num_betas, b, dtype),
            transl=_batch(transl, "transl", (3,), b, dtype), return_full_pose=True)
        return SMPLXOutput(out.joints[:, :55], _world_rotations(out.full_pose), out.vertices)

    def wrist_frame(self, output: SMPLXOutput, side: str) -> tuple[torch.Tensor, torch.Tensor]:
        """World rotation (B, 3, 3) and position (B, 3) of a wrist."""
        if side not in ("left", "right"):
            raise InputError(f"expected 'left' or 'right', got {side!r}", "side")
        j = SMPLX_INDEX[f"{side}_wrist"]
        return output.rotations[:, j], output.joints[:, j]


def _world_rotations(full_pose: torch.Tensor) -> torch.Tensor:
    """World rotations ``(B, 55, 3, 3)`` composed down the SMPL-X tree from ``(B, 165)``."""
    from grip_bench.geometry.rotations import axis_angle_to_matrix

    local = axis_angle_to_matrix(full_pose.reshape(full_pose.shape[0], 55, 3))
    world = [local[:, 0]]
    for j in range(1, 55):
        world.append(world[SMPLX_PARENTS[j]] @ local[:, j])
    return torch.stack(world, dim=1)
