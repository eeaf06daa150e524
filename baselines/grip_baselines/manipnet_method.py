"""``manipnet``: ManipNet-style single right-hand autoregressive finger model as a method.

Training (train split, right hand, every frame of up to ``max_sequences`` sequences):
teacher forcing (the previous finger pose is the ground truth of frame t-1), then
``ss_epochs`` epochs of scheduled sampling where a share ``ss_share`` of frames gets the
model's own prediction of frame t-1 as the previous pose (features recomputed, since the
distance features depend on it). Loss: 6D pose L2 + finger-vertex L1 (cm), plus, on
ground-truth contact frames, GRIP's proximity L1 and the summed penetration depth of hand
vertices (``ContactTerms``, weights ``w_proximity`` and ``w_penetration``).

Prediction: autoregressive over the whole sequence with the input (ground-truth) right
wrist; the first frame starts from the relaxed mean hand (the input's own fingers are
never read). The left hand is returned unchanged: ManipNet is a single-hand model.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from grip_bench.core.constants import MANIPNET_FUTURE, MANIPNET_PAST, MANIPNET_VOXEL_RES
from grip_bench.geometry.rotations import axis_angle_to_rotation_6d, rotation_6d_to_axis_angle
from grip_bench.methods.api import MethodSpec, PredictContext, register_method
from grip_bench.nn import ddp
from grip_bench.nn.terms import penetration_depth, proximity_attention, proximity_l1

from . import common as U
from .manipnet import (
    ManipNet,
    ManipNetConfig,
    manipnet_features,
    motion_features,
    pose_features,
)

if TYPE_CHECKING:
    from grip_bench.bodies.hand import ProceduralHand
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.data.sequence import Sequence


@dataclass
class ManipNetTrainConfig:
    """Profile section ``[manipnet]``."""

    width: int = 256
    hidden: int = 256
    n_blocks: int = 2
    dropout: float = 0.1
    n_past: int = MANIPNET_PAST
    n_future: int = MANIPNET_FUTURE
    voxel_res: int = MANIPNET_VOXEL_RES
    epochs: int = 10  # teacher-forced epochs
    ss_epochs: int = 2  # scheduled-sampling epochs after them
    ss_share: float = 0.3  # share of frames fed the model's own previous pose
    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 0.0
    max_sequences: int = 0  # train files read (0 = all); every frame of each is used
    loss_vertices: int = 256
    w_vertex: float = 100.0  # vertex L1 in m -> read in cm
    # Axis-angle noise (rad) on the teacher-forced previous pose: with slowly changing
    # fingers "copy the previous pose" is nearly optimal, so without it the model never
    # learns to move the fingers towards what the object asks for.
    prev_noise: float = 0.1
    # GRIP's proximity L1 and the penetration depth (m, summed over the vertices), on the
    # ground truth's contact frames: the hand-object terms every learned hand generator of
    # the suite is trained with (0 turns them off).
    w_proximity: float = 10.0
    w_penetration: float = 40.0
    contact_vertices: int = 256  # hand vertices of those terms (a fixed stride subset)


def proximity_fn(
    hand: ProceduralHand,
) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """Proximity vertices ``(M, 99, 3)`` for wrists ``rot (M,3,3)``, ``pos (M,3)`` and finger
    poses ``(M, 15, 3)``: each distinct pose is skinned once, then placed rigidly (the
    feature function repeats one pose on up to 11 wrists)."""
    ids = np.asarray(hand.proximity_ids)

    def fn(rot: np.ndarray, pos: np.ndarray, pose: np.ndarray) -> np.ndarray:
        flat = np.asarray(pose, np.float64).reshape(len(pose), -1)
        uniq, inv = np.unique(flat, axis=0, return_inverse=True)
        local = U.pose_hand(hand, np.zeros((len(uniq), 3)), uniq, np.zeros((len(uniq), 3)))[0]
        local = local[:, ids][inv.reshape(-1)]  # (M, 99, 3)
        return np.einsum("mij,mkj->mki", rot, local) + np.asarray(pos)[:, None]

    return fn


class SeqData:
    """What the feature function needs of one sequence's right hand (numpy, float64)."""

    def __init__(self, seq: Sequence, library: ObjectLibrary) -> None:
        self.wrist_rot, self.wrist_pos = U.wrist_pose(seq.hand_params("right"))
        self.obj_rot, self.obj_pos = U.object_pose(seq)
        self.obj_name, self.scale = seq.obj_name, float(seq.hand_scale or 1.0)
        self.contact = seq.contact_frames("right")  # (T,) bool
        self.pose = np.asarray(seq.rhand["hand_pose"], float).reshape(-1, 15, 3)
        field = library.field(seq.obj_name)
        self.sdf = lambda p: field.signed_distance(p, far="bound")  # noqa: E731
        self.prox = proximity_fn(U.seq_hand(seq, "right"))

    def features(
        self,
        prev: np.ndarray,
        frames: np.ndarray | list[int],
        cfg: ManipNetConfig,
        device: U.Device = "cpu",
    ) -> tuple[torch.Tensor, ...]:
        """Feature tensors on ``device`` for ``frames``; ``prev (T, 15, 3)`` = previous pose
        of each frame."""
        f = manipnet_features(
            self.wrist_rot,
            self.wrist_pos,
            self.obj_rot,
            self.obj_pos,
            prev,
            self.sdf,
            self.prox,
            frames=np.asarray(frames),
            cfg=cfg,
        )
        return f.torch(device=device)

    def motion(self, cfg: ManipNetConfig, device: U.Device = "cpu") -> tuple[torch.Tensor, ...]:
        """Trajectory ``(T, past+future, 9)`` and occupancy ``(T, r, r, r)`` of every frame,
        float32 on ``device``: the inputs a rollout does not change, computed once."""
        t = np.arange(len(self.pose))
        arrays = motion_features(self.wrist_rot, self.wrist_pos, self.obj_rot, self.obj_pos,
                                 self.sdf, t, cfg)
        return tuple(torch.as_tensor(a, dtype=torch.float32, device=device) for a in arrays)

    def pose_inputs(
        self, prev: np.ndarray, frames: np.ndarray | list[int], cfg: ManipNetConfig,
        device: U.Device = "cpu",
    ) -> tuple[torch.Tensor, ...]:
        """Distances ``(F, 1+future, P)`` and previous pose ``(F, J, 6)`` of ``frames``,
        float32 on ``device``; ``prev (T, 15, 3)`` = previous pose of each frame."""
        arrays = pose_features(self.wrist_rot, self.wrist_pos, self.obj_rot, self.obj_pos,
                               prev, self.sdf, self.prox, np.asarray(frames), cfg)
        return tuple(torch.as_tensor(a, dtype=torch.float32, device=device) for a in arrays)


