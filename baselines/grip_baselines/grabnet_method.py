"""``grabnet`` and ``grabnet-smplx``: GrabNet-style static grasp synthesis as benchmark methods.

Both train CoarseNet (cVAE, :mod:`grip_baselines.grabnet`) on ground-truth grasp frames
of the train split, then RefineNet on perturbed ground-truth grasps and CoarseNet's own
reconstructions (GRAB S.9.2), with GRAB's contact and penetration loss terms on the
object's distance field next to the vertex and pose terms. They differ in the *model
frame* a grasp lives in:

* ``grabnet`` (free wrist, GrabNet proper): the right hand's grasp centred at the BPS
  centre (the object's surface centroid), in axes *aligned with the world* (optionally
  under a random rotation per training sample, ``augment``). The network generates wrist
  orientation, wrist position and fingers; the generated wrist is placed in the world by
  the object's translation only.
* ``grabnet-smplx`` (tied to the body): the model frame is the input wrist frame (left
  hands mirrored into the right hand's frame), the BPS basis is centred on the palm, and
  only the fingers are used: the wrist comes from the body motion and may sit where no
  good grasp exists (hence more penetration, as GRIP's Table 4 reports).

A sample maps model-frame points ``y`` to object-frame points ``x = A y + b``
(``A (3, 3)``, not a rotation for mirrored left hands, ``b (3,)``); the BPS query and the
RefineNet distances both go through this map, so one code path serves both variants.

Prediction is per grasp frame of the input hand (the input hand within 4.5 mm of the
object); other frames, and the left hand of ``grabnet``, keep the input unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import igl
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from grip_bench.core.constants import (
    CONTACT_THRESHOLD,
    GRABNET_NOISE_VAR,
    GRABNET_SMPLX_BPS_CENTRE,
    PROXIMITY_N_VERTS,
)
from grip_bench.core.errors import InputError
from grip_bench.geometry.rotations import (
    axis_angle_to_rotation_6d,
    rotation_6d_to_axis_angle,
    rotation_6d_to_matrix,
)
from grip_bench.methods.api import MethodSpec, PredictContext, register_method
from grip_bench.nn import ddp

from . import common as U
from .bps import basis_points, object_centre
from .grabnet import (
    CoarseNet,
    CoarseNetConfig,
    GrabNetLossConfig,
    GraspParams,
    RefineNet,
    RefineNetConfig,
    losses,
    make_hand_fn,
)

if TYPE_CHECKING:
    from grip_bench.bodies.hand import ProceduralHand
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.data.sequence import Sequence
    from grip_bench.geometry.distance import DistanceField

IDENTITY = np.eye(3)


@dataclass
class GrabNetTrainConfig:
    """Profile section ``[grabnet]`` (shared by ``grabnet-smplx``)."""

    bps_points: int = 512  # GRAB uses 4096; 512 keeps the exact BPS of every sample cheap
    width: int = 256
    hidden: int = 256
    latent: int = 16
    refine_width: int = 256
    epochs_coarse: int = 12
    epochs_refine: int = 4
    batch_size: int = 128
    lr: float = 1e-3  # GRAB S.9.3: 5e-4; twice that for a dozen CPU epochs
    weight_decay: float = 1e-5  # GRAB's "weight regulariser"
    w_kl: float = 5e-3
    max_frames: int = 4000  # grasp frames sampled from the train split (0 = all)
    # Frames looked at per hand: every frame_stride-th (neighbouring frames are near
    # duplicates; striding divides the posing and distance cost of finding grasp frames).
    frame_stride: int = 4
    max_sequences: int = 0  # train files read (0 = all)
    loss_vertices: int = 256  # hand vertices in the vertex L1 (a fixed stride subset)
    # grabnet only: a uniformly random object rotation per sample. Off, the samples are in
    # the frame prediction uses (object centred, aligned with the world), where grasps keep
    # their relation to gravity and the table; on, that relation must be learned from the
    # BPS code alone, which a CPU-sized CoarseNet does not manage (it collapses to the
    # mean grasp, a hand inside the object).
    augment: bool = False
    # RefineNet training noise (std). GRAB S.9.2 gives variances 0.2 rad^2 (fingers) and
    # 0.004 rad^2 (root); its translation variance 0.05 would put the hand 22 cm away,
    # beyond the 5 cm distance clip, so a centimetre-scale translation noise is used.
    noise_finger: float = math.sqrt(GRABNET_NOISE_VAR[0])
    noise_orient: float = math.sqrt(GRABNET_NOISE_VAR[1])
    noise_transl: float = 0.01
    # GRAB's contact and penetration loss terms (metres): on CoarseNet's reconstructions
    # and on RefineNet's final grasp. Penetration is a mean over all loss vertices, so a
    # few fingertips 3 mm deep weigh as much as a centimetre of vertex error.
    w_contact: float = 300.0
    w_penetration: float = 10000.0
    # Share of each RefineNet batch that starts from CoarseNet's reconstruction of the
    # grasp instead of the noisy ground truth: what RefineNet refines at inference.
    refine_coarse_share: float = 0.5


@dataclass
class Samples:
    """Training grasps (N of them) in their model frames."""

    obj: np.ndarray  # (N,) index into ``names``
    names: list
    A: np.ndarray  # (N, 3, 3) model -> object frame linear part
    b: np.ndarray  # (N, 3) model -> object frame offset (m)
    orient: np.ndarray  # (N, 3, 3) wrist rotation in the model frame
    transl: np.ndarray  # (N, 3) wrist position in the model frame (m)
    pose: np.ndarray  # (N, 45) right-hand finger axis-angles


# ----------------------------------------------------------------------------- samples


def _frame_samples(
    seq: Sequence,
    library: ObjectLibrary,
    side: str,
    frames: np.ndarray,
    tied: bool,
    rng: np.random.Generator | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per grasp frame of one hand: (A, b, orient, transl, pose) arrays."""
    R_o = U.object_pose(seq)[0][frames]
    p = seq.hand_params(side)
    R_w, p_w = (x[frames] for x in U.wrist_pose(p))
    pose = np.asarray(p["hand_pose"], float)[frames]
    n = len(frames)
    p_loc = U.to_object(seq, p_w[:, None], frames)[:, 0]  # wrist position, object frame
    if tied:
        S = U.MIRROR if side == "left" else IDENTITY
        A = np.einsum("nji,njk,kl->nil", R_o, R_w, S)  # R_o^T R_w S
        pose = U.mirror_pose(pose) if side == "left" else pose
        return A, p_loc, np.broadcast_to(IDENTITY, (n, 3, 3)), np.zeros((n, 3)), pose
    c = object_centre(library.mesh(seq.obj_name))
    R_loc = np.einsum("nji,njk->nik", R_o, R_w)  # wrist in the object frame
    # Model frame y = Q (x - c): a random rotation (augmentation), or else the object
    # centred and aligned with the world (Q = R_o), the frame prediction generates in.
    Q = Rotation.random(n, random_state=rng).as_matrix() if rng is not None else R_o
    A = np.transpose(Q, (0, 2, 1))
    orient = Q @ R_loc
    transl = np.einsum("nij,nj->ni", Q, p_loc - c)
    return A, b_of(c, n), orient, transl, pose


