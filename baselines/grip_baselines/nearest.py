"""``nearest-neighbour``: copy the finger pose of the training frame with the closest sensors.

Reference row (no learning beyond an index). A frame's key is GRIP's stage-one sensor
reading of one hand at its input wrist (:func:`grip_bench.sensors.stage_one`): the
ambient feature ``exp(-5 d)`` at 1024 hemisphere points and the proximity feature
``exp(-50 d)`` of the relaxed mean hand's 99 vertices. The proximity block is scaled by
``sqrt(1024 / 99)`` so both blocks weigh alike. Keys are reduced by PCA and searched
with a KD-tree (rebuilt from the stored keys at load).

Both hands share one index: the sensors of a left hand are the mirror image of a right
hand's (same points, x-mirrored), so left frames enter with their poses mirrored into
the right hand's convention and are mirrored back when copied. Wrists stay the input's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from grip_bench.core.frames import NET_SIDES, SIDES, mirror_pose
from grip_bench.methods.api import MethodSpec, PredictContext, register_method

from . import common as U

if TYPE_CHECKING:
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.data.sequence import Sequence


@dataclass
class NearestTrainConfig:
    """Profile section ``[nearest]``."""

    n_components: int = 32  # PCA dimensions of the keys
    max_frames: int = 50000  # training frames indexed (hands counted apiece; 0 = all)
    max_sequences: int = 0


@dataclass
class NearestIndexConfig:
    """Sizes of the stored index (the checkpoint's 'network')."""

    n_items: int = 1
    feat_dim: int = 1123
    n_components: int = 32

    def build(self) -> NearestIndex:
        return NearestIndex(self)


class NearestIndex(nn.Module):
    """Buffers only: PCA ``mean (D,)``, ``components (k, D)``, ``keys (N, k)``,
    ``poses (N, 45)``."""

    def __init__(self, cfg: NearestIndexConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.register_buffer("mean", torch.zeros(cfg.feat_dim, dtype=torch.float64))
        self.register_buffer(
            "components", torch.zeros(cfg.n_components, cfg.feat_dim, dtype=torch.float64)
        )
        self.register_buffer(
            "keys", torch.zeros(cfg.n_items, cfg.n_components, dtype=torch.float64)
        )
        self.register_buffer("poses", torch.zeros(cfg.n_items, 45, dtype=torch.float64))

    def reduce(self, feats: np.ndarray) -> np.ndarray:
        """Features (M, D) -> PCA keys (M, k) (numpy, float64, on the CPU)."""
        return (feats - self.mean.cpu().numpy()) @ self.components.cpu().numpy().T


def sensor_features(library: ObjectLibrary, seq: Sequence) -> np.ndarray:
    """Per hand and frame keys ``(2, T, D)`` in :data:`~grip_bench.core.frames.SIDES` order
    (right, left)."""
    from grip_bench.sensors import stage_one

    s = stage_one(library, seq)
    amb, prox = s.ambient.astype(np.float64), s.proximity.astype(np.float64)
    w = np.sqrt(amb.shape[-1] / prox.shape[-1])
    feats = np.concatenate([amb, w * prox], -1)  # (T, 2, D), hands (left, right)
    return np.stack([feats[:, NET_SIDES.index(side)] for side in SIDES])


def _training_items(
    seqs: list[Sequence], library: ObjectLibrary, cfg: NearestTrainConfig, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Keys ``(N, D)`` and right-hand-frame finger poses ``(N, 45)`` of the training hand
    frames (each sequence's right hand, then its left), at most ``cfg.max_frames`` of them
    drawn with ``seed``. The draw needs only the count (every sequence gives T frames per
    hand), so only the drawn rows are kept while the sequences are read: the same arrays as
    keeping every frame and then ``[keep]``, without ~2 GB of unused keys at default size."""
    total = sum(len(SIDES) * seq.n_frames for seq in seqs)
    keep = None
    if cfg.max_frames and total > cfg.max_frames:
        keep = np.sort(np.random.default_rng(seed).choice(total, cfg.max_frames, replace=False))
    feats, poses, at = [], [], 0
    for seq in seqs:
        f = sensor_features(library, seq)
        for k, side in enumerate(SIDES):
            pose = np.asarray(seq.hand_params(side)["hand_pose"], float)
            pose = mirror_pose(pose) if side == "left" else pose
            rows = slice(None) if keep is None else \
                keep[np.searchsorted(keep, at):np.searchsorted(keep, at + len(f[k]))] - at
            feats.append(f[k][rows])
            poses.append(pose[rows])
            at += len(f[k])
    if at != total:  # a sequence whose sensors do not give one row per frame
        raise ValueError(f"nearest-neighbour: {at} sensor rows for {total} hand frames")
    return np.concatenate(feats), np.concatenate(poses)


def build_index(feats: np.ndarray, poses: np.ndarray, n_components: int) -> NearestIndex:
    """PCA of ``feats (N, D)`` (top ``n_components`` right singular vectors) and the keys."""
    mean = feats.mean(0)
    k = min(n_components, *feats.shape)
    _, _, vt = np.linalg.svd(feats - mean, full_matrices=False)
    index = NearestIndexConfig(len(feats), feats.shape[1], k).build()
    index.mean.copy_(torch.as_tensor(mean))
    index.components.copy_(torch.as_tensor(vt[:k]))
    index.keys.copy_(torch.as_tensor(index.reduce(feats)))
    index.poses.copy_(torch.as_tensor(poses))
    return index


class NearestMethod(U.TrainedMethod):
    """Retrieval of training finger poses by sensor similarity.

    The index (a buffers-only module) is put on the requested device like every
    baseline's networks; the search itself is a KD-tree (scipy, CPU), so :meth:`load`
    also keeps CPU copies of what the search reads (PCA, keys, poses), taken once.
    """

    section, config_cls, networks = "nearest", NearestTrainConfig, {"index": NearestIndexConfig}

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.index: NearestIndex | None = None
        self.tree: cKDTree | None = None
        self._cpu: NearestIndex | None = None

    def fit(
        self, data_dir: Path, cfg: NearestTrainConfig, seed: int, progress: bool,
        device: torch.device,
    ) -> tuple[dict[str, torch.nn.Module], dict]:
        from grip_bench.core.memory import release_freed_memory
        from grip_bench.data.library import ObjectLibrary

        seqs = U.train_sequences(data_dir, cfg.max_sequences, seed)
        feats, poses = _training_items(seqs, ObjectLibrary(data_dir), cfg, seed)
        del seqs
        release_freed_memory()  # the sensors' freed arrays, before the SVD's (4.3 -> 2.5 GB)
        index = build_index(feats, poses, cfg.n_components).to(device)
        U.log(progress, self.name, f"indexed {len(feats)} hand frames")
        return {"index": index}, {"n_samples": len(feats)}

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        self.index = self.load_checkpoint(checkpoint, device)[0]["index"]
        self._cpu = self.index if self.device.type == "cpu" else _cpu_copy(self.index)
        self.tree = cKDTree(self._cpu.keys.numpy())

    def predict(self, seq: Sequence, ctx: PredictContext) -> Sequence:
        """Both hands' fingers copied from the nearest training frames; wrists kept."""
        self._loaded(self.tree)
        index = self._cpu
        feats = sensor_features(ctx.library, seq)
        new = {}
        for k, side in enumerate(SIDES):
            _, nn_idx = self.tree.query(index.reduce(feats[k]))
            pose = index.poses.numpy()[nn_idx]
            new[side] = {"hand_pose": mirror_pose(pose) if side == "left" else pose}
        return seq.with_hands(**new)


def _cpu_copy(index: NearestIndex) -> NearestIndex:
    """A CPU copy of an index on another device (the original stays where it is)."""
    out = NearestIndexConfig(index.cfg.n_items, index.cfg.feat_dim, index.cfg.n_components)
    copy = out.build()
    copy.load_state_dict({k: v.cpu() for k, v in index.state_dict().items()})
    return copy


register_method(
    MethodSpec(
        name="nearest-neighbour",
        description="copy the finger pose of the training frame with the nearest GRIP sensor "
        "reading",
        factory=NearestMethod,
        needs=("object", "wrists", "train_data"),
    )
)
