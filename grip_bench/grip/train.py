"""Training GRIP: ANet, then CNet, then RNet (on CNet's outputs and perturbed GT hands).

Each network: Adam, ReduceLROnPlateau on the validation loss, early stopping with the
best weights kept, tqdm progress with the loss terms. Deterministic on CPU for a seed:
the frame order of every epoch and the torch RNG (dropout) are re-seeded from
``(seed, stage, epoch)``, so a run resumed from its partial checkpoint (written after
every epoch, ``<out>.partial``) ends with the same weights as an uninterrupted one.

Hyper-parameters come from a profile's ``[grip]`` section (``grip_bench/profiles``).
Loss weights are :class:`~grip_bench.grip.losses.LossConfig`'s (all 1, latent 1e-3).

RNet's loss is GRIP Eq. 4 on the refined hands: pose L2, vertex L1 and the proximity L1,
the last read through each object's distance grid (:class:`HandObjectDistance`), plus our
addition ``w_penetration`` x the summed depth of hand vertices inside the object. The
proximity term alone is blind to depth (exp(-50 d) is 1 for touching and penetrating
vertices alike); measured on the default profile's test split when the weight was chosen
(RNet retrained alone on one CNet), right hand: IV 1.14 -> 0.50 cm3 and contact ratio
98.4 -> 98.4 % with ``w_penetration = 1``.

ANet is trained residually: it predicts the 6D correction of the noisy arm frames and its
head starts at zero, so an undertrained ANet leaves the arms as they are instead of
replacing them with a blurred mean. Its samples (``anet_batch``) carry the paper's joint
noise or GRAB-T-like wrist noise mapped to the arms by IK, at a drawn scale (clean input
included), and frame t carries part of its own noise, as ANet's previous output does in
the recursion. Measured on the default data (12 GRAB-T 0.01 test sequences, both wrists)
when this was chosen: the wrist error 15.9 mm of the input falls to 11.9 mm, and clean
input moves by 1.1 mm; the earlier ANet (clean frame t, joint noise only, 4 epochs on
12,000 frames) moved no wrist by more than 0.2 mm, and trained longer the same way its
recursion drifted by half a metre.

Under torchrun (or ``grip-bench train --nproc N``) the three networks train with DDP
(gloo, CPU; :mod:`grip_bench.nn.ddp`): ``batch_size`` is the global batch, each rank takes
its share of every seeded global batch, BatchNorm uses the global batch's statistics, the
validation loss is reduced over the ranks and only rank 0 writes files
(docs/distributed_training.md). One process runs the plain path, byte for byte as before.

``device`` (``--device cuda``): the three networks, every batch (built as CPU tensors from
the numpy features, moved once in :meth:`Stage.fetch`), the hand model of the vertex loss
and the distance grids of RNet's loss live on that device; the loss of an epoch is read
back once at its end, not per batch. Data preparation stays on the CPU (features, RNet's
samples: CNet's predictions come back once per chunk). Checkpoints, partial checkpoints
and the shared ANet hold CPU tensors, so a GPU-trained file loads anywhere. Under DDP
with ``cuda`` each rank trains on ``cuda:LOCAL_RANK`` over nccl. A GPU training is
deterministic for a seed on one machine (``CUBLAS_WORKSPACE_CONFIG``, set here when
unset) but not bit-equal to the CPU's; the CPU path writes the same bytes as before the
device existed, and a non-CPU training's fingerprint names its device type, so its
partial checkpoint, shared ANet and finished checkpoint never stand in for a CPU one.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from numpy.typing import ArrayLike

from ..core import constants as C
from ..core.checkpoint import load_checkpoint, save_checkpoint
from ..core.errors import InputError
from ..core.io import atomic_file
from ..geometry.distance import grid_signed_distance_many
from ..geometry.rotations import rotation_6d_to_axis_angle, rotation_6d_to_matrix
from ..nn import ddp
from ..nn.terms import penetration_depth, proximity_attention, proximity_l1
from .anet import ANetConfig
from .cnet import CNetConfig, future_cue_dim
from .data import FEATURE_VERSION, FrameSet, build_split, hand_model, recompute_proximity
from .dropout import use_uniform_mask_dropout
from .losses import LossConfig, anet_loss, cnet_loss, rnet_loss
from .rnet import RNetConfig

if TYPE_CHECKING:
    from ..data.library import ObjectLibrary
    from .anet import ANet
    from .cnet import CNet
    from .rnet import RNet

STAGES = ("anet", "cnet", "rnet")
CONFIG_CLASSES = {"anet": ANetConfig, "cnet": CNetConfig, "rnet": RNetConfig}
VOXEL_DIM = int(np.prod(C.VOXEL_CELLS))
# cuBLAS's deterministic workspace setting (one of the two values its documentation gives
# for reproducible results; torch's deterministic mode asks for it on CUDA >= 10.2)
CUBLAS_WORKSPACE = ":4096:8"
CPU = torch.device("cpu")
PROGRESS_EVERY = 10  # batches between the progress bar's loss terms (each read syncs a GPU)


@dataclass(frozen=True)
class Variant:
    """The training switches of one GRIP method (GRIP Tab. 2 and Tab. 4-right).

    ``ambient``: "distance" (GRIP), "voxel" or "none"; ``proximity``: the stage-one
    proximity input. An ablated sensor is fed as a constant 0 (one input per hand for
    ambient; the 99 proximity inputs stay so that CNet still predicts proximity as a target).

    ``geometry=False`` (``grip-blind``, a probe of the data, not a GRIP ablation): CNet sees
    no object geometry. It needs every geometry input off (``ambient="none"``,
    ``proximity=False``, ``future_frames=0``: the cue is a distance to the surface), and
    the ambient slot carries the object's pose in each wrist frame instead
    (``sensors.object_pose_feature``, 9 per hand). RNet reads proximity, so it is neither
    trained nor run. The GT proximity stays CNet's auxiliary target (training only).
    """

    ambient: str = "distance"
    proximity: bool = True
    consistency: str = "latent"
    future_frames: int = C.FUTURE_FRAMES
    geometry: bool = True

    def __post_init__(self) -> None:
        if not self.geometry and (self.ambient != "none" or self.proximity
                                  or self.future_frames):
            raise InputError("a variant without geometry needs ambient='none', proximity=False "
                             "and future_frames=0 (each reads the object's surface)", "geometry")

    def train_key(self) -> str:
        """Identical keys train identical networks (methods may share a checkpoint).

        A switch added later enters the key only where it differs from its default, so
        every earlier variant keeps its key (and its checkpoints and caches)."""
        key = (f"ambient={self.ambient},proximity={int(self.proximity)},"
               f"consistency={self.consistency},future={self.future_frames}")
        return key if self.geometry else key + ",geometry=0"

    @property
    def ambient_dim(self) -> int:
        """CNet's ambient-slot inputs per hand (the object pose's 9 without geometry)."""
        if not self.geometry:
            return C.OBJECT_POSE_DIM
        return {"distance": C.AMBIENT_N_POINTS, "voxel": VOXEL_DIM, "none": 1}[self.ambient]


def build_configs(hp: dict, variant: Variant) -> dict:
    """Network configs ``{anet, cnet, rnet}`` from a profile's ``[grip]`` section."""
    drop = float(hp["dropout"])
    cnet = CNetConfig(
        ambient_dim=variant.ambient_dim,
        future_dim=future_cue_dim(variant.future_frames),
        hidden=hp["hidden"],
        width=hp["width"],
        latent=hp["latent"],
        dropout=drop,
        consistency=variant.consistency,
    )
    anet = ANetConfig(
        hidden=hp["anet_hidden"], width=hp["anet_width"], latent=hp["latent"], dropout=drop,
        relative_future=True,
    )
    rnet = RNetConfig(hidden=hp["rnet_hidden"], width=hp["rnet_width"], dropout=drop)
    return {"anet": anet, "cnet": cnet, "rnet": rnet}


