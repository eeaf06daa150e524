"""GrabNet-style static grasp synthesis: CoarseNet (cVAE) + RefineNet (GRAB Sec. 4, S.9).

Written from the paper's description, not from the official code.

* CoarseNet: a conditional VAE. Encoder ``Q(z | grasp, BPS_o)``, decoder
  ``P(grasp | z, BPS_o)``, latent 16, width 512, residual blocks. A grasp is the right
  hand's wrist orientation (6D) and translation in the object frame (centred at the BPS
  centre, metres) plus the 15 finger joints in 6D: 6 + 3 + 90 = 99 numbers.
* RefineNet: 3 iterations; each one looks at the current grasp and the signed distances
  from a fixed set of hand vertices to the object, and adds a residual to the grasp. The
  distance computation is a function passed in, so the network itself is pure torch.

6D = the first two columns of the rotation matrix (``grip_bench.geometry.rotations``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import torch
from torch import nn

from grip_bench.core.constants import (
    BPS_N_POINTS,
    CONTACT_THRESHOLD,
    GRABNET_LATENT,
    GRABNET_REFINE_ITERS,
    GRABNET_WIDTH,
    N_HAND_POSE_JOINTS,
    PROXIMITY_N_VERTS,
    ROT6D_DIM,
)
from grip_bench.geometry.rotations import rotation_6d_to_axis_angle
from grip_bench.nn.blocks import ResMLP, check_config, check_shape

if TYPE_CHECKING:
    from grip_bench.geometry.distance import DistanceField

__all__ = [
    "CoarseNet",
    "CoarseNetConfig",
    "CoarseOutput",
    "GrabNetLossConfig",
    "GraspParams",
    "RefineNet",
    "RefineNetConfig",
    "RefineOutput",
    "losses",
    "contact_loss",
    "make_distance_fn",
    "make_hand_fn",
    "penetration_loss",
    "sdf_with_gradient",
]

IDENTITY_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)


class GraspParams(NamedTuple):
    """One right-hand grasp per row, in the object frame.

    global_orient (B, 6) 6D; transl (B, 3) wrist position (m); hand_pose (B, J, 6) 6D.
    """

    global_orient: torch.Tensor
    transl: torch.Tensor
    hand_pose: torch.Tensor

    def flat(self) -> torch.Tensor:
        """``(B, 9 + J*6)``: orientation, translation, finger joints."""
        return torch.cat([self.global_orient, self.transl, self.hand_pose.flatten(-2)], -1)

    @classmethod
    def from_flat(cls, x: torch.Tensor, n_joints: int = N_HAND_POSE_JOINTS) -> GraspParams:
        """Inverse of :meth:`flat`; x (B, 9 + J*6)."""
        return cls(x[..., :6], x[..., 6:9], x[..., 9:].unflatten(-1, (n_joints, ROT6D_DIM)))

    def axis_angle(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(global_orient (B, 3), hand_pose (B, J, 3), transl (B, 3))`` for a hand model."""
        return (
            rotation_6d_to_axis_angle(self.global_orient),
            rotation_6d_to_axis_angle(self.hand_pose),
            self.transl,
        )


def grasp_dim(n_joints: int, rot_dim: int) -> int:
    return rot_dim + 3 + n_joints * rot_dim


def _with_identity(flat: torch.Tensor, n_joints: int) -> torch.Tensor:
    """Add the identity 6D to every rotation slot of a flat grasp ``(B, D)``.

    A zero network output then decodes to the flat hand, not to the degenerate 6D (0, 0)
    where Gram-Schmidt is undefined; early training stays well conditioned.
    """
    eye = flat.new_tensor(IDENTITY_6D)
    offset = torch.cat([eye, flat.new_zeros(3), eye.repeat(n_joints)])
    return flat + offset


def _transl_scale(cfg: CoarseNetConfig | RefineNetConfig, unit: float) -> torch.Tensor:
    """Per-output multiplier ``(grasp_dim,)``: ``unit`` on the translation, 1 elsewhere."""
    scale = torch.ones(cfg.grasp_dim)
    scale[cfg.rot_dim : cfg.rot_dim + 3] = unit
    return scale


