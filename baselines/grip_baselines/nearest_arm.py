"""``nearest-arm``: copy both hands' finger poses of the training frame whose arm motion is
closest. A probe of the data (issue #16; a reference row of GRIP's Table 2, never marked
best there; on the leaderboard it competes like ``nearest-neighbour``): its key reads the
body's arms and wrists only, never the object (no mesh, no pose, no identity).

Key of frame t, over the window ``t + NEAREST_ARM_OFFSETS`` (clamped at the sequence's ends;
offline, so the window reads future frames as GRIP's offline cue does), three blocks:

- **arms**: the local rotations of the four arm joints (left/right shoulder, left/right
  elbow: ANet's joints) in 6D, ``4 x 6`` per window frame;
- **wrist positions** (m) and **wrist rotations** (6D) of both hands in the body's root
  frame (``world = R_root @ local + transl``), ``2 x 3`` and ``2 x 6`` per window frame.
  The wrists are the input hand wrists (``seq.hand_params(side)``), as for every method
  that reads wrists.

Blocks mix radians-ish 6D entries and metres, so each block is divided by the square root
of its total variance over the indexed training frames: each block then adds about the
same to a squared distance between two random frames. The scaled keys are reduced by PCA
and searched with a KD-tree (rebuilt from the stored keys at load). One search per frame:
both hands are copied from the same training frame; wrists stay the input's.

The profile section is ``[nearest]`` (PCA dimensions, frame cap, sequence cap), shared with
``nearest-neighbour``; ``max_frames`` counts frames here (each holds both hands).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from torch import nn

from grip_bench.bodies.layouts import SMPLX_INDEX
from grip_bench.core import constants as C
from grip_bench.core.frames import SIDES
from grip_bench.geometry.rotations import axis_angle_to_rotation_6d, matrix_to_rotation_6d
from grip_bench.methods.api import MethodSpec, PredictContext, register_method

from . import common as U

if TYPE_CHECKING:
    from grip_bench.data.sequence import Sequence

ARM_JOINTS = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow")
W = len(C.NEAREST_ARM_OFFSETS)
# (name, columns) of the key's blocks, in key order (module docstring)
BLOCKS = (("arms", W * len(ARM_JOINTS) * 6), ("wrist_position", W * 2 * 3),
          ("wrist_rotation", W * 2 * 6))
FEAT_DIM = sum(n for _, n in BLOCKS)


@dataclass
class NearestTrainConfig:
    """Profile section ``[nearest]``, shared with ``nearest-neighbour`` (the same keys and
    meaning; this module does not import that one, whose code reads GRIP's sensors, so an
    edit of the sensors leaves this method's cache keys alone)."""

    n_components: int = 32  # PCA dimensions of the keys
    max_frames: int = 50000  # training frames indexed (0 = all); each frame holds both hands
    max_sequences: int = 0


@dataclass
class ArmIndexConfig:
    """Sizes of the stored index (the checkpoint's 'network')."""

    n_items: int = 1
    feat_dim: int = FEAT_DIM
    n_components: int = 32

    def build(self) -> ArmIndex:
        return ArmIndex(self)


class ArmIndex(nn.Module):
    """Buffers only: per-column block scale ``scale (D,)``, PCA ``mean (D,)`` and
    ``components (k, D)`` of the scaled keys, ``keys (N, k)``, finger ``poses (N, 2, 45)``
    (axis-angle, hands in ``SIDES`` order: right, left)."""

    def __init__(self, cfg: ArmIndexConfig) -> None:
        super().__init__()
        self.cfg = cfg
        f64 = torch.float64
        self.register_buffer("scale", torch.ones(cfg.feat_dim, dtype=f64))
        self.register_buffer("mean", torch.zeros(cfg.feat_dim, dtype=f64))
        self.register_buffer("components", torch.zeros(cfg.n_components, cfg.feat_dim, dtype=f64))
        self.register_buffer("keys", torch.zeros(cfg.n_items, cfg.n_components, dtype=f64))
        self.register_buffer("poses", torch.zeros(cfg.n_items, 2, 45, dtype=f64))

    def reduce(self, feats: np.ndarray) -> np.ndarray:
        """Unscaled keys (M, D) -> PCA keys (M, k) (numpy, float64, on the CPU)."""
        scaled = feats * self.scale.cpu().numpy()
        return (scaled - self.mean.cpu().numpy()) @ self.components.cpu().numpy().T


def arm_features(seq: Sequence) -> np.ndarray:
    """Keys ``(T, FEAT_DIM)`` float64 of every frame (module docstring): arms 6D, then wrist
    positions (m), then wrist rotations (6D), each block window-frame-major."""
    T = seq.n_frames
    if T < 1:
        return np.zeros((0, FEAT_DIM))
    bp = np.asarray(seq.body["body_pose"], np.float64).reshape(T, 21, 3)
    arms = axis_angle_to_rotation_6d(bp[:, [SMPLX_INDEX[j] - 1 for j in ARM_JOINTS]])  # (T,4,6)
    root = Rotation.from_rotvec(np.asarray(seq.body["global_orient"], np.float64)).as_matrix()
    root_t = np.swapaxes(root, -1, -2)  # (T, 3, 3) world -> body frame
    origin = np.asarray(seq.body["transl"], np.float64)
    pos, rot = [], []
    for side in SIDES:
        p = seq.hand_params(side)
        w_rot = Rotation.from_rotvec(np.asarray(p["global_orient"], np.float64)).as_matrix()
        pos.append(np.einsum("tij,tj->ti", root_t, np.asarray(p["transl"], np.float64) - origin))
        rot.append(matrix_to_rotation_6d(root_t @ w_rot))
    win = np.clip(np.arange(T)[:, None] + np.array(C.NEAREST_ARM_OFFSETS)[None], 0, T - 1)
    blocks = (arms, np.stack(pos, 1), np.stack(rot, 1))  # (T, 4, 6), (T, 2, 3), (T, 2, 6)
    return np.concatenate([b[win].reshape(T, -1) for b in blocks], 1)


def block_scale(feats: np.ndarray) -> np.ndarray:
    """Per-column scale ``(D,)``: ``1 / sqrt(total variance of the column's block)`` over
    ``feats (N, D)`` (1 for a block that does not vary)."""
    scale, at = np.ones(feats.shape[1]), 0
    for _, n in BLOCKS:
        var = float(feats[:, at:at + n].var(0).sum())
        scale[at:at + n] = 1.0 / np.sqrt(var) if var > 0 else 1.0
        at += n
    return scale


def _training_items(
    seqs: list[Sequence], cfg: NearestTrainConfig, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Keys ``(N, D)`` and both hands' poses ``(N, 2, 45)`` of the training frames."""
    feats = np.concatenate([arm_features(s) for s in seqs])
    poses = np.concatenate([
        np.stack([np.asarray(s.hand_params(side)["hand_pose"], np.float64).reshape(-1, 45)
                  for side in SIDES], 1) for s in seqs])
    if cfg.max_frames and len(feats) > cfg.max_frames:
        keep = np.sort(
            np.random.default_rng(seed).choice(len(feats), cfg.max_frames, replace=False)
        )
        feats, poses = feats[keep], poses[keep]
    return feats, poses


def build_index(feats: np.ndarray, poses: np.ndarray, n_components: int) -> ArmIndex:
    """Block scale, PCA of the scaled ``feats (N, D)`` (top ``n_components`` right singular
    vectors) and the keys; ``poses (N, 2, 45)``."""
    scale = block_scale(feats)
    scaled = feats * scale
    mean = scaled.mean(0)
    k = min(n_components, *feats.shape)
    _, _, vt = np.linalg.svd(scaled - mean, full_matrices=False)
    index = ArmIndexConfig(len(feats), feats.shape[1], k).build()
    index.scale.copy_(torch.as_tensor(scale))
    index.mean.copy_(torch.as_tensor(mean))
    index.components.copy_(torch.as_tensor(vt[:k]))
    index.keys.copy_(torch.as_tensor(index.reduce(feats)))
    index.poses.copy_(torch.as_tensor(poses))
    return index


class NearestArmMethod(U.TrainedMethod):
    """Retrieval of training finger poses by arm-motion similarity (module docstring).

    The index lives on the requested device like every baseline's networks; the search is
    a KD-tree (scipy, CPU) over CPU copies taken once at :meth:`load`.
    """

    section, config_cls, networks = "nearest", NearestTrainConfig, {"index": ArmIndexConfig}

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.tree: cKDTree | None = None
        self._cpu: ArmIndex | None = None

    def fit(
        self, data_dir: Path, cfg: NearestTrainConfig, seed: int, progress: bool,
        device: torch.device,
    ) -> tuple[dict[str, torch.nn.Module], dict]:
        seqs = U.train_sequences(data_dir, cfg.max_sequences, seed)
        feats, poses = _training_items(seqs, cfg, seed)
        index = build_index(feats, poses, cfg.n_components).to(device)
        U.log(progress, self.name, f"indexed {len(feats)} frames")
        return {"index": index}, {"n_samples": len(feats)}

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        index = self.load_checkpoint(checkpoint, device)[0]["index"]
        cpu = ArmIndexConfig(index.cfg.n_items, index.cfg.feat_dim, index.cfg.n_components)
        self._cpu = cpu.build()
        self._cpu.load_state_dict({k: v.cpu() for k, v in index.state_dict().items()})
        self.tree = cKDTree(self._cpu.keys.numpy())

    def predict(self, seq: Sequence, ctx: PredictContext) -> Sequence:
        """Both hands' fingers copied from the nearest training frame; wrists kept."""
        self._loaded(self.tree)
        _, nn_idx = self.tree.query(self._cpu.reduce(arm_features(seq)))
        poses = self._cpu.poses.numpy()[nn_idx]  # (T, 2, 45)
        return seq.with_hands(**{side: {"hand_pose": poses[:, k]}
                                 for k, side in enumerate(SIDES)})


register_method(
    MethodSpec(
        name="nearest-arm",
        description="copy the finger poses of the training frame with the nearest arm and "
        "wrist motion; no object input (probe)",
        factory=NearestArmMethod,
        needs=("body", "wrists", "train_data"),
    )
)