# --- batches ---------------------------------------------------------------------------
def _t(a: ArrayLike) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32)


def sensor_inputs(
    ambient: np.ndarray, proximity: np.ndarray, variant: Variant
) -> tuple[np.ndarray, np.ndarray]:
    """Apply the variant's ablation to stage-one sensors ``(..., 2, A)``, ``(..., 2, 99)``."""
    if variant.ambient == "none":
        ambient = np.zeros((*ambient.shape[:-1], 1), np.float32)
    if not variant.proximity:
        proximity = np.zeros_like(proximity)
    return ambient, proximity


def cnet_batch(fs: FrameSet, idx: np.ndarray, variant: Variant) -> dict:
    """CNet inputs and targets for pairs (t, t+1) starting at frames ``idx``."""
    j = fs.next_index(idx)
    pair = np.stack([idx, j], 1)  # (B, 2)
    if variant.geometry:
        amb = fs.voxel if variant.ambient == "voxel" else fs.ambient
        amb, prox = sensor_inputs(amb[pair].astype(np.float32), fs.proximity[pair], variant)
    else:  # the object's pose in the wrist frames; no sensor reading enters
        amb, prox = fs.object_pose(pair), np.zeros(fs.proximity[pair].shape, np.float32)
    return {
        "body": _t(fs.body[pair]), "ambient": _t(amb), "proximity": _t(prox),
        "future": _t(fs.future(idx, variant.future_frames)),
        "poses_t": _t(fs.gt_poses[idx]), "poses_t1": _t(fs.gt_poses[j]),
        "proximity_t": _t(fs.gt_proximity[idx]), "proximity_t1": _t(fs.gt_proximity[j]),
    }