# ----------------------------------------------------------------------------- CoarseNet


@dataclass
class CoarseNetConfig:
    bps_dim: int = BPS_N_POINTS
    n_joints: int = N_HAND_POSE_JOINTS
    rot_dim: int = ROT6D_DIM
    width: int = GRABNET_WIDTH
    hidden: int = GRABNET_WIDTH
    latent: int = GRABNET_LATENT
    n_enc_blocks: int = 2
    n_dec_blocks: int = 2
    # GRAB gives no dropout; the KL term and weight decay regularise.
    dropout: float = 0.0
    # Decoded translations are in this unit (m): grasps sit within ~0.15 m of the object
    # centre, so an O(1) output per decimetre matches the 6D outputs' scale.
    transl_unit: float = 0.1

    def __post_init__(self) -> None:
        check_config(self)
        if not self.transl_unit > 0:
            raise ValueError(f"CoarseNetConfig.transl_unit must be > 0, got {self.transl_unit!r}")

    @property
    def grasp_dim(self) -> int:
        return grasp_dim(self.n_joints, self.rot_dim)

    def build(self) -> CoarseNet:
        return CoarseNet(self)


class CoarseOutput(NamedTuple):
    grasp: GraspParams  # decoded from z ~ Q(z | grasp, bps)
    mu: torch.Tensor  # (B, latent)
    logvar: torch.Tensor  # (B, latent)


class CoarseNet(nn.Module):
    """cVAE over grasps conditioned on the BPS code of the object.

    BatchNorm is used throughout, so call ``.eval()`` before sampling single objects.
    """

    def __init__(self, cfg: CoarseNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        mlp = dict(width=cfg.width, hidden=cfg.hidden, dropout=cfg.dropout)
        self.encoder = ResMLP(
            cfg.bps_dim + cfg.grasp_dim, 2 * cfg.latent, n_blocks=cfg.n_enc_blocks, **mlp
        )
        self.decoder = ResMLP(
            cfg.bps_dim + cfg.latent, cfg.grasp_dim, n_blocks=cfg.n_dec_blocks, **mlp
        )
        self.register_buffer("out_scale", _transl_scale(cfg, cfg.transl_unit), persistent=False)

    def encode(self, bps: torch.Tensor, grasp: GraspParams) -> tuple[torch.Tensor, torch.Tensor]:
        """bps (B, bps_dim) distances (m); grasp -> mu, logvar (B, latent)."""
        check_shape(bps, (None, self.cfg.bps_dim), "CoarseNet bps")
        h = self.encoder(torch.cat([bps, grasp.flat()], -1))  # (B, 2*latent)
        mu, logvar = h.chunk(2, dim=-1)
        return mu, logvar

    def decode(self, z: torch.Tensor, bps: torch.Tensor) -> GraspParams:
        """z (B, latent), bps (B, bps_dim) -> grasp."""
        check_shape(z, (bps.shape[0], self.cfg.latent), "CoarseNet z")
        out = self.decoder(torch.cat([bps, z], -1)) * self.out_scale  # (B, grasp_dim)
        return GraspParams.from_flat(_with_identity(out, self.cfg.n_joints), self.cfg.n_joints)

    def forward(
        self, bps: torch.Tensor, grasp: GraspParams, generator: torch.Generator | None = None
    ) -> CoarseOutput:
        """Training pass: encode, reparameterise, decode."""
        mu, logvar = self.encode(bps, grasp)
        # Drawn where the generator lives (a CPU generator for seeded runs), then moved:
        # the same noise for a seed on every device.
        where = mu.device if generator is None else generator.device
        eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=where)
        eps = eps.to(mu.device)
        z = mu + eps * torch.exp(0.5 * logvar)
        return CoarseOutput(self.decode(z, bps), mu, logvar)

    def sample(
        self,
        bps: torch.Tensor,
        seed: int | None = None,
        generator: torch.Generator | None = None,
    ) -> GraspParams:
        """One grasp per row of ``bps (B, bps_dim)`` from z ~ N(0, I).

        Reproducible: pass ``seed`` (a fresh CPU generator) or your own ``generator``;
        with neither, z comes from torch's global RNG. z is drawn on the CPU so a seed
        gives the same z on any device.
        """
        if generator is None and seed is not None:
            generator = torch.Generator().manual_seed(int(seed))
        z = torch.randn(bps.shape[0], self.cfg.latent, generator=generator, dtype=bps.dtype)
        return self.decode(z.to(bps.device), bps)


