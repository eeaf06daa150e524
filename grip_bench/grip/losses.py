"""Training losses of GRIP's networks (GRIP Eq. 4 plus the consistency terms).

``L = w_v L_v + w_p L_hP + w_theta L_theta (+ consistency)``: vertex L1 through a
differentiable hand model passed in by the caller, pose L2 (6D or rotation matrices),
proximity L1. The paper gives no weights; the defaults below are ours (all 1, the
latent residual penalty small so it regularises without collapsing the motion).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from grip_bench.grip.ltc import check_mode
from grip_bench.nn.terms import proximity_l1

if TYPE_CHECKING:
    from grip_bench.grip.anet import ANetOutput
    from grip_bench.grip.cnet import CNetOutput

HandFn = Callable[[torch.Tensor], torch.Tensor]  # poses (..., 2, J, 6) -> vertices (..., 2, V, 3)


@dataclass
class LossConfig:
    w_vertex: float = 1.0
    w_pose: float = 1.0
    w_proximity: float = 1.0
    w_output_consistency: float = 1.0  # "output" variant: match the GT frame-to-frame change
    w_latent: float = 1e-3  # "latent" variant: keep dz small (a smooth latent path)
    pose_space: str = "6d"  # "6d" | "matrix"

    def __post_init__(self) -> None:
        if self.pose_space not in ("6d", "matrix"):
            raise ValueError(
                f"LossConfig.pose_space must be '6d' or 'matrix', got {self.pose_space!r}"
            )


def vertex_l1(pred_poses: torch.Tensor, gt_poses: torch.Tensor, hand_fn: HandFn) -> torch.Tensor:
    """Mean absolute vertex error (m) of the hands posed by ``hand_fn``.

    pred_poses, gt_poses (..., 2, J, 6); ``hand_fn`` must be differentiable in the poses.
    """
    with torch.no_grad():
        gt_vertices = hand_fn(gt_poses)
    return (hand_fn(pred_poses) - gt_vertices).abs().mean()


def pose_l2(pred: torch.Tensor, gt: torch.Tensor, space: str = "6d") -> torch.Tensor:
    """Mean squared rotation error; pred, gt (..., 6). ``space="matrix"`` compares the
    Gram-Schmidt rotation matrices, which ignores the unused freedom of raw 6D vectors."""
    if space == "matrix":
        from grip_bench.geometry.rotations import rotation_6d_to_matrix

        pred, gt = rotation_6d_to_matrix(pred), rotation_6d_to_matrix(gt)
    return (pred - gt).pow(2).mean()


def output_consistency(
    pred_t: torch.Tensor,
    pred_t1: torch.Tensor,
    gt_t: torch.Tensor | None = None,
    gt_t1: torch.Tensor | None = None,
) -> torch.Tensor:
    """Output-space consistency: L1 between predicted and GT frame-to-frame changes.

    Without GT it penalises the raw change ``pred_t1 - pred_t`` (a smoothness prior).
    """
    change = pred_t1 - pred_t
    if gt_t is not None:
        change = change - (gt_t1 - gt_t)
    return change.abs().mean()


def latent_residual(dz: torch.Tensor) -> torch.Tensor:
    """LTC regulariser: mean squared latent residual ``dz (..., L)``."""
    return dz.pow(2).sum(-1).mean()


def cnet_loss(
    out: CNetOutput,
    target: dict,
    cfg: LossConfig,
    consistency: str,
    hand_fn: HandFn | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """CNet loss over the frames it produced; returns ``(total, {term: value})``.

    ``out`` is a ``CNetOutput``; ``target`` holds ``poses_t``/``poses_t1`` (B, 2, J, 6) and
    ``proximity_t``/``proximity_t1`` (B, 2, P). The vertex term needs ``hand_fn``.
    """
    frames = ("t",) if check_mode(consistency) == "none" else ("t", "t1")
    pred_p = torch.stack([getattr(out, f"poses_{f}") for f in frames], 1)  # (B, F, 2, J, 6)
    gt_p = torch.stack([target[f"poses_{f}"] for f in frames], 1)
    pred_h = torch.stack([getattr(out, f"proximity_{f}") for f in frames], 1)  # (B, F, 2, P)
    gt_h = torch.stack([target[f"proximity_{f}"] for f in frames], 1)
    terms = {"pose": pose_l2(pred_p, gt_p, cfg.pose_space), "proximity": proximity_l1(pred_h, gt_h)}
    weights = {"pose": cfg.w_pose, "proximity": cfg.w_proximity}
    if hand_fn is not None:
        terms["vertex"], weights["vertex"] = vertex_l1(pred_p, gt_p, hand_fn), cfg.w_vertex
    terms.update(_consistency_terms(consistency, out.dz, pred_p, gt_p))
    weights.update(latent=cfg.w_latent, output_consistency=cfg.w_output_consistency)
    return _total(terms, weights), terms


def anet_loss(
    out: ANetOutput, target_arms: torch.Tensor, cfg: LossConfig, consistency: str
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """ANet loss; ``out`` an ``ANetOutput``, ``target_arms (B, F, J, 6)`` for its frames."""
    terms = {"pose": pose_l2(out.arms, target_arms, cfg.pose_space)}
    terms.update(_consistency_terms(consistency, out.dz, out.arms, target_arms))
    weights = dict(
        pose=cfg.w_pose, latent=cfg.w_latent, output_consistency=cfg.w_output_consistency
    )
    return _total(terms, weights), terms


def rnet_loss(
    refined: torch.Tensor,
    gt_poses: torch.Tensor,
    cfg: LossConfig,
    hand_fn: HandFn | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """RNet loss on refined poses ``(..., 2, J, 6)``: pose L2 (+ vertex L1 with ``hand_fn``).

    A proximity term on the refined hands needs the object's distance field; callers that
    have one add ``cfg.w_proximity * proximity_l1(...)`` themselves.
    """
    terms = {"pose": pose_l2(refined, gt_poses, cfg.pose_space)}
    weights = {"pose": cfg.w_pose, "vertex": cfg.w_vertex}
    if hand_fn is not None:
        terms["vertex"] = vertex_l1(refined, gt_poses, hand_fn)
    return _total(terms, weights), terms


def _consistency_terms(
    consistency: str, dz: torch.Tensor | None, pred: torch.Tensor, gt: torch.Tensor
) -> dict:
    """The variant's consistency term; pred, gt (B, F, ...) with frames on dim 1."""
    if check_mode(consistency) == "latent" and dz is not None:
        return {"latent": latent_residual(dz)}
    if consistency == "output" and pred.shape[1] > 1:
        return {
            "output_consistency": output_consistency(
                pred[:, :-1], pred[:, 1:], gt[:, :-1], gt[:, 1:]
            )
        }
    return {}


def _total(terms: dict, weights: dict) -> torch.Tensor:
    return sum(weights[k] * v for k, v in terms.items())