def anet_batch(fs: FrameSet, idx: np.ndarray, cfg: ANetConfig) -> dict:
    """ANet inputs (arms at t, noisy arms at t+1..t+5) and residual targets (B, F, 4, 6).

    Each sample's noise is drawn from its frame index alone (so a DDP rank's share of a batch
    gets the same samples as one process): the paper's joint noise or, for
    ``ANET_WRIST_SHARE`` of the samples, the IK-mapped wrist noise (``noisy_arms_wrist``),
    scaled by a factor in ``ANET_NOISE_SCALE``. Frame t carries a fraction in [0, 1) of its
    own noise: at inference it is ANet's previous output, not the clean arms, and an ANet
    trained on clean frames t trusts them fully, so its recursion drifted (wrists 0.5 m off
    after 300 frames, measured on the default data).
    """
    fut = np.stack([fs.next_index(idx, k) for k in range(1, cfg.n_future + 1)], 1)
    frames = np.stack([fs.next_index(idx, k) for k in range(cfg.n_frames)], 1)
    scale, own, wrist = (_frame_uniform(idx, salt) for salt in (1, 2, 3))
    lo, hi = C.ANET_NOISE_SCALE
    scale = (lo + (hi - lo) * scale)[:, None, None, None]
    wrist = wrist < C.ANET_WRIST_SHARE if fs.noisy_arms_wrist is not None else wrist < 0

    def noisy(at: np.ndarray) -> np.ndarray:  # (B, K) frame indices -> (B, K, 4, 6)
        joint = fs.noisy_arms[at] - fs.arms[at]
        if fs.noisy_arms_wrist is not None:
            joint = np.where(wrist[:, None, None, None], fs.noisy_arms_wrist[at] - fs.arms[at],
                             joint)
        return (fs.arms[at] + scale * joint).astype(np.float32)

    inputs = noisy(frames)
    current = fs.arms[idx] + own[:, None, None] * (inputs[:, 0] - fs.arms[idx])
    inputs[:, 0] = current
    return {"current": _t(current.astype(np.float32)), "noisy_future": _t(noisy(fut)),
            "target": _t(fs.arms[frames] - inputs)}


def _frame_uniform(idx: np.ndarray, salt: int) -> np.ndarray:
    """A uniform number in [0, 1) per frame index ``(B,)`` (splitmix64 of index and salt)."""
    with np.errstate(over="ignore"):  # uint64 arithmetic wraps by design
        x = idx.astype(np.uint64) + np.uint64(salt) * np.uint64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        x = x ^ (x >> np.uint64(31))
    return (x >> np.uint64(11)).astype(np.float64) / float(1 << 53)


class VertexFn:
    """Differentiable hand vertices for the vertex L1: ``(..., 2, 15, 6) -> (..., 2, K, 3)``.

    K = ``loss_vertices`` vertices at a fixed stride over the mesh (0: all), in the hand frame.
    The hand model and the vertex indices live on ``device``, the poses' device.
    """

    def __init__(self, n_vertices: int, device: torch.device = CPU):
        self.model = hand_model(1.0, device)
        V = self.model.hands[0].num_vertices
        self.ids = (
            None if n_vertices in (0, V) else torch.as_tensor(
                np.linspace(0, V - 1, n_vertices).round().astype(int), device=device)
        )

    def __call__(self, poses: torch.Tensor) -> torch.Tensor:
        lead = poses.shape[:-3]
        rot = rotation_6d_to_matrix(poses.reshape(-1, 2, 15, 6))
        v = self.model.vertices(rot, self.ids)
        return v.reshape(*lead, *v.shape[1:])


class HandObjectDistance:
    """Signed hand-object distances, differentiable in the finger poses (RNet's proximity
    and penetration terms).

    ``(poses (B, 2, 15, 6), batch) -> (B, 2, K)`` signed distances (m) of K hand vertices
    (the 99 proximity vertices plus ``n_vertices`` at a fixed stride), placed at the batch's
    wrists and read from each object's distance grid
    (:meth:`~grip_bench.geometry.distance.DistanceField.grid_signed_distance`).
    ``proximity_ids`` index the proximity vertices among the K. The hand model and the
    indices live on ``device`` (the poses' and the batch's); each grid is copied there on
    first use (:meth:`~grip_bench.geometry.distance.DistanceField.grid_signed_distance`).
    """

    def __init__(
        self, library: ObjectLibrary, objects: Iterable[str], n_vertices: int = 256,
        device: torch.device = CPU,
    ):
        # vertices scale linearly with the hand scale
        self.model = hand_model(1.0, device)
        V = self.model.hands[0].num_vertices
        prox = np.array(self.model.proximity_ids)
        ids = np.union1d(prox, np.linspace(0, V - 1, n_vertices).round().astype(int))
        self.ids = torch.as_tensor(ids, device=device)
        self.proximity_ids = torch.as_tensor(np.searchsorted(ids, prox), device=device)
        self.fields = [library.field(str(o)) for o in objects]

    def __call__(self, poses: torch.Tensor, b: dict) -> torch.Tensor:
        v = self.model.vertices(rotation_6d_to_matrix(poses), self.ids)  # (B, 2, K, 3) hand frame
        v = v * b["hand_scale"][:, None, None, None]
        world = torch.einsum("bhij,bhvj->bhvi", b["wrist_rot"], v) + b["wrist_transl"][:, :, None]
        # GRAB's row-vector object pose: local = R (world - t) per frame
        local = torch.einsum("bij,bhvj->bhvi", b["obj_rot"], world - b["obj_transl"][:, None, None])
        return grid_signed_distance_many(self.fields, b["object"], local)


# --- RNet data ------------------------------------------------------------------------------
@torch.no_grad()
def cnet_predict(
    cnet: CNet, fs: FrameSet, idx: np.ndarray, variant: Variant, batch: int = 1024
) -> np.ndarray:
    """CNet's poses at frames ``idx`` ``(N, 2, 15, 6)`` (eval mode), computed on CNet's
    device; each chunk of ``batch`` frames comes back to the host once (data preparation)."""
    cnet.eval()
    device = next(cnet.parameters()).device
    out = []
    for s in range(0, len(idx), batch):
        b = {k: v.to(device) for k, v in cnet_batch(fs, idx[s:s + batch], variant).items()}
        out.append(
            cnet(
                b["body"],
                b["ambient"],
                b["proximity"],
                b["future"] if variant.future_frames else None,
            ).poses_t.cpu().numpy()
        )
    return np.concatenate(out) if out else np.zeros((0, 2, 15, 6), np.float32)