# ----------------------------------------------------------------------------- RefineNet

DistanceFn = Callable[[GraspParams], torch.Tensor]  # grasp -> signed distances (B, K) in m


@dataclass
class RefineNetConfig:
    n_verts: int = PROXIMITY_N_VERTS  # hand vertices whose object distance is fed back
    n_joints: int = N_HAND_POSE_JOINTS
    rot_dim: int = ROT6D_DIM
    width: int = GRABNET_WIDTH
    hidden: int = GRABNET_WIDTH
    n_blocks: int = 2
    n_iters: int = GRABNET_REFINE_ITERS
    dropout: float = 0.0
    # Distances beyond this (m) carry no refinement signal; clipping keeps a hand far
    # from the object from dominating BatchNorm statistics.
    dist_clip: float = 0.05
    # The head's translation outputs are in this unit (m): corrections are cm-sized, and an
    # O(1) output per cm sits on the scale of the 6D corrections, so one learning rate
    # suits both (in metres, Adam's ~lr-sized steps swamp a 1 cm correction).
    transl_unit: float = 0.01
    share_weights: bool = False
    zero_init_head: bool = True

    def __post_init__(self) -> None:
        check_config(self)
        for name in ("dist_clip", "transl_unit"):
            if not getattr(self, name) > 0:
                raise ValueError(f"RefineNetConfig.{name} must be > 0, got {getattr(self, name)!r}")

    @property
    def grasp_dim(self) -> int:
        return grasp_dim(self.n_joints, self.rot_dim)

    def build(self) -> RefineNet:
        return RefineNet(self)


class RefineOutput(NamedTuple):
    grasp: GraspParams  # after the last iteration
    steps: list[GraspParams]  # after each iteration (for a loss on every step)
    distances: list[torch.Tensor]  # (B, K) fed to each iteration


