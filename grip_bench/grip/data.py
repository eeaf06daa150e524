"""GRIP's training data: per-frame tensors built from a GRAB-layout data directory.

Per frame (hands ordered left, right; ``net_*`` arrays as GRIP's networks read them):

- ``body (154,)``: CNet's body context = the 21 SMPL-X body joints' local rotations in 6D
  (no root, 126), then per hand the wrist rotation (6D) and position (m) **in the
  object's frame** (2 x 9: the hand-object relation the sensors also see), then 10 shape
  numbers (stature m, hand scale, 8 zeros: the procedural body has two shape values).
- ``ambient (2, 1024)`` exp(-5 d), ``voxel (2, 1014)`` occupancy (only when asked for),
  ``proximity (2, 99)`` exp(-50 d) on the relaxed mean hand at the wrist, ``mean_dist
  (2,)`` m (the future cue is assembled per variant from it, ``sensors.future_cue``).
- targets ``gt_poses (2, 15, 6)`` and ``gt_proximity (2, 99)`` (exp(-50 d) of the GT
  hands' proximity vertices), ``gt_min_dist (2,)`` m (RNet's interaction mask).
- ANet: ``arms (4, 6)`` (left/right shoulder, left/right elbow, local 6D),
  ``noisy_arms`` from ``perturb_sequence(seq, "arm")`` (0.01 / 0.03 rad) and
  ``noisy_arms_wrist``: the arms that reach wrists moved by ``ANET_WRIST_SIGMA`` (IK,
  :func:`wrist_noise_arms`).
- object and wrist transforms, for recomputing proximity on predicted hands (RNet data).

Whole splits are cached in one ``.npz`` keyed by the dataset hash and the feature version.
"""

from __future__ import annotations

import functools
import hashlib
import os
from collections.abc import Iterable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from numpy.typing import ArrayLike

from ..bodies.layouts import SMPLX_INDEX
from ..core import constants as C
from ..core.errors import InputError
from ..core.frames import NET_SIDES
from ..core.io import atomic_file
from ..core.threads import single_thread
from ..geometry.rotations import axis_angle_to_matrix, matrix_to_rotation_6d
from ..sensors import ambient_sensor, object_pose_feature, stage_one, wrist_frames

if TYPE_CHECKING:
    from ..bodies.hand import ProceduralHand
    from ..data.library import ObjectLibrary
    from ..data.sequence import Sequence

FEATURE_VERSION = 2  # bump when any per-frame array changes meaning
ARM_JOINTS = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow")
N_SHAPE = 10