def b_of(c: np.ndarray, n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(c, float), (n, 3)).copy()


def collect_samples(
    seqs: list[Sequence], library: ObjectLibrary, cfg: GrabNetTrainConfig, tied: bool, seed: int
) -> Samples:
    """Ground-truth grasp frames of the train split as model-frame samples."""
    rng = np.random.default_rng(seed)
    sides = U.SIDES if tied else ("right",)
    names = sorted({s.obj_name for s in seqs})
    parts = []
    # Candidate frames: every frame_stride-th frame from a random phase; the tied variant
    # takes its two hands on interleaved frames, so both variants pose as many hands.
    stride = cfg.frame_stride * len(sides)
    for seq in seqs:
        phase = int(rng.integers(stride))
        for k, side in enumerate(sides):
            start = (phase + k * cfg.frame_stride) % stride
            cand = np.arange(start, seq.n_frames, stride)
            frames = cand[U.contact_frames(library, seq, side, frames=cand)]
            if len(frames):
                aug = rng if (cfg.augment and not tied) else None
                arrays = _frame_samples(seq, library, side, frames, tied, aug)
                parts.append((np.full(len(frames), names.index(seq.obj_name)), *arrays))
    if not parts:
        raise InputError("no grasp frames in the train split", "grabnet training data")
    cols = [np.concatenate([np.asarray(p[k]) for p in parts]) for k in range(6)]
    keep = np.arange(len(cols[0]))
    if cfg.max_frames and len(keep) > cfg.max_frames:
        keep = np.sort(rng.choice(len(keep), cfg.max_frames, replace=False))
    obj, A, b, orient, transl, pose = (c[keep] for c in cols)
    return Samples(obj, names, A, b, orient, transl, pose)