def perturb_poses(poses_6d: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """GT poses ``(N, 2, 15, 6)`` with ``N(0, sigma^2)`` added to every axis-angle component."""
    from .data import aa_to_6d

    aa = rotation_6d_to_axis_angle(poses_6d.astype(np.float64))
    return aa_to_6d(aa + rng.normal(0.0, sigma, size=aa.shape))


def rnet_data(
    cnet: CNet,
    fs: FrameSet,
    library: ObjectLibrary,
    variant: Variant,
    hp: dict,
    rng: np.random.Generator,
    objects: list[str],
) -> dict:
    """RNet samples on interaction frames: CNet outputs plus perturbed GT hands (GRIP Sup. 6).

    Returns arrays ``poses (N,2,15,6)``, ``proximity (N,2,99)`` recomputed on those
    hands, ``mask (N,2)`` (GT hand within ``interaction_distance``), ``target (N,2,15,6)``,
    its proximity ``gt_proximity (N,2,99)`` and the hands' :func:`placement` (object index
    into ``objects``).
    """
    near = fs.gt_min_dist < hp["interaction_distance"]  # (N, 2)
    idx = np.flatnonzero(near.any(axis=1) & (np.arange(len(fs)) + 1 < fs.end))
    cap = hp["max_train_frames"]
    if cap and len(idx) > cap:
        idx = np.sort(rng.choice(idx, cap, replace=False))
    poses = cnet_predict(cnet, fs, idx, variant)
    noisy = rng.random(len(idx)) < hp["rnet_noisy_share"]
    if noisy.any():
        poses[noisy] = perturb_poses(fs.gt_poses[idx[noisy]], hp["rnet_noise"], rng)
    return {"poses": poses, "proximity": recompute_proximity(fs, idx, poses, library),
            "mask": near[idx], "target": fs.gt_poses[idx], "gt_proximity": fs.gt_proximity[idx],
            **placement(fs, idx, objects)}


def placement(fs: FrameSet, idx: np.ndarray, objects: list[str]) -> dict:
    """Where the hands of frames ``idx`` sit: wrists, object pose, hand scale and the index
    of the object in ``objects`` (what :class:`HandObjectDistance` needs)."""
    at = {name: k for k, name in enumerate(objects)}
    per_seq = np.array([at[str(o)] for o in fs.objects], np.int64)
    return {"wrist_rot": fs.wrist_rot[idx], "wrist_transl": fs.wrist_transl[idx],
            "obj_rot": fs.obj_rot[idx], "obj_transl": fs.obj_transl[idx],
            "hand_scale": fs.hand_scale[idx], "object": per_seq[fs.seq_id[idx]]}


# --- the generic loop ---------------------------------------------------------------------
@dataclass
class Stage:
    """One network's training problem: its batches and its loss, on ``device``."""

    name: str
    model: torch.nn.Module
    n_train: int
    n_val: int
    batch: callable  # (split "train"|"val", idx) -> dict of (CPU) tensors
    loss: callable  # (model, batch) -> (total, {term: tensor})
    device: torch.device = CPU

    def fetch(self, split: str, idx: np.ndarray) -> dict:
        """:attr:`batch` with every tensor on :attr:`device`: the one move of a batch
        (``Tensor.to`` returns the tensor itself where it already is, so the CPU path
        does no copy)."""
        return {k: v.to(self.device) for k, v in self.batch(split, idx).items()}


def _seed(*parts: int) -> int:
    return int(np.random.SeedSequence(list(parts)).generate_state(1)[0])


def _evaluate(stage: Stage, bs: int, d: ddp.Dist = ddp.SINGLE) -> float:
    """Mean validation loss; under DDP rank r takes the batches r, r + N, ... and the
    (loss sum, count) pair is reduced, so every rank gets the same value to decide on."""
    stage.model.eval()
    losses, sizes = [], []
    with torch.no_grad():
        for k, s in enumerate(range(0, stage.n_val, bs)):
            if k % d.world != d.rank:
                continue
            idx = np.arange(s, min(s + bs, stage.n_val))
            loss, _ = stage.loss(stage.model, stage.fetch("val", idx))
            losses.append(loss.detach())
            sizes.append(len(idx))
    total, n = 0.0, 0
    for value, size in zip(_host_floats(losses), sizes, strict=True):  # the old float sum
        total, n = total + value * size, n + size
    if d.active:
        return ddp.global_mean(total, n, d, _collective_device(stage.device))
    return total / max(n, 1)


def _host_floats(values: list[torch.Tensor]) -> list[float]:
    """Scalar tensors ``[()]`` as Python floats in one device-to-host read (one GPU sync
    per epoch instead of one per batch; the same float32 -> float64 values)."""
    return torch.stack(values).tolist() if values else []


def _collective_device(device: torch.device) -> torch.device:
    """Where DDP's float64 reductions run: the GPU under nccl (it has no CPU tensors),
    the CPU under gloo."""
    return device if device.type == "cuda" else CPU


def _epoch(
    stage: Stage, opt: torch.optim.Optimizer, bs: int, seed: int, epoch: int, progress: bool,
    net: torch.nn.Module | None = None, d: ddp.Dist = ddp.SINGLE,
) -> float:
    """One pass over the train samples in a seeded order; returns the mean loss.

    ``net``: what the loss calls (the DDP wrapper of ``stage.model`` under DDP). Every rank
    draws the same global order and takes its share of each global batch of ``bs``.
    """
    stage.model.train()
    net = stage.model if net is None else net
    # dropout: one stream per rank under DDP, the single-process stream otherwise
    rank_part = (d.rank,) if d.active else ()
    torch.manual_seed(_seed(seed, STAGES.index(stage.name), epoch, 1, *rank_part))
    order = np.random.default_rng(_seed(seed, STAGES.index(stage.name), epoch)).permutation(
        stage.n_train
    )
    # drop a last batch of 1: BatchNorm cannot normalise a single sample (under DDP also
    # one with fewer samples than ranks: a rank with nothing has no mean loss)
    starts = [s for s in range(0, stage.n_train, bs)
              if min(bs, stage.n_train - s) > max(1, d.world - 1)]
    bar = _bar(starts, f"{stage.name} epoch {epoch + 1}", progress)
    # the batch losses stay where they are computed until the epoch ends: no host read
    # (a GPU sync) per batch; a progress bar reads the terms every PROGRESS_EVERY batches
    losses, factors = [], []
    for k, s in enumerate(bar):
        glob = order[s:s + bs]
        mine = ddp.rank_share(glob, d) if d.active else glob
        loss, terms = stage.loss(net, stage.fetch("train", mine))
        opt.zero_grad(set_to_none=True)
        w = ddp.share_weight(len(mine), len(glob), d)  # 1.0 unless a last batch splits unevenly
        (loss * w if w != 1.0 else loss).backward()
        opt.step()
        losses.append(loss.detach())
        factors.append(w / d.world if d.active else 1.0)
        if progress and (k % PROGRESS_EVERY == 0 or k == len(starts) - 1):
            bar.set_postfix({t: f"{float(v.detach()):.4f}" for t, v in terms.items()})
    total = 0.0
    for value, f in zip(_host_floats(losses), factors, strict=True):  # the old float sum
        total += value * f
    if d.active:  # the mean over global batches of the global-batch mean loss
        total = ddp.global_sum([total], d, _collective_device(stage.device))[0]
    return total / max(len(starts), 1)


def _bar(items: Iterable[Any], desc: str, enabled: bool) -> Any:
    if not enabled:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=desc, unit="batch", leave=False)