# --- hands: differentiable skinning from rotation matrices ------------------------------
class HandModel(torch.nn.Module):
    """Both procedural hands (left, right) posed from finger rotation matrices.

    ``vertices(rot (N, 2, 15, 3, 3), ids) -> (N, 2, K, 3)`` in each hand's own frame
    (wrist at the origin, no global rotation), differentiable; ``ids`` picks K vertices
    (None: all). Skinning only the needed vertices keeps the vertex loss cheap.
    """

    def __init__(self, scale: float = 1.0):
        super().__init__()
        from ..bodies.hand import ProceduralHand

        self.hands = torch.nn.ModuleList(ProceduralHand(s, scale) for s in NET_SIDES)
        self.parents = self.hands[0].parents
        self.proximity_ids = self.hands[0].proximity_ids  # identical for both sides (mirror)

    def _fk(self, hand: ProceduralHand, rot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Global joint rotations (N, 16, 3, 3) and positions (N, 16, 3).

        From local rotations ``rot`` (N, 15, 3, 3).
        """
        rest = hand.rest_joints.to(rot)
        eye = torch.eye(3, dtype=rot.dtype, device=rot.device).expand(rot.shape[0], 3, 3)
        g_rot, g_pos = [eye], [rest[0].expand(rot.shape[0], 3)]
        for j in range(1, 16):  # MANO parents precede children
            p = self.parents[j]
            g_rot.append(g_rot[p] @ rot[:, j - 1])
            g_pos.append(g_pos[p] + (g_rot[p] @ (rest[j] - rest[p])[:, None])[..., 0])
        return torch.stack(g_rot, 1), torch.stack(g_pos, 1)

    def vertices(self, rot: torch.Tensor, ids: ArrayLike | torch.Tensor | None = None
                 ) -> torch.Tensor:
        """``ids``: vertex indices, as an index tensor on the model's device for losses in
        a loop (no host-to-device copy per call) or anything ``np.array`` takes."""
        out = []
        for h, hand in enumerate(self.hands):
            g_rot, g_pos = self._fk(hand, rot[:, h])
            rest = hand.rest_joints.to(rot)
            shift = g_pos - torch.einsum("njab,jb->nja", g_rot, rest)  # x -> R x + shift
            sel = (slice(None) if ids is None else ids if isinstance(ids, torch.Tensor)
                   else torch.as_tensor(np.array(ids)))
            w, v = hand.weights[sel].to(rot), hand.template_vertices[sel].to(rot)
            r = torch.einsum("kj,njab->nkab", w, g_rot)
            out.append(torch.einsum("nkab,kb->nka", r, v) + torch.einsum("kj,nja->nka", w, shift))
        return torch.stack(out, 1)


def hand_model(scale: float = 1.0, device: str | torch.device = "cpu") -> HandModel:
    """A cached :class:`HandModel` of one hand scale (float64 buffers are not needed), its
    buffers on ``device``: one cached model per device, so the GPU copy of the training
    losses never moves the CPU one the data preparation uses."""
    return _hand_model(float(scale), str(torch.device(device)))


@functools.lru_cache(maxsize=4)
def _hand_model(scale: float, device: str) -> HandModel:
    return HandModel(scale).to(device)


def hand_proximity_points(poses_6d: np.ndarray, rot: np.ndarray, transl: np.ndarray,
                          scale: float) -> np.ndarray:
    """World positions ``(T, 2, 99, 3)`` of the proximity vertices of hands with finger poses
    ``poses_6d (T, 2, 15, 6)`` at wrists ``rot (T, 2, 3, 3)``, ``transl (T, 2, 3)``."""
    from ..geometry.rotations import rotation_6d_to_matrix

    model = hand_model(float(scale))
    with torch.no_grad():
        r = rotation_6d_to_matrix(torch.as_tensor(poses_6d, dtype=torch.float32))
        local = model.vertices(r, model.proximity_ids).double().numpy()  # (T, 2, 99, 3)
    return np.einsum("thij,thnj->thni", rot, local) + transl[:, :, None]


# --- per-sequence features ----------------------------------------------------------------
def aa_to_6d(aa: np.ndarray) -> np.ndarray:
    """Axis-angle ``(..., 3)`` -> 6D ``(..., 6)`` float32."""
    return matrix_to_rotation_6d(axis_angle_to_matrix(np.asarray(aa, np.float64))).astype(
        np.float32
    )


def arms_6d(body_pose: np.ndarray) -> np.ndarray:
    """ANet's arms ``(T, 4, 6)`` from SMPL-X ``body_pose (T, 63)`` (joints 1..21)."""
    rows = [SMPLX_INDEX[j] - 1 for j in ARM_JOINTS]
    return aa_to_6d(np.asarray(body_pose).reshape(-1, 21, 3)[:, rows])


def body_context(seq: Sequence, wrists: dict, body_pose: np.ndarray | None = None) -> np.ndarray:
    """CNet's body context ``(T, 154)`` float32 (module docstring).

    wrists: ``{side: (rot (T,3,3), transl (T,3))}``; body_pose (T, 63) overrides the
    sequence's (ANet's denoised arms).
    """
    bp = np.asarray(seq.body["body_pose"] if body_pose is None else body_pose, float)
    parts = [aa_to_6d(bp.reshape(-1, 21, 3)).reshape(len(bp), -1)]
    R_obj = seq.object_rotations()  # row-vector convention: local rotation = R_obj @ R_hand
    t_obj = np.asarray(seq.object["transl"], float)
    for side in NET_SIDES:
        rot, transl = wrists[side]
        r_local = np.einsum("tij,tjk->tik", R_obj, rot)
        p_local = np.einsum("tij,tj->ti", R_obj, transl - t_obj)
        parts += [matrix_to_rotation_6d(r_local).astype(np.float32), p_local]
    shape = np.zeros((len(bp), N_SHAPE))
    shape[:, 0] = seq.height or C.BODY_HEIGHT
    shape[:, 1] = seq.hand_scale or 1.0
    return np.concatenate(parts + [shape], axis=1).astype(np.float32)


def all_wrists(seq: Sequence) -> dict:
    return {side: wrist_frames(seq, side) for side in NET_SIDES}


def gt_poses_6d(seq: Sequence) -> np.ndarray:
    """Both hands' finger poses ``(T, 2, 15, 6)`` float32 (left, right)."""
    return np.stack([aa_to_6d(seq.hand_params(s)["hand_pose"].reshape(-1, 15, 3))
                     for s in NET_SIDES], 1)


def stack_wrists(wrists: dict) -> tuple[np.ndarray, np.ndarray]:
    """``{side: (rot (T,3,3), transl (T,3))}`` -> ``rot (T, 2, 3, 3)``, ``transl (T, 2, 3)``.

    Hands in (left, right) order.
    """
    return (np.stack([wrists[s][0] for s in NET_SIDES], 1),
            np.stack([wrists[s][1] for s in NET_SIDES], 1))


def hand_proximity(
    library: ObjectLibrary, seq: Sequence, poses_6d: np.ndarray, wrists: dict
) -> tuple[np.ndarray, np.ndarray]:
    """Proximity sensor ``(T, 2, 99)`` exp(-50 d) and distances ``(T, 2, 99)`` m of given hands."""
    from ..sensors import proximity_feature

    pts = hand_proximity_points(poses_6d, *stack_wrists(wrists), seq.hand_scale or 1.0)
    feats = [proximity_feature(library, seq, pts[:, h]) for h in range(2)]
    return np.stack([f[0] for f in feats], 1), np.stack([f[1] for f in feats], 1)


def sequence_features(
    library: ObjectLibrary, seq: Sequence, *, voxel: bool, rng: np.random.Generator
) -> dict:
    """Every per-frame array of one sequence (module docstring), keyed as :class:`FrameSet`."""
    from ..data.perturb import perturb_sequence

    wrists = all_wrists(seq)
    one = stage_one(library, seq, wrists, "distance")
    gt = gt_poses_6d(seq)
    gt_prox, gt_d = hand_proximity(library, seq, gt, wrists)
    noisy = perturb_sequence(seq, "arm", None, rng)
    T = seq.n_frames
    out = {
        "body": body_context(seq, wrists),
        "ambient": one.ambient.astype(np.float16),
        "proximity": one.proximity,
        "mean_dist": one.mean_dist.astype(np.float32),
        "gt_poses": gt,
        "gt_proximity": gt_prox,
        "gt_min_dist": gt_d.min(axis=2).astype(np.float32),
        "arms": arms_6d(seq.body["body_pose"]),
        "noisy_arms": arms_6d(noisy.body["body_pose"]),
        "noisy_arms_wrist": wrist_noise_arms(seq, rng),
        "wrist_rot": np.stack([wrists[s][0] for s in NET_SIDES], 1).astype(np.float32),
        "wrist_transl": np.stack([wrists[s][1] for s in NET_SIDES], 1).astype(np.float32),
        "obj_rot": seq.object_rotations().astype(np.float32),
        "obj_transl": np.asarray(seq.object["transl"], np.float32),
        "hand_scale": np.full(T, seq.hand_scale or 1.0, np.float32),
    }
    if voxel:
        out["voxel"] = voxel_feature(library, seq, wrists)
    return out


def wrist_noise_arms(seq: Sequence, rng: np.random.Generator) -> np.ndarray:
    """Arms ``(T, 4, 6)`` whose wrists reach the hand wrists moved by ``N(0, ANET_WRIST_SIGMA^2)``
    per axis and frame: GRAB-T's noise as ANet sees it in refine mode (two-bone IK, each
    frame's swivel kept, as ``pipeline.arms_to_wrists`` maps a perturbed test input)."""
    from ..data.perturb import perturb_sequence
    from ..sensors import wrist_frames
    from .pipeline import arms_to_wrists

    moved = perturb_sequence(seq, "T", C.ANET_WRIST_SIGMA, rng)
    return arms_6d(arms_to_wrists(moved, {s: wrist_frames(moved, s) for s in NET_SIDES}))


def voxel_feature(
    library: ObjectLibrary, seq: Sequence, wrists: dict | None = None
) -> np.ndarray:
    """The voxel-ambient array ``(T, 2, 1014)`` float16 of :func:`sequence_features`."""
    return ambient_sensor(library, seq, wrists or all_wrists(seq), "voxel").astype(np.float16)


# --- whole splits ----------------------------------------------------------------------------
@dataclass
class FrameSet:
    """All frames of one split, concatenated over sequences (see the module docstring).

    ``seq_id (N,)`` indexes ``names`` / ``objects``; ``start``/``end`` ``(N,)`` are the
    frame's sequence bounds in this array (for pairs and future windows).
    """

    names: list
    objects: list
    seq_id: np.ndarray
    start: np.ndarray
    end: np.ndarray
    body: np.ndarray
    ambient: np.ndarray
    proximity: np.ndarray
    mean_dist: np.ndarray
    gt_poses: np.ndarray
    gt_proximity: np.ndarray
    gt_min_dist: np.ndarray
    arms: np.ndarray
    noisy_arms: np.ndarray
    wrist_rot: np.ndarray
    wrist_transl: np.ndarray
    obj_rot: np.ndarray
    obj_transl: np.ndarray
    hand_scale: np.ndarray
    noisy_arms_wrist: np.ndarray | None = None  # None in a FrameSet built without it (tests)
    voxel: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.seq_id)

    def next_index(self, idx: np.ndarray, k: int = 1) -> np.ndarray:
        """Index of frame t+k in the same sequence, clamped at its last frame."""
        return np.minimum(idx + k, self.end[idx] - 1)

    def pair_index(self) -> np.ndarray:
        """Frames t with a following frame t+1 in their sequence (CNet's pairs)."""
        idx = np.arange(len(self))
        return idx[idx + 1 < self.end]

    def object_pose(self, idx: np.ndarray) -> np.ndarray:
        """``grip-blind``'s object input ``(*idx.shape, 2, 9)`` float32 of frames ``idx``
        (:func:`~grip_bench.sensors.object_pose_feature` of the stored object and wrist
        poses: no mesh is read, so the feature cache needs no new array)."""
        return object_pose_feature(self.obj_rot[idx], self.obj_transl[idx],
                                   self.wrist_rot[idx], self.wrist_transl[idx])

    def future(self, idx: np.ndarray, n: int, online: bool = False) -> np.ndarray:
        """Future cue ``(B, 2*2*n)`` of frames ``idx`` (``sensors.future_cue`` layout)."""
        if n == 0:
            return np.zeros((len(idx), 0), np.float32)
        k = np.arange(n + 1)[None]
        j = idx[:, None] if online else np.minimum(idx[:, None] + k, self.end[idx][:, None] - 1)
        d = self.mean_dist[np.broadcast_to(j, (len(idx), n + 1))]  # (B, n+1, 2)
        cue = np.stack([d[:, 1:], np.diff(d, axis=1) * C.FPS], -1)  # (B, n, 2, 2)
        return cue.transpose(0, 2, 1, 3).reshape(len(idx), -1).astype(np.float32)


