"""CNet, GRIP's consistency network (GRIP Sec. 3.4, Fig. 4).

Two consecutive frames of body context and hand-sensor features, plus the future
hand-to-object distance cue, go through an encoder that gives the global latent ``z_t``
and a residual ``dz``; ``z_{t+1} = z_t + dz``; one shared decoder maps each latent to
both hands' 15 x 6D poses and the 2 x 99 proximity values of that frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from grip_bench.core.constants import (
    AMBIENT_N_POINTS,
    CNET_BODY_DIM,
    FUTURE_FRAMES,
    GRIP_DROPOUT,
    GRIP_HIDDEN,
    GRIP_LATENT,
    GRIP_WIDTH,
    N_HAND_POSE_JOINTS,
    PROXIMITY_N_VERTS,
    ROT6D_DIM,
)
from grip_bench.core.errors import InputError
from grip_bench.grip.ltc import (
    Latents,
    check_mode,
    decode_frames,
    encoder_decoder,
    n_frames_out,
    split_codes,
)
from grip_bench.nn.blocks import check_config, check_shape

N_HANDS = 2  # left, right (index 0 = left, 1 = right throughout GRIP's networks)


def future_cue_dim(n_future: int) -> int:
    """Size of the future cue: per hand, mean distance and its rate for n frames."""
    return N_HANDS * 2 * n_future


@dataclass
class CNetConfig:
    body_dim: int = CNET_BODY_DIM  # per frame: body pose (no root), wrists, shape
    ambient_dim: int = AMBIENT_N_POINTS  # per hand: exp(-5 d) at the hemisphere points
    proximity_dim: int = PROXIMITY_N_VERTS  # per hand: exp(-50 d) at the 99 hand vertices
    future_dim: int = future_cue_dim(FUTURE_FRAMES)  # 0 for the "no future" ablation
    n_joints: int = N_HAND_POSE_JOINTS
    rot_dim: int = ROT6D_DIM
    hidden: int = GRIP_HIDDEN
    width: int = GRIP_WIDTH
    latent: int = GRIP_LATENT
    n_enc_blocks: int = 2
    n_dec_blocks: int = 2
    dropout: float = GRIP_DROPOUT
    consistency: str = "latent"  # "latent" | "output" | "none" (GRIP Tab. 2)

    def __post_init__(self) -> None:
        check_mode(self.consistency)
        check_config(self, may_be_zero=("future_dim",))

    @property
    def n_frames(self) -> int:
        """Frames seen by the encoder and decoded: 2, or 1 without consistency."""
        return n_frames_out(self.consistency, n_next=1)

    @property
    def frame_dim(self) -> int:
        return self.body_dim + N_HANDS * (self.ambient_dim + self.proximity_dim)

    @property
    def in_dim(self) -> int:
        return self.n_frames * self.frame_dim + self.future_dim

    @property
    def out_dim(self) -> int:
        """Decoder output per frame: both hands' poses, then both hands' proximity."""
        return N_HANDS * (self.n_joints * self.rot_dim + self.proximity_dim)

    def build(self) -> CNet:
        return CNet(self)


@dataclass
class CNetOutput:
    """CNet predictions; the ``*_t1`` fields and ``dz`` are None when not produced."""

    poses_t: torch.Tensor  # (B, 2, J, 6) both hands' finger joint rotations at t
    proximity_t: torch.Tensor  # (B, 2, P) predicted proximity sensor values at t
    z_t: torch.Tensor  # (B, L) global latent of frame t
    poses_t1: torch.Tensor | None = None  # (B, 2, J, 6) at t+1
    proximity_t1: torch.Tensor | None = None  # (B, 2, P) at t+1
    z_t1: torch.Tensor | None = None  # (B, L); = z_t + dz in latent mode
    dz: torch.Tensor | None = None  # (B, L) latent residual (latent mode only)


class CNet(nn.Module):
    """Encoder ``E_C`` + shared decoder ``D_C`` with latent temporal consistency."""

    def __init__(self, cfg: CNetConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder, self.decoder = encoder_decoder(cfg, cfg.out_dim)

    def pack_inputs(
        self,
        body: torch.Tensor,
        ambient: torch.Tensor,
        proximity: torch.Tensor,
        future: torch.Tensor | None,
    ) -> torch.Tensor:
        """Check shapes and concatenate the encoder input ``(B, in_dim)``."""
        c, f = self.cfg, self.cfg.n_frames
        check_shape(body, (None, None, c.body_dim), "CNet body")
        b, n_in = body.shape[:2]
        if n_in not in (f, 2):  # "none" reads frame t of a two-frame sample, or one frame
            raise InputError(f"CNet needs {f} frames (t, t+1), got {n_in}", where="CNet body")
        check_shape(ambient, (b, n_in, N_HANDS, c.ambient_dim), "CNet ambient")
        check_shape(proximity, (b, n_in, N_HANDS, c.proximity_dim), "CNet proximity")
        frames = [body, ambient.flatten(2), proximity.flatten(2)]
        frames = torch.cat(frames, dim=-1)[:, :f]  # (B, f, frame_dim)
        parts = [frames.flatten(1)]  # (B, f * frame_dim)
        if c.future_dim:
            if future is None:
                raise InputError(
                    f"CNet expects a future cue of size {c.future_dim}", where="CNet future"
                )
            check_shape(future, (b, c.future_dim), "CNet future")
            parts.append(future)
        return torch.cat(parts, dim=-1)

    def encode(
        self,
        body: torch.Tensor,
        ambient: torch.Tensor,
        proximity: torch.Tensor,
        future: torch.Tensor | None = None,
    ) -> Latents:
        """Per-frame latents ``z (B, F, L)`` of the inputs of :meth:`forward`."""
        codes = self.encoder(self.pack_inputs(body, ambient, proximity, future))  # (B, F*L)
        return split_codes(codes, self.cfg.latent, self.cfg.consistency)

    def decode(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Shared decoder: latents ``(..., L)`` -> poses ``(..., 2, J, 6)``, proximity
        ``(..., 2, P)``.

        Inference decodes only the latents it keeps (offline: z_t of every pair)."""
        c = self.cfg
        out = decode_frames(self.decoder, z)  # (..., out_dim)
        n_pose = N_HANDS * c.n_joints * c.rot_dim
        poses = out[..., :n_pose].unflatten(-1, (N_HANDS, c.n_joints, c.rot_dim))
        return poses, out[..., n_pose:].unflatten(-1, (N_HANDS, c.proximity_dim))

    def forward(
        self,
        body: torch.Tensor,
        ambient: torch.Tensor,
        proximity: torch.Tensor,
        future: torch.Tensor | None = None,
    ) -> CNetOutput:
        """Predict both hands' poses for frames t and t+1.

        body (B, F, body_dim), ambient (B, F, 2, ambient_dim), proximity (B, F, 2, proximity_dim)
        with F = 2 frames (t, t+1; F >= 1 when ``consistency == "none"``, which uses frame t
        only); future (B, future_dim) or None when ``future_dim == 0``. Hands: 0 left, 1 right.
        """
        c = self.cfg
        lat = self.encode(body, ambient, proximity, future)  # z (B, F, L)
        poses, prox = self.decode(lat.z)  # (B, F, 2, J, 6), (B, F, 2, P)
        result = CNetOutput(poses_t=poses[:, 0], proximity_t=prox[:, 0], z_t=lat.z[:, 0])
        if c.n_frames == 2:
            result.poses_t1, result.proximity_t1, result.z_t1 = poses[:, 1], prox[:, 1], lat.z[:, 1]
            result.dz = None if lat.dz is None else lat.dz[:, 0]
        return result
