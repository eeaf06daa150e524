"""``grabnet`` and ``grabnet-smplx``: GrabNet-style static grasp synthesis as benchmark methods.

Both train CoarseNet (cVAE, :mod:`grip_baselines.grabnet`) on ground-truth grasp frames
of the train split, then RefineNet on perturbed ground-truth grasps (GRAB S.9.2). They
differ in the *model frame* a grasp lives in:

* ``grabnet`` (free wrist, GrabNet proper): the right hand's grasp in the object frame,
  centred at the BPS centre (the object's surface centroid), under a random rotation
  per sample (augmentation). The network generates wrist orientation, wrist position and
  fingers. At prediction the frame is the object centred and *aligned with the world*,
  so the generated wrist is placed in the world by the object's translation only.
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
import time
from dataclasses import dataclass
from pathlib import Path

import igl
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from grip_bench.bench.methods import MethodSpec, PredictContext, register_method
from grip_bench.constants import GRABNET_NOISE_VAR, GRABNET_SMPLX_BPS_CENTRE, PROXIMITY_N_VERTS
from grip_bench.geometry.rotations import (
    axis_angle_to_rotation_6d,
    rotation_6d_to_axis_angle,
    rotation_6d_to_matrix,
)

from . import common as U
from .bps import basis_points, object_centre
from .grabnet import (
    CoarseNetConfig,
    GrabNetLossConfig,
    GraspParams,
    RefineNetConfig,
    losses,
    make_hand_fn,
)

IDENTITY = np.eye(3)


@dataclass
class GrabNetTrainConfig:
    """Profile section ``[grabnet]`` (shared by ``grabnet-smplx``)."""

    bps_points: int = 1024  # GRAB uses 4096; 1024 keeps CPU training in minutes
    width: int = 256
    hidden: int = 256
    latent: int = 16
    refine_width: int = 256
    epochs_coarse: int = 12
    epochs_refine: int = 8
    batch_size: int = 128
    lr: float = 5e-4  # GRAB S.9.3
    weight_decay: float = 1e-5  # GRAB's "weight regulariser"
    w_kl: float = 5e-3
    max_frames: int = 6000  # grasp frames sampled from the train split (0 = all)
    max_sequences: int = 0  # train files read (0 = all)
    loss_vertices: int = 256  # hand vertices in the vertex L1 (a fixed stride subset)
    augment: bool = True  # random object rotation per sample (grabnet only)
    # RefineNet training noise (std). GRAB S.9.2 gives variances 0.2 rad^2 (fingers) and
    # 0.004 rad^2 (root); its translation variance 0.05 would put the hand 22 cm away,
    # beyond the 5 cm distance clip, so a centimetre-scale translation noise is used.
    noise_finger: float = math.sqrt(GRABNET_NOISE_VAR[0])
    noise_orient: float = math.sqrt(GRABNET_NOISE_VAR[1])
    noise_transl: float = 0.01


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


def _frame_samples(seq, library, side: str, frames: np.ndarray, tied: bool, rng):
    """Per grasp frame of one hand: (A, b, orient, transl, pose) arrays."""
    R_o, t_o = U.object_pose(seq)
    p = seq.hand_params(side)
    R_w, p_w = U.wrist_pose(p)
    R_o, t_o, R_w, p_w = R_o[frames], t_o[frames], R_w[frames], p_w[frames]
    pose = np.asarray(p["hand_pose"], float)[frames]
    n = len(frames)
    if tied:
        S = U.MIRROR if side == "left" else IDENTITY
        A = np.einsum("nji,njk,kl->nil", R_o, R_w, S)  # R_o^T R_w S
        b = np.einsum("nji,nj->ni", R_o, p_w - t_o)
        pose = U.mirror_pose(pose) if side == "left" else pose
        return A, b, np.broadcast_to(IDENTITY, (n, 3, 3)), np.zeros((n, 3)), pose
    c = object_centre(library.mesh(seq.obj_name))
    R_loc = np.einsum("nji,njk->nik", R_o, R_w)  # wrist in the object frame
    p_loc = np.einsum("nji,nj->ni", R_o, p_w - t_o)
    Q = (
        Rotation.random(n, random_state=rng).as_matrix()
        if rng is not None
        else np.tile(IDENTITY, (n, 1, 1))
    )
    A = np.transpose(Q, (0, 2, 1))
    orient = Q @ R_loc
    transl = np.einsum("nij,nj->ni", Q, p_loc - c)
    return A, b_of(c, n), orient, transl, pose


def b_of(c: np.ndarray, n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(c, float), (n, 3)).copy()


def collect_samples(seqs, library, cfg: GrabNetTrainConfig, tied: bool, seed: int) -> Samples:
    """Ground-truth grasp frames of the train split as model-frame samples."""
    rng = np.random.default_rng(seed)
    sides = U.SIDES if tied else ("right",)
    names = sorted({s.obj_name for s in seqs})
    parts = []
    for seq in seqs:
        for side in sides:
            frames = np.flatnonzero(U.contact_frames(library, seq, side))
            if len(frames):
                aug = rng if (cfg.augment and not tied) else None
                arrays = _frame_samples(seq, library, side, frames, tied, aug)
                parts.append((np.full(len(frames), names.index(seq.obj_name)), *arrays))
    if not parts:
        from grip_bench.errors import InputError

        raise InputError("no grasp frames in the train split", "grabnet training data")
    cols = [np.concatenate([np.asarray(p[k]) for p in parts]) for k in range(6)]
    keep = np.arange(len(cols[0]))
    if cfg.max_frames and len(keep) > cfg.max_frames:
        keep = np.sort(rng.choice(len(keep), cfg.max_frames, replace=False))
    obj, A, b, orient, transl, pose = (c[keep] for c in cols)
    return Samples(obj, names, A, b, orient, transl, pose)


def bps_codes(library, names, obj, A, b, basis, centre) -> np.ndarray:
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


def to_grasp(orient, transl, pose) -> GraspParams:
    """numpy (N,3,3), (N,3), (N,45) -> float32 :class:`GraspParams` with 6D rotations."""
    o6 = np.concatenate([orient[..., :, 0], orient[..., :, 1]], -1)
    p6 = axis_angle_to_rotation_6d(np.asarray(pose, np.float64).reshape(-1, 15, 3))
    f = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    return GraspParams(f(o6), f(transl), f(p6))


def index_grasp(g: GraspParams, idx) -> GraspParams:
    return GraspParams(*(x[idx] for x in g))


def pin_wrist(g: GraspParams) -> GraspParams:
    """The same fingers on the identity wrist at the origin (the tied variant's frame)."""
    eye = g.global_orient.new_tensor((1.0, 0.0, 0.0, 0.0, 1.0, 0.0)).expand_as(g.global_orient)
    return GraspParams(eye, torch.zeros_like(g.transl), g.hand_pose)


class DistanceFeed:
    """RefineNet's distance function for a batch: signed distances (B, K) (m) of the
    proximity vertices of a model-frame grasp to each sample's object."""

    def __init__(self, library, names, obj, A, b, hand, vertex_ids):
        self.library, self.names, self.obj = library, names, np.asarray(obj)
        self.A, self.b = np.asarray(A), np.asarray(b)
        self.hand_fn = make_hand_fn(hand, vertex_ids)

    def __call__(self, grasp: GraspParams) -> torch.Tensor:
        with torch.no_grad():
            y = self.hand_fn(grasp).double().numpy()  # (B, K, 3) model frame
        x = np.einsum("bij,bkj->bki", self.A, y) + self.b[:, None]
        d = np.empty(y.shape[:2])
        for k in np.unique(self.obj):
            rows = self.obj == k
            d[rows] = self.library.field(self.names[k]).signed_distance(x[rows], far="bound")
        return torch.as_tensor(d, dtype=grasp.transl.dtype)


def refine(net, grasp: GraspParams, feed, tied: bool) -> list[GraspParams]:
    """RefineNet's iterations; the tied variant keeps its wrist pinned after each step."""
    steps = []
    for i in range(net.cfg.n_iters):
        grasp = net.step(grasp, feed(grasp), i)
        grasp = pin_wrist(grasp) if tied else grasp
        steps.append(grasp)
    return steps


# ----------------------------------------------------------------------------- training


def _noisy(g: GraspParams, cfg: GrabNetTrainConfig, tied: bool, gen) -> GraspParams:
    """GT grasps with Gaussian noise on finger axis-angles, root orientation and position."""
    pose = rotation_6d_to_axis_angle(g.hand_pose)
    pose = pose + cfg.noise_finger * torch.randn(pose.shape, generator=gen)
    if tied:
        return GraspParams(g.global_orient, g.transl, axis_angle_to_rotation_6d(pose))
    R = rotation_6d_to_matrix(g.global_orient)
    dR = axis_angle_to_rotation_6d(cfg.noise_orient * torch.randn(R.shape[0], 3, generator=gen))
    R = rotation_6d_to_matrix(dR) @ R
    transl = g.transl + cfg.noise_transl * torch.randn(g.transl.shape, generator=gen)
    return GraspParams(
        torch.cat([R[..., :, 0], R[..., :, 1]], -1), transl, axis_angle_to_rotation_6d(pose)
    )


def _contact_weights(feed: DistanceFeed, target: GraspParams) -> torch.Tensor:
    """Per proximity vertex contact likelihood in the training grasps, as RefineNet's
    distance weights (GrabNet learns these from GRAB): 0.25 + 0.75 * frequency / max."""
    d = feed(target).numpy()
    freq = (d <= 0.0045).mean(0)
    return torch.as_tensor(0.25 + 0.75 * freq / max(freq.max(), 1e-9), dtype=torch.float32)


def _epochs(name, net, params, n, cfg, epochs, step, progress, rng):
    opt = torch.optim.Adam(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    for epoch in range(epochs):
        net.train()
        total = 0.0
        for idx in U.batches(n, cfg.batch_size, rng):
            loss = step(idx)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        U.log(progress, name, f"epoch {epoch + 1}/{epochs} loss {total / n:.4f}")
    return net.eval()


def train_grabnet(name, data_dir, cfg, tied, seed, progress):
    """CoarseNet then RefineNet; returns (coarse, refine, n_samples)."""
    from grip_bench.data.library import ObjectLibrary

    torch.manual_seed(seed)
    rng, gen = np.random.default_rng(seed), U.seeded(seed)
    library = ObjectLibrary(data_dir)
    s = collect_samples(
        U.train_sequences(data_dir, cfg.max_sequences, seed), library, cfg, tied, seed
    )
    centre = GRABNET_SMPLX_BPS_CENTRE if tied else (0.0, 0.0, 0.0)
    bps = torch.as_tensor(
        bps_codes(library, s.names, s.obj, s.A, s.b, basis_points(cfg.bps_points), centre),
        dtype=torch.float32,
    )
    target = to_grasp(s.orient, s.transl, s.pose)
    hand = U.hand_model("right")
    vids = U.vertex_subset(hand, cfg.loss_vertices)
    hand_fn = make_hand_fn(hand, vids)
    lcfg = GrabNetLossConfig(w_kl=cfg.w_kl)
    U.log(progress, name, f"{len(s.obj)} grasp frames of {len(s.names)} objects")

    coarse = CoarseNetConfig(
        bps_dim=cfg.bps_points, width=cfg.width, hidden=cfg.hidden, latent=cfg.latent
    ).build()

    def coarse_step(idx):
        out = coarse(bps[idx], index_grasp(target, idx), generator=gen)
        return losses(
            out.grasp, index_grasp(target, idx), lcfg, hand_fn=hand_fn, mu=out.mu, logvar=out.logvar
        )[0]

    _epochs(
        name,
        coarse,
        coarse.parameters(),
        len(s.obj),
        cfg,
        cfg.epochs_coarse,
        coarse_step,
        progress,
        rng,
    )

    refine_net = RefineNetConfig(
        n_verts=PROXIMITY_N_VERTS, width=cfg.refine_width, hidden=cfg.refine_width
    ).build()
    feed_all = DistanceFeed(library, s.names, s.obj, s.A, s.b, hand, hand.proximity_ids)
    refine_net.contact_weights.copy_(_contact_weights(feed_all, target))
    lcfg_r = GrabNetLossConfig(w_kl=0.0)

    def refine_step(idx):
        feed = DistanceFeed(
            library, s.names, s.obj[idx], s.A[idx], s.b[idx], hand, hand.proximity_ids
        )
        gt = index_grasp(target, idx)
        steps = refine(refine_net, _noisy(gt, cfg, tied, gen), feed, tied)
        return sum(losses(g, gt, lcfg_r, hand_fn=hand_fn)[0] for g in steps) / len(steps)

    _epochs(
        name,
        refine_net,
        refine_net.parameters(),
        len(s.obj),
        cfg,
        cfg.epochs_refine,
        refine_step,
        progress,
        rng,
    )
    return coarse, refine_net, len(s.obj)


# ----------------------------------------------------------------------------- method


class GrabNetMethod:
    """GrabNet-style grasp synthesis (``tied=False``) or its body-tied variant (``tied=True``)."""

    def __init__(self, name: str, tied: bool = False):
        self.name, self.tied = name, tied
        self.coarse = self.refine_net = None

    def train(
        self,
        data_dir: Path,
        out: Path,
        *,
        profile: dict,
        seed: int = 0,
        device: str = "cpu",
        progress: bool = True,
    ) -> Path:
        t0 = time.perf_counter()
        cfg = U.section_config(GrabNetTrainConfig, profile, "grabnet")
        coarse, ref, n = train_grabnet(self.name, Path(data_dir), cfg, self.tied, seed, progress)
        meta = U.train_meta(self.name, Path(data_dir), seed, cfg, t0, n_samples=n, tied=self.tied)
        return U.save_models(Path(out), {"coarse": coarse, "refine": ref}, meta)

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        ck = U.load_own(checkpoint, {"coarse": CoarseNetConfig, "refine": RefineNetConfig}, self.name)
        nets = ck.models()
        self.coarse, self.refine_net = nets["coarse"], nets["refine"]

    def predict(self, seq, ctx: PredictContext):
        """The input with generated hands at the grasp frames of the input hands."""
        if self.coarse is None:
            from grip_bench.errors import InputError

            raise InputError("load a checkpoint before predicting", self.name)
        sides = U.SIDES if self.tied else ("right",)
        new = {side: self._predict_side(seq, ctx, side) for side in sides}
        return seq.with_hands(**{k: v for k, v in new.items() if v is not None})

    def _frames(self, seq, ctx, side):
        given = (ctx.extra or {}).get("grasp_frames", {}).get(side)
        if given is not None:
            return np.flatnonzero(np.asarray(given, bool))
        return np.flatnonzero(U.contact_frames(ctx.library, seq, side))

    def _predict_side(self, seq, ctx, side):
        frames = self._frames(seq, ctx, side)
        if len(frames) == 0:
            return None
        library, cfg = ctx.library, self.coarse.cfg
        A, b, _, _, _ = _frame_samples(seq, library, side, frames, self.tied, None)
        if not self.tied:  # object centred, aligned with the world: A = R_o^T
            A = np.transpose(U.object_pose(seq)[0][frames], (0, 2, 1))
        names, obj = [seq.obj_name], np.zeros(len(frames), int)
        centre = GRABNET_SMPLX_BPS_CENTRE if self.tied else (0.0, 0.0, 0.0)
        bps = torch.as_tensor(
            bps_codes(library, names, obj, A, b, basis_points(cfg.bps_dim), centre),
            dtype=torch.float32,
        )
        offset = 0 if side == "right" else 100_003  # distinct latents for the two hands
        z = torch.stack(
            [
                torch.randn(cfg.latent, generator=U.seeded(ctx.seed + int(t) + offset))
                for t in frames
            ]
        )
        hand = U.seq_hand(seq, "right")  # the model frame is a right hand's
        feed = DistanceFeed(library, names, obj, A, b, hand, hand.proximity_ids)
        with torch.no_grad():
            grasp = self.coarse.decode(z, bps)
            grasp = pin_wrist(grasp) if self.tied else grasp
            grasp = refine(self.refine_net, grasp, feed, self.tied)[-1]
        return self._to_world(seq, side, frames, grasp, A, b)

    def _to_world(self, seq, side, frames, grasp, A, b) -> dict:
        """Model-frame grasps -> the side's full-length hand params (input elsewhere)."""
        p = {k: np.array(v, float) for k, v in seq.hand_params(side).items()}
        go, pose, transl = (x.double().numpy() for x in grasp.axis_angle())
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
        description="GrabNet-style static right-hand grasps (CoarseNet cVAE + RefineNet) per grasp frame",
        factory=GrabNetMethod,
        needs=("object",),
        tables=("table4_grasp",),
        options={"tied": False},
    )
)
register_method(
    MethodSpec(
        name="grabnet-smplx",
        description="GrabNet fingers for both hands at the body's wrists (BPS in the wrist frame)",
        factory=GrabNetMethod,
        needs=("object", "body"),
        tables=("table4_grasp",),
        options={"tied": True},
    )
)