def _compact(feats: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, ...]:
    """Training features with the occupancy grid ``(F, r, r, r)`` stored as bool: it holds
    0 / 1 only, which :meth:`ManipNet.forward` turns back into the same floats, and at
    float32 it was a quarter of the features' memory (every train frame is kept)."""
    traj, voxels, distances, prev = feats
    return traj, voxels.bool(), distances, prev


def _cat(parts: list[tuple[torch.Tensor, ...]]) -> list[torch.Tensor]:
    return [torch.cat(x) for x in zip(*parts, strict=True)]


def _teacher(d: SeqData, noise: float, rng: np.random.Generator) -> np.ndarray:
    """Previous poses (T, 15, 3): the ground truth of t-1 (t = 0 repeats itself), noised."""
    prev = np.concatenate([d.pose[:1], d.pose[:-1]])
    return prev + noise * rng.normal(size=prev.shape)


def _build(
    seqs: list[Sequence],
    library: ObjectLibrary,
    cfg: ManipNetConfig,
    noise: float,
    rng: np.random.Generator,
    device: U.Device = "cpu",
) -> tuple[list[SeqData], list[torch.Tensor], torch.Tensor, np.ndarray]:
    """Teacher-forced features of every frame on ``device``: (data list, feature tensors,
    targets 6D, seq index)."""
    data = [SeqData(s, library) for s in seqs]
    feats, targets, owner = [], [], []
    for k, d in enumerate(data):
        prev = _teacher(d, noise, rng)
        feats.append(_compact(d.features(prev, np.arange(len(d.pose)), cfg, device)))
        targets.append(torch.as_tensor(axis_angle_to_rotation_6d(d.pose), dtype=torch.float32,
                                       device=device))
        owner.append(np.full(len(d.pose), k))
    return data, _cat(feats), torch.cat(targets), np.concatenate(owner)