class RefineNet(nn.Module):
    """Iterative residual refinement of a grasp from hand-to-object distances.

    Iterative error feedback: at each step a regressor sees the grasp and the distances
    *of that grasp*, and outputs a correction. Each step has its own regressor unless
    ``cfg.share_weights``: the corrections shrink from step to step, so one shared
    network's BatchNorm running statistics would average distributions that match no
    step (measured: a shared 2-step net left 38% of a 2 cm offset in eval mode).
    ``contact_weights (K,)`` scales each vertex's distance feature; GrabNet learns these
    contact likelihoods from GRAB, so training code may set them from contact frequencies
    (default ones).
    """

    def __init__(self, cfg: RefineNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        n_nets = 1 if cfg.share_weights else cfg.n_iters
        self.nets = nn.ModuleList(
            ResMLP(
                cfg.grasp_dim + cfg.n_verts,
                cfg.grasp_dim,
                width=cfg.width,
                hidden=cfg.hidden,
                n_blocks=cfg.n_blocks,
                dropout=cfg.dropout,
            )
            for _ in range(n_nets)
        )
        self.register_buffer("contact_weights", torch.ones(cfg.n_verts))
        self.register_buffer("out_scale", _transl_scale(cfg, cfg.transl_unit), persistent=False)
        if cfg.zero_init_head:
            # An untrained RefineNet returns its input: training learns corrections only.
            for net in self.nets:
                nn.init.zeros_(net.head.weight)
                nn.init.zeros_(net.head.bias)

    def step(self, grasp: GraspParams, distances: torch.Tensor, i: int = 0) -> GraspParams:
        """Refinement step ``i``; distances (B, K) signed (m)."""
        c = self.cfg
        check_shape(distances, (grasp.transl.shape[0], c.n_verts), "RefineNet distances")
        feat = distances.clamp(-c.dist_clip, c.dist_clip) / c.dist_clip * self.contact_weights
        flat = grasp.flat()  # (B, grasp_dim)
        net = self.nets[0 if self.cfg.share_weights else i]
        delta = net(torch.cat([flat, feat.to(flat.dtype)], -1))  # (B, grasp_dim)
        delta = delta * self.out_scale
        return GraspParams.from_flat(flat + delta, c.n_joints)

    def forward(self, grasp: GraspParams, distance_fn: DistanceFn) -> RefineOutput:
        """Refine ``grasp`` in ``n_iters`` steps, recomputing distances before each.

        The distances are detached: they are observations of the current estimate (as in
        GrabNet, where they come from a mesh query), so any distance function works.
        """
        steps, dists = [], []
        for i in range(self.cfg.n_iters):
            d = distance_fn(grasp).detach()
            grasp = self.step(grasp, d, i)
            steps.append(grasp)
            dists.append(d)
        return RefineOutput(grasp, steps, dists)


# ----------------------------------------------------------------------------- helpers

HandFn = Callable[[GraspParams], torch.Tensor]  # grasp -> vertices (B, V, 3), differentiable
SdfFn = Callable[[torch.Tensor], torch.Tensor]  # points (..., 3) -> signed distance (...)


def make_hand_fn(hand: torch.nn.Module, vertex_ids: np.ndarray | None = None) -> HandFn:
    """Differentiable ``grasp -> vertices (B, V, 3)`` (or ``(B, K, 3)`` at ``vertex_ids``)
    from a hand model with ``forward(global_orient, hand_pose, transl)`` (ProceduralHand)."""

    ids = None if vertex_ids is None else torch.tensor(np.asarray(vertex_ids, dtype=np.int64))

    def fn(grasp: GraspParams) -> torch.Tensor:
        go, pose, transl = grasp.axis_angle()
        verts = hand(go, pose, transl)[0]
        return verts if ids is None else verts[:, ids.to(verts.device)]

    return fn


def make_distance_fn(hand: torch.nn.Module, sdf: SdfFn, vertex_ids: np.ndarray) -> DistanceFn:
    """RefineNet's distance function: signed distances ``(B, K)`` (m) of the grasp's hand
    vertices ``vertex_ids (K,)`` to the object, ``sdf`` e.g. ``DistanceField.signed_distance``
    (object frame = the grasp frame; numpy or torch results are both accepted)."""
    hand_fn = make_hand_fn(hand, vertex_ids)

    def fn(grasp: GraspParams) -> torch.Tensor:
        with torch.no_grad():
            pts = hand_fn(grasp)
        d = sdf(pts)
        return torch.as_tensor(d, dtype=pts.dtype, device=pts.device)

    return fn


class _FieldSDF(torch.autograd.Function):
    """Signed distance with the field's spatial gradient as its derivative."""

    @staticmethod
    def forward(ctx: Any, points: torch.Tensor, field: DistanceField) -> torch.Tensor:
        d = field.signed_distance(points.detach())
        ctx.save_for_backward(field.gradient(points.detach()))
        return d

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, None]:
        (g,) = ctx.saved_tensors
        return grad[..., None] * g, None


def sdf_with_gradient(field: DistanceField) -> SdfFn:
    """Wrap a ``DistanceField`` as a differentiable ``points (..., 3) -> (...)`` for the
    contact and penetration losses (the field itself is not autograd-aware)."""
    return lambda points: _FieldSDF.apply(points, field)


# ----------------------------------------------------------------------------- losses


@dataclass
class GrabNetLossConfig:
    """Loss weights (GRAB gives the terms, not the weights; these are ours).

    The vertex term is in metres, so its weight of 100 reads it in centimetres, on the
    scale of the 6D pose term. GRAB's "weight regulariser" is the optimiser's weight decay.
    The contact and penetration terms (GRAB Sec. 4: "a penetration and a contact loss")
    are in metres too; see :func:`contact_loss` and :func:`penetration_loss`.
    """

    w_vertex: float = 100.0  # L1 on hand vertices
    w_edge: float = 0.0  # L1 on mesh edge vectors (GRAB's data term), needs faces
    w_pose: float = 1.0  # L2 on 6D (orientation and fingers)
    w_transl: float = 100.0  # L2 on wrist translation (m^2 -> weight like cm-ish)
    w_kl: float = 5e-3  # CoarseNet only
    w_contact: float = 0.0  # pull GT-contact vertices onto the surface, needs sdf
    w_penetration: float = 0.0  # push vertices out of the object, needs sdf
    contact_threshold: float = CONTACT_THRESHOLD  # m, GT vertices this close are contacts