@dataclass
class StageState:
    """Resumable state of one network's training (stored in the partial checkpoint)."""

    epoch: int = 0  # epochs completed
    best_loss: float = float("inf")
    best_state: dict | None = None
    bad_epochs: int = 0
    optimizer: dict | None = None
    scheduler: dict | None = None
    train_curve: list | None = None
    val_curve: list | None = None
    done: bool = False


def fit(
    stage: Stage,
    hp: dict,
    st: StageState,
    seed: int,
    epochs: int,
    save: Callable[[StageState], None],
    progress: bool,
) -> StageState:
    """Train ``stage.model`` from state ``st``; returns the final state.

    ``save(st)`` runs after each epoch.
    """
    d = ddp.current()
    ddp.check_batch(hp["batch_size"], d, "grip.batch_size")
    net = ddp.wrap(stage.model, d, stage.device)  # stage.model itself for one process
    # foreach: the same float operations per parameter as the single-tensor loop (equal bits,
    # tests/unit/test_grip_train_speed.py), with less Python per step (torch's CUDA default)
    opt = torch.optim.Adam(stage.model.parameters(), lr=hp["lr"], weight_decay=hp["weight_decay"],
                           foreach=True)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
        opt, factor=hp["lr_factor"], patience=hp["lr_patience"]
    )
    if st.optimizer is not None:
        opt.load_state_dict(st.optimizer)
        sched.load_state_dict(st.scheduler)
    st.train_curve, st.val_curve = st.train_curve or [], st.val_curve or []
    while not st.done and st.epoch < epochs:
        train_loss = _epoch(stage, opt, hp["batch_size"], seed, st.epoch, progress, net, d)
        val_loss = _evaluate(stage, hp["batch_size"], d)
        sched.step(val_loss)
        st.train_curve.append(train_loss)
        st.val_curve.append(val_loss)
        if val_loss < st.best_loss:
            st.best_loss, st.bad_epochs = val_loss, 0
            st.best_state = copy.deepcopy(stage.model.state_dict())
        else:
            st.bad_epochs += 1
        st.epoch += 1
        st.done = st.bad_epochs >= hp["patience"] or st.epoch >= epochs
        st.optimizer, st.scheduler = opt.state_dict(), sched.state_dict()
        if progress:
            print(f"{stage.name} epoch {st.epoch}: train {train_loss:.5f} val {val_loss:.5f}"
                  f" lr {opt.param_groups[0]['lr']:.2e}", flush=True)
        save(st)
    stage.model.load_state_dict(st.best_state)
    ddp.broadcast_module(stage.model, d)  # identical already; rank 0's bits by construction
    return st


# --- stages --------------------------------------------------------------------------------
def _subset(n: int, cap: int, rng: np.random.Generator) -> np.ndarray:
    idx = np.arange(n)
    return np.sort(rng.choice(idx, cap, replace=False)) if cap and n > cap else idx