class ContactTerms:
    """GRIP's proximity L1 and the penetration depth of the predicted right hand, per frame
    row, read from each object's distance grid (differentiable in the pose)."""

    def __init__(
        self, data: list[SeqData], library: ObjectLibrary, n_vertices: int,
        device: U.Device = "cpu",
    ) -> None:
        names = sorted({d.obj_name for d in data})
        self.fields = [library.field(n) for n in names]
        self.device = torch.device(device)
        hand = U.hand_model("right", device=device)
        self.hand = U.SubsetHand(hand, U.vertex_subset(hand, n_vertices))

        def cat(f: Callable[[SeqData], np.ndarray]) -> torch.Tensor:
            rows = np.concatenate([f(d) for d in data])
            return torch.as_tensor(rows, dtype=torch.float32, device=device)

        n = lambda d: len(d.pose)  # noqa: E731
        self.wrist_rot, self.wrist_pos = cat(lambda d: d.wrist_rot), cat(lambda d: d.wrist_pos)
        self.obj_rot, self.obj_pos = cat(lambda d: d.obj_rot), cat(lambda d: d.obj_pos)
        self.scale = cat(lambda d: np.full(n(d), d.scale))
        # object index per frame row: on the CPU, beside the distance grids it selects
        self.object = torch.as_tensor(
            np.concatenate([np.full(n(d), names.index(d.obj_name)) for d in data])
        )
        self.contact = np.concatenate([d.contact for d in data])
        self.gt_attention: torch.Tensor | None = None  # (contact rows, K), precompute_gt
        self.gt_row = np.full(len(self.contact), -1)  # frame row -> row of gt_attention

    def precompute_gt(self, target6: torch.Tensor, chunk: int) -> None:
        """Proximity attention ``(C, K)`` of the ground truth ``target6 (N, 15, 6)`` on
        every contact row, computed once in chunks of ``chunk`` rows instead of once per
        batch and epoch. Every step is per row (skinning, transforms, grid reads), so a
        row's values do not depend on the rows computed with it."""
        rows = np.flatnonzero(self.contact)
        self.gt_row[rows] = np.arange(len(rows))
        with torch.no_grad():
            parts = [
                proximity_attention(self.signed_distance(target6[r], r))
                for r in (rows[i : i + chunk] for i in range(0, len(rows), chunk))
            ]
        self.gt_attention = torch.cat(parts) if parts else None

    def signed_distance(self, pose6: torch.Tensor, rows: np.ndarray) -> torch.Tensor:
        """Signed distances ``(B, K)`` (m) of the hand with finger poses ``pose6 (B, 15, 6)``
        at the wrists of frame rows ``rows``."""
        from grip_bench.geometry.distance import grid_signed_distance_many

        r = torch.as_tensor(rows, device=self.device)
        v = self.hand(None, rotation_6d_to_axis_angle(pose6), None)[0] * self.scale[r, None, None]
        world = torch.einsum("bij,bkj->bki", self.wrist_rot[r], v) + self.wrist_pos[r, None]
        # world -> object frame, R^T (x - t) with column rotations (torch, differentiable;
        # core.frames.world_to_object is its numpy counterpart)
        local = torch.einsum("bji,bkj->bki", self.obj_rot[r], world - self.obj_pos[r, None])
        # The distance grids live on the CPU (grip_bench.geometry): read them there; the
        # transfer is differentiable and a no-op on the CPU.
        which = torch.as_tensor(rows)
        d = grid_signed_distance_many(self.fields, self.object[which], local.cpu())
        return d.to(local.device)

    def __call__(
        self, pred6: torch.Tensor, target6: torch.Tensor, rows: np.ndarray
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(proximity L1, penetration depth) over the ground truth's contact frames in ``rows``."""
        keep = np.flatnonzero(self.contact[rows])
        if not len(keep):
            zero = pred6.sum() * 0.0
            return zero, zero
        sd = self.signed_distance(pred6[keep], rows[keep])
        if self.gt_attention is not None:
            at = torch.as_tensor(self.gt_row[rows[keep]], device=self.gt_attention.device)
            gt_att = self.gt_attention[at]
        else:
            with torch.no_grad():
                gt_att = proximity_attention(self.signed_distance(target6[keep], rows[keep]))
        return proximity_l1(proximity_attention(sd), gt_att), penetration_depth(sd)


def _predict_all(net: ManipNet, feats: list[torch.Tensor], bs: int = 1024) -> torch.Tensor:
    net.eval()
    with torch.no_grad():
        return torch.cat(
            [net(*(x[i : i + bs] for x in feats)) for i in range(0, len(feats[0]), bs)]
        )


def _scheduled(
    net: ManipNet,
    data: list[SeqData],
    feats: list[torch.Tensor],
    cfg: ManipNetConfig,
    share: float,
    rng: np.random.Generator,
) -> list[torch.Tensor]:
    """Features where a share of frames sees the model's own prediction of frame t-1
    (computed in numpy from the predictions, then put back on the features' device;
    ``feats`` in :meth:`ManipNet.forward` order: traj, voxels, distances, prev_pose)."""
    device = feats[0].device
    pred = rotation_6d_to_axis_angle(_predict_all(net, feats).double()).cpu().numpy()  # (N,15,3)
    feats = [feats[0], feats[1], feats[2].clone(), feats[3].clone()]  # the first two stay
    start = 0
    for d in data:
        n = len(d.pose)
        pick = np.flatnonzero(rng.random(n) < share)
        pick = pick[pick > 0]
        if len(pick):
            prev = np.concatenate([d.pose[:1], d.pose[:-1]])
            prev[pick] = pred[start + pick - 1]
            # Only the distances and the previous pose depend on it: the trajectory and
            # occupancy rows of the teacher features are already these frames' own.
            dist, prev6 = d.pose_inputs(prev, pick, cfg, device)
            feats[2][start + pick] = dist
            feats[3][start + pick] = prev6
        start += n
    return feats


def _loss(
    net: ManipNet,
    feats: list[torch.Tensor],
    target: torch.Tensor,
    idx: np.ndarray,
    hand: U.SubsetHand,
    cfg: ManipNetTrainConfig,
    contact: ContactTerms | None = None,
    gt_vertices: torch.Tensor | None = None,
) -> torch.Tensor:
    """Pose L2 + vertex L1 over ``hand``'s vertex subset (+ the contact terms);
    ``gt_vertices (N, K, 3)``: the target's vertices of every row (:func:`_gt_vertices`),
    else posed per batch."""
    pred = net(*(x[idx] for x in feats))  # (B, 15, 6)
    loss = (pred - target[idx]).pow(2).mean()
    aa = lambda p: rotation_6d_to_axis_angle(p)  # noqa: E731
    v_pred = hand(None, aa(pred), None)[0]
    if gt_vertices is not None:
        v_gt = gt_vertices[torch.as_tensor(idx, device=gt_vertices.device)]
    else:
        with torch.no_grad():
            v_gt = hand(None, aa(target[idx]), None)[0]
    loss = loss + cfg.w_vertex * (v_pred - v_gt).abs().mean()
    if contact is not None:
        prox, pen = contact(pred, target[idx], idx)
        loss = loss + cfg.w_proximity * prox + cfg.w_penetration * pen
    return loss


def _gt_vertices(hand: U.SubsetHand, target6: torch.Tensor, chunk: int) -> torch.Tensor:
    """``hand``'s vertices ``(N, K, 3)`` at the target poses ``target6 (N, 15, 6)``, posed in
    chunks of ``chunk`` rows once for the whole training (they were posed again in every
    batch of every epoch; skinning is per row, so the values are the same)."""
    with torch.no_grad():
        return torch.cat([
            hand(None, rotation_6d_to_axis_angle(target6[i : i + chunk]), None)[0]
            for i in range(0, len(target6), chunk)
        ])


def train_manipnet(
    name: str,
    data_dir: Path,
    cfg: ManipNetTrainConfig,
    seed: int,
    progress: bool,
    device: U.Device = "cpu",
) -> tuple[ManipNet, int]:
    """The finger model, built and trained on ``device``; returns (net, n_frames)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    library = U.train_library(data_dir)
    seqs = U.train_sequences(data_dir, cfg.max_sequences, seed)
    ncfg = ManipNetConfig(
        n_past=cfg.n_past,
        n_future=cfg.n_future,
        voxel_res=cfg.voxel_res,
        width=cfg.width,
        hidden=cfg.hidden,
        n_blocks=cfg.n_blocks,
        dropout=cfg.dropout,
    )
    net = ncfg.build().to(device)
    data, feats, target, owner = _build(seqs, library, ncfg, cfg.prev_noise, rng, device)
    U.log(progress, name, f"{len(owner)} frames of {len(seqs)} sequences")
    hand = U.hand_model("right", device=device)
    vhand = U.SubsetHand(hand, U.vertex_subset(hand, cfg.loss_vertices))  # skin only those
    contact = (ContactTerms(data, library, cfg.contact_vertices, device)
               if cfg.w_proximity or cfg.w_penetration else None)
    # What the loss reads of the (fixed) targets, computed once: ~a sixth of a batch's time
    gt_vertices = _gt_vertices(vhand, target, cfg.batch_size)
    if contact is not None:
        contact.precompute_gt(target, cfg.batch_size)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    d = ddp.current()  # DDP under torchrun / --nproc: each rank its share of a batch
    model = ddp.wrap(net, d, torch.device(device))  # BatchNorm over the global batch
    if d.active:
        torch.manual_seed(U.rank_seed(seed, d))  # dropout: one stream per rank
    teacher = feats
    for epoch in range(cfg.epochs + cfg.ss_epochs):
        if epoch >= cfg.epochs:  # the same on every rank: same weights, same rng
            feats = _scheduled(net, data, teacher, ncfg, cfg.ss_share, rng)
        net.train()
        total = 0.0
        for idx, w in U.rank_batches(U.batches(len(owner), cfg.batch_size, rng), d):
            loss = _loss(model, feats, target, idx, vhand, cfg, contact, gt_vertices)
            opt.zero_grad()
            U.backward(loss, w)
            opt.step()
            total += loss.item() * len(idx)
        total = ddp.global_sum([total], d)[0]
        U.log(
            progress,
            name,
            f"epoch {epoch + 1}/{cfg.epochs + cfg.ss_epochs} loss {total / len(owner):.4f}",
        )
    return net.eval(), len(owner)


class ManipNetMethod(U.TrainedMethod):
    """Right-hand fingers rolled out frame by frame at the input wrists."""

    section, config_cls, networks = "manipnet", ManipNetTrainConfig, {"manipnet": ManipNetConfig}

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.net: ManipNet | None = None

    def fit(
        self, data_dir: Path, cfg: ManipNetTrainConfig, seed: int, progress: bool,
        device: torch.device,
    ) -> tuple[dict[str, torch.nn.Module], dict]:
        net, n = train_manipnet(self.name, data_dir, cfg, seed, progress, device)
        return {"manipnet": net}, {"n_samples": n}

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        self.net = self.load_checkpoint(checkpoint, device)[0]["manipnet"]

    def predict(self, seq: Sequence, ctx: PredictContext) -> Sequence:
        """Autoregressive right-hand fingers; wrists and the left hand as in the input.

        The network runs on the device :meth:`load` put it on. Each frame's distance
        features are computed in numpy from the pose just predicted (the object's distance
        field is a CPU structure), so that pose (45 numbers) comes back once per frame;
        the outputs stay on the device and come back together at the end.
        """
        self._loaded(self.net)
        dev = self.device
        d = SeqData(seq, ctx.library)
        T = seq.n_frames
        prev = np.zeros((T, 15, 3))
        outs = []
        state = U.seq_hand(seq, "right").named_pose("relaxed").double().numpy()  # (15, 3)
        self.net.eval()
        cfg = self.net.cfg
        with U.single_thread(), torch.no_grad():
            # The trajectory and occupancy do not depend on the rollout: all frames at once
            # (per frame, the same numbers as manipnet_features gives for that frame).
            traj, voxels = d.motion(cfg, dev) if T else (None, None)
            for t in range(T):
                prev[t] = state
                dist, prev6 = d.pose_inputs(prev, [t], cfg, dev)
                out6 = self.net(traj[t : t + 1], voxels[t : t + 1], dist, prev6)
                pose = rotation_6d_to_axis_angle(out6.double())[0]
                outs.append(pose)
                state = pose.cpu().numpy()  # the next frame's features need it in numpy
        out = torch.stack(outs).cpu().numpy() if outs else np.zeros((0, 15, 3))
        return seq.with_hands(right={"hand_pose": out.reshape(T, 45)})


register_method(
    MethodSpec(
        name="manipnet",
        description="ManipNet-style autoregressive right-hand fingers at the input wrists "
        "(left unchanged)",
        factory=ManipNetMethod,
        needs=("object", "wrists"),
        hands=("right",),
        predict_cost=3.0,  # autoregressive: one network call per frame
    )
)