def _concat(per_seq: list[dict], names: list, objects: list) -> FrameSet:
    lengths = np.array([len(f["body"]) for f in per_seq])
    ends = np.cumsum(lengths)
    seq_id = np.repeat(np.arange(len(per_seq)), lengths)
    arrays = {k: np.concatenate([f[k] for f in per_seq]) for k in per_seq[0]}
    return FrameSet(names=names, objects=objects, seq_id=seq_id, start=(ends - lengths)[seq_id],
                    end=ends[seq_id], **arrays)


def split_files(data_dir: Path, split: str) -> list[Path]:
    """Sequence files of a split; ``val`` falls back to every 10th train file when empty."""
    from ..data.splits import sequences_in_split

    files = sequences_in_split(data_dir, split)
    if split == "val" and not files:
        files = sequences_in_split(data_dir, "train")[::10]
    if not files:
        raise InputError(f"no sequences in split {split!r}", data_dir)
    return files


def _cache_path(cache_dir: Path, data_hash: str, split: str, voxel: bool, seed: int) -> Path:
    key = hashlib.sha256(
        f"{data_hash}|{split}|{voxel}|{seed}|{FEATURE_VERSION}".encode()
    ).hexdigest()
    return Path(cache_dir) / f"grip-{split}-{key[:16]}.npz"