def _anet_stage(model: ANet, data: dict, hp: dict, device: torch.device) -> Stage:
    cfg, lc = model.cfg, LossConfig()
    caps = {"train": hp["anet_max_train_frames"], "val": hp["max_val_frames"]}
    idx = {
        s: _subset(len(data[s]), caps[s], np.random.default_rng(hp["seed"])) for s in caps
    }

    def batch(split: str, i: np.ndarray) -> dict:
        return anet_batch(data[split], idx[split][i], cfg)

    def loss(m: ANet, b: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return anet_loss(m(b["current"], b["noisy_future"]), b["target"], lc, cfg.consistency)

    return Stage("anet", model, len(idx["train"]), len(idx["val"]), batch, loss, device)


def _cnet_stage(
    model: CNet, data: dict, hp: dict, variant: Variant, device: torch.device
) -> Stage:
    lc, vert = LossConfig(), VertexFn(hp["loss_vertices"], device)
    rng = np.random.default_rng(hp["seed"] + 1)
    idx = {
        s: _subset_of(data[s].pair_index(), hp[f"max_{s}_frames"], rng) for s in ("train", "val")
    }

    def batch(split: str, i: np.ndarray) -> dict:
        return cnet_batch(data[split], idx[split][i], variant)

    def loss(m: CNet, b: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        out = m(
            b["body"], b["ambient"], b["proximity"], b["future"] if variant.future_frames else None
        )
        return cnet_loss(out, b, lc, variant.consistency, vert)

    return Stage("cnet", model, len(idx["train"]), len(idx["val"]), batch, loss, device)


def _subset_of(idx: np.ndarray, cap: int, rng: np.random.Generator) -> np.ndarray:
    return idx[_subset(len(idx), cap, rng)]


def _rnet_stage(
    model: RNet, rdata: dict, hp: dict, dist: HandObjectDistance | None = None,
    device: torch.device = CPU,
) -> Stage:
    lc, vert = LossConfig(), VertexFn(hp["loss_vertices"], device)
    w_pen = float(hp["w_penetration"])

    def batch(split: str, i: np.ndarray) -> dict:
        d = rdata[split]
        return {k: torch.as_tensor(d[k][i]) if k in ("mask", "object") else _t(d[k][i]) for k in d}

    def loss(m: RNet, b: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        refined = m(b["poses"], b["proximity"], mask=b["mask"])
        total, terms = rnet_loss(refined, b["target"], lc, vert)
        if dist is None:
            return total, terms
        sd = dist(refined, b)  # (B, 2, V)
        # GRIP Eq. 4's proximity L1 on the refined hands, then our penetration term
        prox = proximity_attention(sd[..., dist.proximity_ids])
        terms["proximity"] = proximity_l1(prox, b["gt_proximity"])
        total = total + lc.w_proximity * terms["proximity"]
        if w_pen:
            terms["penetration"] = penetration_depth(sd, b["mask"])
            total = total + w_pen * terms["penetration"]
        return total, terms

    return Stage(
        "rnet", model, len(rdata["train"]["poses"]), len(rdata["val"]["poses"]), batch, loss,
        device,
    )


# --- orchestration ------------------------------------------------------------------------------
@contextlib.contextmanager
def deterministic(threads: int | None = None) -> Iterator[None]:
    """Deterministic torch algorithms for the block (restored afterwards).

    On CUDA, deterministic cuBLAS needs ``CUBLAS_WORKSPACE_CONFIG`` (see
    :func:`_cuda_determinism`, called by :func:`train_grip` before any CUDA work)."""
    before = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(before)


def _cuda_determinism(device: torch.device) -> None:
    """Set ``CUBLAS_WORKSPACE_CONFIG`` for a CUDA training when the environment has none.

    cuBLAS reads it when the process first uses it, so it takes effect only when this
    training is the process's first cuBLAS work (``grip-bench train``, a runner's worker);
    export it beforehand to be sure. With it a GPU training is deterministic for a seed on
    one machine (same GPU model, driver and torch); it is never bit-equal to the CPU's.
    """
    if device.type == "cuda" and not os.environ.get("CUBLAS_WORKSPACE_CONFIG"):
        os.environ["CUBLAS_WORKSPACE_CONFIG"] = CUBLAS_WORKSPACE


def _fingerprint(hp: dict, variant: Variant, data_hash: str, seed: int) -> dict:
    return {"train_key": variant.train_key(), "data_hash": data_hash, "seed": int(seed),
            "grip_profile": {k: hp[k] for k in sorted(hp)}, "feature_version": FEATURE_VERSION}


def _load_partial(path: Path, fp: dict) -> tuple[dict, dict]:
    """(finished/current network states, stage states) of a partial checkpoint, or empty."""
    if not path.is_file():
        return {}, {}
    import torch as _torch

    payload = _torch.load(path, map_location="cpu", weights_only=True)
    meta = payload.get("meta", {})
    if meta.get("fingerprint") != fp:
        raise InputError("a partial checkpoint of a different training (data, profile, seed or "
                         "variant) is in the way; delete it to start over", path)
    states = {k: StageState(**v) for k, v in meta.get("stages", {}).items()}
    return payload["models"], states


def train_grip(
    data_dir: str | os.PathLike,
    out: str | os.PathLike,
    *,
    profile: dict,
    variant: Variant = Variant(),
    seed: int | None = None,
    device: str = "cpu",
    progress: bool = True,
    feature_cache: Path | None = None,
) -> Path:
    """Train ANet, CNet and RNet on ``data_dir`` (train split; val for early stopping).

    Writes the checkpoint ``out`` (all three networks' configs and weights, data hash,
    versions, training curves; no wall times, so the same inputs give the same
    bytes). Features go to ``feature_cache`` (None: ``<out dir>/.grip-cache``). Resumes
    from ``<out>.partial`` when present; an existing ``out`` of the same data, profile, seed
    and variant is kept as it is. Returns ``out``.

    ``device``: ``cpu``, ``cuda`` or ``cuda:N`` (a ``torch.device`` too): where the
    networks train (module docstring); an unknown or absent device is a one-line
    :class:`InputError` naming ``--device`` before any work. Files hold CPU tensors.
    """
    from ..data.grab_io import dataset_hash

    d = ddp.current()  # a DDP job under torchrun / --nproc, else one process
    dev = ddp.train_device(device, d)  # cuda:LOCAL_RANK for a rank of a CUDA job
    if dev.type not in ("cpu", "cuda"):
        raise InputError(f"GRIP trains on cpu or cuda, not {dev.type}", "--device")
    _cuda_determinism(dev)
    out, data_dir = Path(out), Path(data_dir)
    hp = dict(profile["grip"])
    seed = hp["seed"] if seed is None else int(seed)
    hp["seed"] = seed
    ddp.check_batch(hp["batch_size"], d, "grip.batch_size")
    progress = progress and d.main
    data_hash = dataset_hash(data_dir)
    fp = _fingerprint(hp, variant, data_hash, seed)
    if d.active:  # N processes train other weights than one: never mix their partials
        fp["nproc"] = d.world
    if dev.type != "cpu":  # nor a GPU's with the CPU's (absent on the CPU: its bytes stay)
        fp["device"] = dev.type
    if ddp.agree(_already_trained(out, fp), d):
        return out
    # features are shared by every variant trained on the same data (keyed by its hash)
    cache = Path(feature_cache) if feature_cache else out.parent / ".grip-cache"
    with ddp.main_first(d):  # rank 0 fills the feature cache, the others read it
        data = _features(data_dir, cache, variant, seed, data_hash, progress)
    configs = build_configs(hp, variant)
    partial = out.with_name(out.name + ".partial")
    models_done, states = _load_partial(partial, fp)
    shared = _shared_anet_path(cache, fp, configs["anet"])
    with deterministic():
        nets = _build_nets(configs, seed, models_done, dev)
        _train_stages(nets, states, data, hp, variant, data_dir, (partial, configs, fp, shared),
                      seed, progress, d, dev)
    meta = {**fp, "curves": {k: {"train": s.train_curve, "val": s.val_curve, "epochs": s.epoch}
                             for k, s in states.items()},
            "variant": asdict(variant), "profile": profile.get("name", "?"),
            "n_frames": {s: len(fs) for s, fs in data.items()}}
    if d.main:
        save_checkpoint(out, model_state={k: m.state_dict() for k, m in nets.items()},
                        configs=configs, meta=meta)
        partial.unlink(missing_ok=True)
    ddp.barrier(d)  # the file exists before any rank returns
    return out


def _features(
    data_dir: Path, cache: Path, variant: Variant, seed: int, data_hash: str, progress: bool
) -> dict[str, FrameSet]:
    """The train and val :class:`FrameSet` (built once per data hash into ``cache``)."""
    return {
        s: build_split(
            data_dir,
            s,
            cache_dir=cache,
            voxel=variant.ambient == "voxel",
            seed=seed,
            data_hash=data_hash,
            progress=progress,
        )
        for s in ("train", "val")
    }


def _train_stages(
    nets: dict, states: dict, data: dict, hp: dict, variant: Variant, data_dir: Path,
    files: tuple, seed: int, progress: bool, d: ddp.Dist,
    device: torch.device = CPU,
) -> None:
    """ANet, CNet, RNet in turn (a finished stage is skipped); ``states`` is updated.

    ``files``: (partial checkpoint, configs, fingerprint, shared ANet path). Only rank 0
    writes; a file that decides what to do is read by rank 0 and its answer broadcast.
    """
    from ..data.library import ObjectLibrary

    partial, configs, fp, shared = files
    # without geometry RNet (it reads proximity) is never run: it keeps its seeded initial
    # weights in the checkpoint, untrained (Variant docstring)
    for name in STAGES if variant.geometry else STAGES[:2]:
        st = states.get(name, StageState())
        if name == "anet" and not st.done:
            # rank 0 reads the shared ANet and hands it to the others: one decision
            got = ddp.agree(_load_shared_anet(shared, nets["anet"]) if d.main else None, d)
            if got is not None and not d.main:
                nets["anet"].load_state_dict(got.best_state)
            st = got or st
        if st.done:
            states[name] = st
            continue
        stage = _make_stage(name, nets, data, hp, variant, ObjectLibrary(data_dir), device)
        epochs = hp[f"epochs_{name}"]

        def save(s: StageState, name: str = name) -> None:
            states[name] = s
            if d.main:
                _save_partial(partial, nets, configs, states, fp, device)

        states[name] = fit(stage, hp, st, seed, epochs, save, progress)
        if name == "anet" and d.main:
            _save_shared_anet(shared, nets["anet"], states[name])


# --- ANet shared by the variants ------------------------------------------------------------
# ANet sees only the arms: its config, data, seeds and batches do not depend on the variant,
# so every variant trained on the same data with the same profile gets the same weights.
# The first one to train it leaves them in the feature cache; the others load them.
def _shared_anet_path(cache: Path, fp: dict, cfg: ANetConfig) -> Path:
    ident = {k: v for k, v in fp.items() if k != "train_key"}
    ident["anet"] = asdict(cfg)
    key = hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:16]
    return Path(cache) / f"anet-{key}.pt"


def _save_shared_anet(path: Path, anet: ANet, st: StageState) -> None:
    curves = {"epoch": st.epoch, "best_loss": float(st.best_loss),
              "train_curve": st.train_curve, "val_curve": st.val_curve}
    state = anet.state_dict()
    with atomic_file(path) as f:  # CPU tensors: a GPU-trained file loads anywhere
        torch.save({"state": _host_copy(state, _device_of(anet)), "curves": curves}, f)


def _load_shared_anet(path: Path, anet: ANet) -> StageState | None:
    """The finished ANet stage from ``path`` loaded into ``anet``, or None (absent, unreadable)."""
    if not path.is_file():
        return None
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        anet.load_state_dict(saved["state"])
    except (OSError, RuntimeError, KeyError, ValueError, EOFError):
        return None  # a broken cache file is retrained over, never trusted
    return StageState(**saved["curves"], best_state=saved["state"], done=True)


def _already_trained(out: Path, fp: dict) -> bool:
    """Whether ``out`` is a finished checkpoint of this very training (then it is reused)."""
    if not out.is_file():
        return False
    meta = load_checkpoint(out, CONFIG_CLASSES).meta
    # a CPU fingerprint has no "device": a GPU-trained file must not pass for a CPU one
    return all(meta.get(k) == v for k, v in fp.items()) and meta.get("device") == fp.get("device")


def _build_nets(
    configs: dict, seed: int, states: dict, device: torch.device = CPU
) -> dict:
    """Seeded fresh networks, with the weights of ``states`` where a partial run has them,
    on ``device`` (built and seeded on the CPU, so every device starts from the same
    weights, then moved)."""
    nets = {}
    for name in STAGES:
        torch.manual_seed(_seed(seed, STAGES.index(name), 999))
        # the same dropout masks as nn.Dropout, drawn cheaper (grip.dropout); no weights
        nets[name] = use_uniform_mask_dropout(configs[name].build())
        if name == "anet":  # residual ANet starts as the identity (module docstring)
            torch.nn.init.zeros_(nets[name].decoder.head.weight)
            torch.nn.init.zeros_(nets[name].decoder.head.bias)
        if name in states:
            nets[name].load_state_dict(states[name])
        nets[name] = nets[name].to(device)
    return nets


def _make_stage(
    name: str, nets: dict, data: dict, hp: dict, variant: Variant, library: ObjectLibrary,
    device: torch.device = CPU,
) -> Stage:
    if name == "anet":
        return _anet_stage(nets["anet"], data, hp, device)
    if name == "cnet":
        return _cnet_stage(nets["cnet"], data, hp, variant, device)
    rng = np.random.default_rng(_seed(hp["seed"], 7))
    objects = sorted({str(o) for s in ("train", "val") for o in data[s].objects})
    rdata = {
        s: rnet_data(nets["cnet"], data[s], library, variant, hp, rng, objects)
        for s in ("train", "val")
    }
    return _rnet_stage(nets["rnet"], rdata, hp,
                       HandObjectDistance(library, objects, device=device), device)


def _save_partial(
    path: Path, nets: dict, configs: dict, states: dict, fp: dict,
    device: torch.device = CPU,
) -> None:
    """The partial checkpoint: networks and stage states (best weights, optimizer) as CPU
    tensors, so a run resumes on any device."""
    stages = {k: _host_copy({**asdict(s)}, device) for k, s in states.items()}
    for s in stages.values():
        s["best_loss"] = float(s["best_loss"])
    save_checkpoint(path, model_state={k: m.state_dict() for k, m in nets.items()},
                    configs=configs, meta={"fingerprint": fp, "stages": stages})


def _device_of(module: torch.nn.Module) -> torch.device:
    return next(module.parameters()).device


def _host_copy(obj: Any, device: torch.device) -> Any:
    """``obj`` (nested dicts, lists and tuples of tensors) with every tensor on the CPU, for
    files. ``obj`` itself when ``device`` is the CPU, so the CPU path pickles exactly the
    objects it did before devices existed (the same bytes)."""
    return obj if device.type == "cpu" else _on_host(obj)


def _on_host(obj: Any) -> Any:
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu()
    if isinstance(obj, dict):
        out = type(obj)((k, _on_host(v)) for k, v in obj.items())
        if hasattr(obj, "_metadata"):  # a state_dict's module versions
            out._metadata = obj._metadata
        return out
    if isinstance(obj, list | tuple):
        return type(obj)(_on_host(v) for v in obj)
    return obj


def load_grip(path: str | os.PathLike, device: str = "cpu") -> tuple[dict, dict]:
    """Networks ``{anet, cnet, rnet}`` (eval mode) and the meta of a GRIP checkpoint."""
    ck = load_checkpoint(path, CONFIG_CLASSES)
    return {k: m.to(device) for k, m in ck.models().items()}, ck.meta