def kl_divergence(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(mu, exp(logvar)) || N(0, I)), summed over the latent, mean over the batch."""
    return (-0.5 * (1 + logvar - mu.pow(2) - logvar.exp()).sum(-1)).mean()


def penetration_loss(distances: torch.Tensor) -> torch.Tensor:
    """Penetration term: mean depth (m) of the hand vertices inside the object.

    distances (B, V) signed (m, negative inside); a vertex outside or on the surface adds
    nothing, one at depth ``p`` adds ``p``; the sum over vertices is averaged over ``B * V``.
    The gradient pushes each inside vertex along the outward distance gradient.
    """
    return torch.relu(-distances).mean()


def contact_loss(distances: torch.Tensor, contact: torch.Tensor) -> torch.Tensor:
    """Contact term: mean unsigned distance (m) to the object of the vertices that are in
    contact in the ground truth (``contact (B, V)`` bool); 0 when no vertex is."""
    mask = contact.to(distances.dtype)
    return (distances.abs() * mask).sum() / mask.sum().clamp(min=1)


def losses(
    pred: GraspParams,
    target: GraspParams,
    cfg: GrabNetLossConfig | None = None,
    *,
    hand_fn: HandFn | None = None,
    mu: torch.Tensor | None = None,
    logvar: torch.Tensor | None = None,
    sdf: SdfFn | None = None,
    faces: np.ndarray | None = None,
    gt_contact: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """CoarseNet / RefineNet training loss; returns ``(total, {term: value})``.

    Pose and translation terms always; vertex (and edge) terms when ``hand_fn`` is given;
    KL when ``mu, logvar`` are given (CoarseNet); contact and penetration when ``sdf``
    (differentiable, object frame) and their weights are given. ``gt_contact (B, V)``:
    the ground-truth contact vertices, if known (else ``sdf`` of the target hand within
    ``cfg.contact_threshold``).
    """
    cfg = cfg or GrabNetLossConfig()
    terms = {
        "pose": (pred.global_orient - target.global_orient).pow(2).mean()
        + (pred.hand_pose - target.hand_pose).pow(2).mean(),
        "transl": (pred.transl - target.transl).pow(2).sum(-1).mean(),
    }
    total = cfg.w_pose * terms["pose"] + cfg.w_transl * terms["transl"]
    if hand_fn is not None:
        v_pred = hand_fn(pred)  # (B, V, 3)
        with torch.no_grad():
            v_gt = hand_fn(target)
        terms["vertex"] = (v_pred - v_gt).abs().mean()
        total = total + cfg.w_vertex * terms["vertex"]
        if faces is not None and cfg.w_edge:
            f = torch.tensor(np.asarray(faces, dtype=np.int64), device=v_pred.device)
            e_pred = v_pred[:, f[:, 1]] - v_pred[:, f[:, 0]]
            e_gt = v_gt[:, f[:, 1]] - v_gt[:, f[:, 0]]
            terms["edge"] = (e_pred - e_gt).abs().mean()
            total = total + cfg.w_edge * terms["edge"]
        if sdf is not None and (cfg.w_contact or cfg.w_penetration):
            d_pred = sdf(v_pred)  # (B, V)
            if gt_contact is None:
                with torch.no_grad():
                    gt_contact = sdf(v_gt) < cfg.contact_threshold
            terms["contact"] = contact_loss(d_pred, gt_contact)
            terms["penetration"] = penetration_loss(d_pred)
            total = (
                total + cfg.w_contact * terms["contact"] + cfg.w_penetration * terms["penetration"]
            )
    if mu is not None and logvar is not None:
        terms["kl"] = kl_divergence(mu, logvar)
        total = total + cfg.w_kl * terms["kl"]
    return total, terms