def bps_codes(
    library: ObjectLibrary,
    names: list[str],
    obj: np.ndarray,
    A: np.ndarray,
    b: np.ndarray,
    basis: np.ndarray,
    centre: tuple[float, float, float] | np.ndarray,
) -> np.ndarray:
    """BPS distances (N, n) (m): basis ``centre + basis`` in each sample's model frame,
    mapped to the object frame, distance to the object's surface (exact, libigl)."""
    out = np.empty((len(obj), len(basis)))
    local = np.asarray(centre, float) + basis  # (n, 3)
    for k in np.unique(obj):
        rows = np.flatnonzero(obj == k)
        mesh = library.mesh(names[k])
        q = np.einsum("rij,nj->rni", A[rows], local) + b[rows, None]  # (R, n, 3)
        sqd, _, _ = igl.point_mesh_squared_distance(
            q.reshape(-1, 3),
            np.ascontiguousarray(mesh.vertices, np.float64),
            np.ascontiguousarray(mesh.faces, np.int64),
        )
        out[rows] = np.sqrt(sqd).reshape(len(rows), -1)
    return out


# ----------------------------------------------------------------------------- tensors


def to_grasp(
    orient: np.ndarray, transl: np.ndarray, pose: np.ndarray, device: U.Device = "cpu"
) -> GraspParams:
    """numpy (N,3,3), (N,3), (N,45) -> float32 :class:`GraspParams` with 6D rotations."""
    o6 = np.concatenate([orient[..., :, 0], orient[..., :, 1]], -1)
    p6 = axis_angle_to_rotation_6d(np.asarray(pose, np.float64).reshape(-1, 15, 3))
    f = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
    return GraspParams(f(o6), f(transl), f(p6))


def index_grasp(g: GraspParams, idx: np.ndarray | torch.Tensor) -> GraspParams:
    return GraspParams(*(x[idx] for x in g))


def pin_wrist(g: GraspParams) -> GraspParams:
    """The same fingers on the identity wrist at the origin (the tied variant's frame)."""
    eye = g.global_orient.new_tensor((1.0, 0.0, 0.0, 0.0, 1.0, 0.0)).expand_as(g.global_orient)
    return GraspParams(eye, torch.zeros_like(g.transl), g.hand_pose)


def field_distance_and_gradient(
    field: DistanceField, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance ``(N,)`` (m) and unit outward gradient ``(N, 3)`` of object-frame
    points ``q (N, 3)``.

    Within the field's grid padding of the object (every point that can be inside it or
    in contact) both come from the field; beyond it the distance is the bounding-box
    bound (``far="bound"``) and the gradient points away from the box, which is all a
    loss needs of a far point (the direction back towards the object) and costs no
    exact mesh query.
    """
    d = field.signed_distance(q, far="bound")
    g = np.empty_like(q)
    lo, hi = field.mesh.bounds
    off = q - np.clip(q, lo, hi)
    norm = np.linalg.norm(off, axis=1)
    near = (d < 0.99 * field.padding) | (norm < 1e-9)
    if near.any():
        g[near] = field.gradient(q[near])
    g[~near] = off[~near] / norm[~near, None]
    return d, g


class _FeedSDF(torch.autograd.Function):
    """Signed distance of model-frame points with the field's gradient as derivative."""

    @staticmethod
    def forward(ctx: Any, points: torch.Tensor, feed: DistanceFeed) -> torch.Tensor:
        d, g = feed.distance(points.detach(), gradient=True)
        ctx.save_for_backward(g)
        return d

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, None]:
        (g,) = ctx.saved_tensors
        return grad[..., None] * g, None


