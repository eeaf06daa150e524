"""RNet, GRIP's refinement network (GRIP Sec. 3.6, Sup. Mat. 8, Fig. S.9).

Per frame: both hands' poses from CNet plus the proximity sensor recomputed on those
hands (and optionally an ambient summary) -> a residual on the input poses. The head is
zero-initialised, so an untrained RNet is the identity, and an interaction mask gates
the residual so that frames away from the object pass through bit-for-bit unchanged
(the paper trains RNet to refine interaction frames only).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from grip_bench.core.constants import (
    GRIP_DROPOUT,
    GRIP_WIDTH,
    N_HAND_POSE_JOINTS,
    PROXIMITY_N_VERTS,
    ROT6D_DIM,
)
from grip_bench.core.errors import InputError
from grip_bench.nn.blocks import ResMLP, check_config, check_shape

N_HANDS = 2


@dataclass
class RNetConfig:
    n_joints: int = N_HAND_POSE_JOINTS
    rot_dim: int = ROT6D_DIM
    proximity_dim: int = PROXIMITY_N_VERTS  # per hand, recomputed on CNet's hands
    ambient_dim: int = 0  # optional ambient summary per frame (Fig. S.9 has none)
    hidden: int = GRIP_WIDTH
    width: int = GRIP_WIDTH
    n_blocks: int = 4  # Sup. Mat. 8 (the main text says 3)
    dropout: float = GRIP_DROPOUT
    zero_init_head: bool = True

    def __post_init__(self) -> None:
        check_config(self, may_be_zero=("ambient_dim",))

    @property
    def pose_dim(self) -> int:
        return N_HANDS * self.n_joints * self.rot_dim

    @property
    def in_dim(self) -> int:
        return self.pose_dim + N_HANDS * self.proximity_dim + self.ambient_dim

    def build(self) -> RNet:
        return RNet(self)


def gate(mask: torch.Tensor, lead: torch.Size) -> torch.Tensor:
    """Interaction mask ``(...)`` (per frame) or ``(..., 2)`` (per hand) -> ``(..., 2, 1, 1)``."""
    if mask.shape == lead:
        mask = mask.unsqueeze(-1).expand(*lead, N_HANDS)
    check_shape(mask, (*lead, N_HANDS), "RNet mask")
    return mask[..., None, None]


class RNet(nn.Module):
    """Residual MLP predicting a pose correction, gated by the interaction mask."""

    def __init__(self, cfg: RNetConfig):
        super().__init__()
        self.cfg = cfg
        self.net = ResMLP(
            cfg.in_dim,
            cfg.pose_dim,
            width=cfg.width,
            hidden=cfg.hidden,
            n_blocks=cfg.n_blocks,
            dropout=cfg.dropout,
        )
        if cfg.zero_init_head:
            # Start from "change nothing": training then only has to learn corrections.
            nn.init.zeros_(self.net.head.weight)
            nn.init.zeros_(self.net.head.bias)

    def pack_inputs(
        self, poses: torch.Tensor, proximity: torch.Tensor, ambient: torch.Tensor | None
    ) -> torch.Tensor:
        """Check shapes and concatenate ``(..., in_dim)``."""
        c = self.cfg
        check_shape(
            poses, (*[None] * (poses.ndim - 3), N_HANDS, c.n_joints, c.rot_dim), "RNet poses"
        )
        lead = poses.shape[:-3]
        check_shape(proximity, (*lead, N_HANDS, c.proximity_dim), "RNet proximity")
        parts = [poses.flatten(-3), proximity.flatten(-2)]
        if c.ambient_dim:
            if ambient is None:
                raise InputError(
                    f"RNet expects an ambient summary of size {c.ambient_dim}", where="RNet ambient"
                )
            check_shape(ambient, (*lead, c.ambient_dim), "RNet ambient")
            parts.append(ambient)
        return torch.cat(parts, dim=-1)

    def forward(
        self,
        poses: torch.Tensor,
        proximity: torch.Tensor,
        ambient: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Refine hand poses.

        poses (..., 2, J, 6); proximity (..., 2, P); ambient (..., ambient_dim) or None;
        mask (...) or (..., 2), bool (refine where True) or float in [0, 1] (blend), None =
        refine all. Leading dims (batch, time) are flattened for BatchNorm. Returns (..., 2, J, 6).
        """
        c = self.cfg
        delta = self.net(self.pack_inputs(poses, proximity, ambient))  # (..., 2*J*6)
        delta = delta.unflatten(-1, (N_HANDS, c.n_joints, c.rot_dim))  # (..., 2, J, 6)
        if mask is None:
            return poses + delta
        g = gate(mask, poses.shape[:-3])
        if g.dtype == torch.bool:
            return torch.where(g, poses + delta, poses)  # exact pass-through where False
        return poses + g.to(delta.dtype) * delta