def _save(path: Path, fs: FrameSet) -> None:
    arrays = {f.name: getattr(fs, f.name) for f in fields(fs) if getattr(fs, f.name) is not None}
    arrays["names"], arrays["objects"] = np.array(fs.names), np.array(fs.objects)
    with atomic_file(path) as f:
        np.savez(f, **arrays)


def _load(path: Path) -> FrameSet:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["names"], arrays["objects"] = list(arrays["names"]), list(arrays["objects"])
    return FrameSet(**arrays)


def build_split(data_dir: str | os.PathLike, split: str, *,
                cache_dir: str | os.PathLike | None = None, voxel: bool = False, seed: int = 0,
                data_hash: str | None = None, progress: bool = False) -> FrameSet:
    """Per-frame arrays of every sequence of ``split`` (cached when ``cache_dir`` is given).

    The arm noise of each sequence is seeded by ``(seed, sequence name)``. A voxel split is
    the plain split (built, or read from the cache, with the same arguments) plus its voxel
    arrays: only the voxel sensor is computed for it. Features are computed with one torch
    thread (the small tensor operations only lose time to thread hand-offs; the arrays are
    the same for any thread count).
    """
    from ..data.grab_io import dataset_hash

    data_dir = Path(data_dir)
    path = None
    if cache_dir is not None:
        data_hash = data_hash or dataset_hash(data_dir)
        path = _cache_path(cache_dir, data_hash, split, voxel, seed)
        if path.is_file():
            return _load(path)
    with single_thread():
        if voxel:
            base = build_split(data_dir, split, cache_dir=cache_dir, voxel=False, seed=seed,
                               data_hash=data_hash, progress=progress)
            fs = _add_voxel(base, data_dir, split, progress)
        else:
            fs = _build(data_dir, split, seed, progress)
    if path is not None:
        _save(path, fs)
    return fs