class DistanceFeed:
    """Object distances of model-frame points for a batch of samples.

    Sample ``i`` maps model-frame points ``y`` to its object's frame ``x = A_i y + b_i``.
    ``feed(grasp)`` is RefineNet's distance function (signed distances ``(B, K)`` of the
    proximity vertices); :meth:`sdf` is the differentiable signed distance of any
    model-frame points ``(B, V, 3)``, for the contact and penetration losses.
    """

    def __init__(
        self,
        library: ObjectLibrary,
        names: list[str],
        obj: np.ndarray,
        A: np.ndarray,
        b: np.ndarray,
        hand: ProceduralHand,
        vertex_ids: np.ndarray | list[int],
    ) -> None:
        self.library, self.names, self.obj = library, names, np.asarray(obj)
        self.A, self.b = np.asarray(A), np.asarray(b)
        self.hand_fn = make_hand_fn(U.SubsetHand(hand, vertex_ids))

    def subset(self, idx: np.ndarray | list[int]) -> DistanceFeed:
        """The feed of samples ``idx`` (same library, objects and hand)."""
        out = object.__new__(DistanceFeed)
        out.library, out.names, out.hand_fn = self.library, self.names, self.hand_fn
        out.obj, out.A, out.b = self.obj[idx], self.A[idx], self.b[idx]
        return out

    def distance(
        self, points: torch.Tensor, gradient: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Signed distances ``(B, V)`` of model-frame points ``(B, V, 3)`` (torch, the
        points' dtype); with ``gradient`` also ``d distance / d point`` ``(B, V, 3)``."""
        y = points.detach().double().cpu().numpy()
        x = np.einsum("bij,bkj->bki", self.A, y) + self.b[:, None]
        d = np.empty(y.shape[:2])
        g = np.empty(y.shape) if gradient else None
        for k in np.unique(self.obj):
            rows = self.obj == k
            field = self.library.field(self.names[k])
            if gradient:
                dk, gk = field_distance_and_gradient(field, x[rows].reshape(-1, 3))
                d[rows] = dk.reshape(-1, y.shape[1])
                # x = A y + b, so d distance / dy = A^T grad_x.
                g[rows] = np.einsum("bji,bkj->bki", self.A[rows], gk.reshape(-1, y.shape[1], 3))
            else:
                d[rows] = field.signed_distance(x[rows], far="bound")
        t = lambda a: torch.as_tensor(a, dtype=points.dtype, device=points.device)  # noqa: E731
        return (t(d), t(g)) if gradient else t(d)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Differentiable signed distances ``(B, V)`` of model-frame points ``(B, V, 3)``."""
        return _FeedSDF.apply(points, self)

    def __call__(self, grasp: GraspParams) -> torch.Tensor:
        with torch.no_grad():
            y = self.hand_fn(grasp)  # (B, K, 3) model frame
        return self.distance(y).to(grasp.transl.dtype)


def refine(
    net: RefineNet, grasp: GraspParams, feed: Callable[[GraspParams], torch.Tensor], tied: bool
) -> list[GraspParams]:
    """RefineNet's iterations; the tied variant keeps its wrist pinned after each step."""
    steps = []
    for i in range(net.cfg.n_iters):
        grasp = net.step(grasp, feed(grasp), i)
        grasp = pin_wrist(grasp) if tied else grasp
        steps.append(grasp)
    return steps


# ----------------------------------------------------------------------------- training


def _noisy(
    g: GraspParams, cfg: GrabNetTrainConfig, tied: bool, gen: torch.Generator
) -> GraspParams:
    """GT grasps with Gaussian noise on finger axis-angles, root orientation and position
    (drawn from the CPU generator ``gen``, then put on the grasps' device)."""
    dev = g.transl.device
    pose = rotation_6d_to_axis_angle(g.hand_pose)
    pose = pose + cfg.noise_finger * U.randn(pose.shape, gen, dev)
    if tied:
        return GraspParams(g.global_orient, g.transl, axis_angle_to_rotation_6d(pose))
    R = rotation_6d_to_matrix(g.global_orient)
    dR = axis_angle_to_rotation_6d(cfg.noise_orient * U.randn((R.shape[0], 3), gen, dev))
    R = rotation_6d_to_matrix(dR) @ R
    transl = g.transl + cfg.noise_transl * U.randn(g.transl.shape, gen, dev)
    return GraspParams(
        torch.cat([R[..., :, 0], R[..., :, 1]], -1), transl, axis_angle_to_rotation_6d(pose)
    )


def _contact_weights(feed: DistanceFeed, target: GraspParams) -> torch.Tensor:
    """Per proximity vertex contact likelihood in the training grasps, as RefineNet's
    distance weights (GrabNet learns these from GRAB): 0.25 + 0.75 * frequency / max."""
    d = feed(target)
    freq = (d.cpu().numpy() <= 0.0045).mean(0)
    weights = 0.25 + 0.75 * freq / max(freq.max(), 1e-9)
    return torch.as_tensor(weights, dtype=torch.float32, device=d.device)


def _epochs(
    name: str,
    net: torch.nn.Module,
    params: Any,
    n: int,
    cfg: GrabNetTrainConfig,
    epochs: int,
    step: Callable[[torch.nn.Module, np.ndarray], torch.Tensor],
    progress: bool,
    rng: np.random.Generator,
) -> torch.nn.Module:
    """Train ``net`` for ``epochs``; ``step(model, idx)`` is the loss of samples ``idx``
    through ``model`` (``net``, or its DDP wrapper in a DDP job: each rank its share)."""
    opt = torch.optim.Adam(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    d = ddp.current()
    model = ddp.wrap(net, d, U.device_of(net))  # BatchNorm over the global batch
    for epoch in range(epochs):
        net.train()
        total = 0.0
        for idx, w in U.rank_batches(U.batches(n, cfg.batch_size, rng), d):
            loss = step(model, idx)
            opt.zero_grad()
            U.backward(loss, w)
            opt.step()
            total += loss.item() * len(idx)
        total = ddp.global_sum([total], d)[0]
        U.log(progress, name, f"epoch {epoch + 1}/{epochs} loss {total / n:.4f}")
    return net.eval()


class _RefineRun(torch.nn.Module):
    """:func:`refine` as a module's forward ``(grasp, feed) -> [GraspParams] * n_iters``,
    so that DDP, which hooks ``forward``, can wrap RefineNet's training iterations."""

    def __init__(self, net: RefineNet, tied: bool) -> None:
        super().__init__()
        self.net, self.tied = net, tied

    def forward(self, grasp: GraspParams, feed: DistanceFeed) -> list[GraspParams]:
        return refine(self.net, grasp, feed, self.tied)


def _coarse_inputs(
    coarse: CoarseNet, bps: torch.Tensor, gt: GraspParams, tied: bool, gen: torch.Generator
) -> GraspParams:
    """CoarseNet's reconstructions of ``gt`` (z from the posterior), as RefineNet sees
    CoarseNet grasps at inference; no gradient into CoarseNet."""
    with torch.no_grad():
        g = coarse(bps, gt, generator=gen).grasp
    return pin_wrist(g) if tied else g


def train_grabnet(
    name: str,
    data_dir: Path,
    cfg: GrabNetTrainConfig,
    tied: bool,
    seed: int,
    progress: bool,
    device: U.Device = "cpu",
) -> tuple[CoarseNet, RefineNet, int]:
    """CoarseNet then RefineNet, built and trained on ``device``; returns
    (coarse, refine, n_samples).

    Both are trained with the vertex, pose and translation data terms plus GRAB's contact
    and penetration terms on the object's distance field (``w_contact``,
    ``w_penetration``); RefineNet sees noisy ground truth and, for a share
    ``refine_coarse_share`` of each batch, CoarseNet's own reconstructions.
    """
    torch.manual_seed(seed)
    rng, gen = np.random.default_rng(seed), U.seeded(seed)
    d = ddp.current()
    # DDP: the latent samples, noise and CoarseNet rows of a rank's share come from the
    # rank's own streams; ``rng`` only orders the global batches, the same on every rank
    row_rng = np.random.default_rng(U.rank_seed(seed, d)) if d.active else rng
    library = U.train_library(data_dir)
    s = collect_samples(
        U.train_sequences(data_dir, cfg.max_sequences, seed), library, cfg, tied, seed
    )
    centre = GRABNET_SMPLX_BPS_CENTRE if tied else (0.0, 0.0, 0.0)
    bps = torch.as_tensor(
        bps_codes(library, s.names, s.obj, s.A, s.b, basis_points(cfg.bps_points), centre),
        dtype=torch.float32,
        device=device,
    )
    target = to_grasp(s.orient, s.transl, s.pose, device)
    hand = U.hand_model("right", device=device)
    hand_fn = make_hand_fn(U.SubsetHand(hand, U.vertex_subset(hand, cfg.loss_vertices)))
    feed_all = DistanceFeed(library, s.names, s.obj, s.A, s.b, hand, hand.proximity_ids)
    with torch.no_grad():
        gt_contact = feed_all.distance(hand_fn(target)) < CONTACT_THRESHOLD  # (N, V)
    lcfg = GrabNetLossConfig(
        w_kl=cfg.w_kl, w_contact=cfg.w_contact, w_penetration=cfg.w_penetration
    )
    U.log(progress, name, f"{len(s.obj)} grasp frames of {len(s.names)} objects")

    def loss(
        pred: GraspParams, idx: np.ndarray, feed: DistanceFeed, contact: bool = True,
        **kw: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        gt = index_grasp(target, idx)
        sdf = dict(sdf=feed.sdf, gt_contact=gt_contact[idx]) if contact else {}
        return losses(pred, gt, lcfg, hand_fn=hand_fn, **sdf, **kw)

    coarse = CoarseNetConfig(
        bps_dim=cfg.bps_points, width=cfg.width, hidden=cfg.hidden, latent=cfg.latent
    ).build().to(device)
    if d.active:  # after the seeded initialisation, identical on every rank
        gen = U.seeded(U.rank_seed(seed, d, 1))

    def coarse_step(net: torch.nn.Module, idx: np.ndarray) -> torch.Tensor:
        out = net(bps[idx], index_grasp(target, idx), generator=gen)
        return loss(out.grasp, idx, feed_all.subset(idx), mu=out.mu, logvar=out.logvar)[0]

    _epochs(name, coarse, coarse.parameters(), len(s.obj), cfg, cfg.epochs_coarse, coarse_step,
            progress, rng)  # fmt: skip

    refine_net = RefineNetConfig(
        n_verts=PROXIMITY_N_VERTS, width=cfg.refine_width, hidden=cfg.refine_width
    ).build().to(device)
    refine_net.contact_weights.copy_(_contact_weights(feed_all, target))

    def refine_step(net: torch.nn.Module, idx: np.ndarray) -> torch.Tensor:
        feed = feed_all.subset(idx)
        gt = index_grasp(target, idx)
        start = _noisy(gt, cfg, tied, gen)
        n_coarse = int(round(cfg.refine_coarse_share * len(idx)))
        if n_coarse:
            rows = np.sort(row_rng.permutation(len(idx))[:n_coarse])
            rec = _coarse_inputs(coarse.eval(), bps[idx[rows]], index_grasp(gt, rows), tied, gen)
            at = torch.as_tensor(rows, device=device)
            start = GraspParams(*(a.index_copy(0, at, b) for a, b in zip(start, rec, strict=True)))
        steps = net(start, feed)  # refine() through _RefineRun (DDP sees a forward)
        # Data terms on every step; contact and penetration on the final grasp (the one
        # that is used), which also keeps the distance queries to one per batch.
        last = len(steps) - 1
        total = sum(loss(g, idx, feed, contact=i == last)[0] for i, g in enumerate(steps))
        return total / len(steps)

    _epochs(name, _RefineRun(refine_net, tied), refine_net.parameters(), len(s.obj), cfg,
            cfg.epochs_refine, refine_step, progress, rng)  # fmt: skip
    refine_net.eval()
    return coarse, refine_net, len(s.obj)


# ----------------------------------------------------------------------------- method


class GrabNetMethod(U.TrainedMethod):
    """GrabNet-style grasp synthesis (``tied=False``) or its body-tied variant (``tied=True``)."""

    section, config_cls = "grabnet", GrabNetTrainConfig
    networks = {"coarse": CoarseNetConfig, "refine": RefineNetConfig}

    def __init__(self, name: str, tied: bool = False) -> None:
        super().__init__(name)
        self.tied = tied
        self.coarse: CoarseNet | None = None
        self.refine_net: RefineNet | None = None

    def fit(
        self, data_dir: Path, cfg: GrabNetTrainConfig, seed: int, progress: bool,
        device: torch.device,
    ) -> tuple[dict[str, torch.nn.Module], dict]:
        coarse, ref, n = train_grabnet(self.name, data_dir, cfg, self.tied, seed, progress,
                                       device)
        return {"coarse": coarse, "refine": ref}, {"n_samples": n, "tied": self.tied}

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        nets = self.load_checkpoint(checkpoint, device)[0]
        self.coarse, self.refine_net = nets["coarse"], nets["refine"]

    def predict(self, seq: Sequence, ctx: PredictContext) -> Sequence:
        """The input with generated hands at the grasp frames of the input hands
        (networks on the device :meth:`load` put them on)."""
        self._loaded(self.coarse, self.refine_net)
        sides = U.SIDES if self.tied else ("right",)
        with U.single_thread():
            new = {side: self._predict_side(seq, ctx, side) for side in sides}
        return seq.with_hands(**{k: v for k, v in new.items() if v is not None})

    def _frames(self, seq: Sequence, ctx: PredictContext, side: str) -> np.ndarray:
        given = (ctx.grasp_frames or {}).get(side)
        if given is not None:
            return np.flatnonzero(np.asarray(given, bool))
        return np.flatnonzero(U.contact_frames(ctx.library, seq, side))

    def _predict_side(self, seq: Sequence, ctx: PredictContext, side: str) -> dict | None:
        frames = self._frames(seq, ctx, side)
        if len(frames) == 0:
            return None
        library, cfg = ctx.library, self.coarse.cfg
        # Without augmentation the model frame is the prediction frame: the wrist frame
        # (tied) or the object centred and aligned with the world (A = R_o^T).
        A, b, _, _, _ = _frame_samples(seq, library, side, frames, self.tied, None)
        names, obj = [seq.obj_name], np.zeros(len(frames), int)
        centre = GRABNET_SMPLX_BPS_CENTRE if self.tied else (0.0, 0.0, 0.0)
        dev = self.device
        bps = torch.as_tensor(
            bps_codes(library, names, obj, A, b, basis_points(cfg.bps_dim), centre),
            dtype=torch.float32,
            device=dev,
        )
        offset = 0 if side == "right" else 100_003  # distinct latents for the two hands
        # z per frame from a CPU generator (the same latents on every device), moved once
        z = torch.stack(
            [
                torch.randn(cfg.latent, generator=U.seeded(ctx.seed + int(t) + offset))
                for t in frames
            ]
        ).to(dev)
        hand = U.seq_hand(seq, "right", dev)  # the model frame is a right hand's
        feed = DistanceFeed(library, names, obj, A, b, hand, hand.proximity_ids)
        with torch.no_grad():
            grasp = self.coarse.decode(z, bps)
            grasp = pin_wrist(grasp) if self.tied else grasp
            grasp = refine(self.refine_net, grasp, feed, self.tied)[-1]
        return self._to_world(seq, side, frames, grasp, A, b)

    def _to_world(
        self,
        seq: Sequence,
        side: str,
        frames: np.ndarray,
        grasp: GraspParams,
        A: np.ndarray,
        b: np.ndarray,
    ) -> dict:
        """Model-frame grasps -> the side's full-length hand params (input elsewhere)."""
        p = {k: np.array(v, float) for k, v in seq.hand_params(side).items()}
        go, pose, transl = (x.double().cpu().numpy() for x in grasp.axis_angle())
        pose = pose.reshape(len(frames), 45)
        p["hand_pose"][frames] = U.mirror_pose(pose) if side == "left" else pose
        if not self.tied:
            R_o, t_o = (x[frames] for x in U.object_pose(seq))
            R_y = Rotation.from_rotvec(go).as_matrix()
            p["global_orient"][frames] = U.matrix_to_rotvec(R_o @ A @ R_y)
            p["transl"][frames] = (
                np.einsum("nij,nj->ni", R_o, np.einsum("nij,nj->ni", A, transl) + b) + t_o
            )
        return {k: p[k] for k in ("global_orient", "hand_pose", "transl")}


register_method(
    MethodSpec(
        name="grabnet",
        description="GrabNet-style static right-hand grasps (CoarseNet cVAE + RefineNet) "
        "per grasp frame",
        factory=GrabNetMethod,
        needs=("object",),
        options={"tied": False},
        hands=("right",),
    )
)
register_method(
    MethodSpec(
        name="grabnet-smplx",
        description="GrabNet fingers for both hands at the body's wrists (BPS in the wrist frame)",
        factory=GrabNetMethod,
        needs=("object", "body"),
        options={"tied": True},
    )
)