def _build(data_dir: Path, split: str, seed: int, progress: bool) -> FrameSet:
    from ..data.grab_io import read_grab
    from ..data.library import ObjectLibrary
    from ..data.perturb import sequence_rng

    library = ObjectLibrary(data_dir)
    files = split_files(data_dir, split)
    per_seq, names, objects = [], [], []
    for f in _progress(files, f"features {split}", progress):
        seq = read_grab(f)
        per_seq.append(
            sequence_features(library, seq, voxel=False, rng=sequence_rng(seed, seq.name))
        )
        names.append(seq.name)
        objects.append(seq.obj_name)
    return _concat(per_seq, names, objects)


def _add_voxel(base: FrameSet, data_dir: Path, split: str, progress: bool) -> FrameSet:
    """``base`` (a plain split) with the voxel arrays of its sequences, in its frame order."""
    from ..data.grab_io import read_grab
    from ..data.library import ObjectLibrary

    library = ObjectLibrary(data_dir)
    files = split_files(data_dir, split)
    voxels, names = [], []
    for f in _progress(files, f"voxel features {split}", progress):
        seq = read_grab(f)
        voxels.append(voxel_feature(library, seq))
        names.append(seq.name)
    if [str(n) for n in names] != [str(n) for n in base.names]:
        raise InputError(f"the {split} split changed while its features were built", data_dir)
    arrays = {f.name: getattr(base, f.name) for f in fields(base) if f.name != "voxel"}
    return FrameSet(**arrays, voxel=np.concatenate(voxels))


def _progress(items: Iterable[Any], desc: str, enabled: bool) -> Iterable[Any]:
    if not enabled:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=desc, unit="seq", leave=False)


def recompute_proximity(
    fs: FrameSet, idx: np.ndarray, poses_6d: np.ndarray, library: ObjectLibrary
) -> np.ndarray:
    """Proximity sensor ``(N, 2, 99)`` float32 of hands ``poses_6d (N, 2, 15, 6)`` placed at the
    GT wrists of frames ``idx`` (stage two, Fig. 3-C), one object field per sequence."""
    from ..sensors import attention

    out = np.zeros((len(idx), 2, C.PROXIMITY_N_VERTS), np.float32)
    sid = fs.seq_id[idx]
    for s in np.unique(sid):
        g = np.flatnonzero(sid == s)
        f = idx[g]
        pts = hand_proximity_points(poses_6d[g], fs.wrist_rot[f].astype(float),
                                    fs.wrist_transl[f].astype(float), float(fs.hand_scale[f[0]]))
        # GRAB's row-vector convention world = local @ R + t inverts to (world - t) @ R.T
        local = np.einsum(
            "thnj,tij->thni", pts - fs.obj_transl[f][:, None, None], fs.obj_rot[f].astype(float)
        )
        # far="coarse": the distances of sensors.signed_object_distance, as at inference
        sd = library.field(str(fs.objects[s])).signed_distance(local, far="coarse")
        out[g] = attention(np.maximum(sd, 0.0), C.PROXIMITY_DECAY)
    return out
