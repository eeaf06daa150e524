"""ANet, GRIP's arm denoising network (GRIP Sec. 3.5, Sup. Mat. 7, Fig. S.8).

Input: both arms (shoulders, elbows; 6D) at the current frame t plus 5 noisy future
frames, optionally with extra per-sample context (e.g. hand-sensor features of frame t).
Output: denoised arms for frames t .. t+n_next, with the same latent temporal
consistency as CNet (``grip_bench.grip.ltc``): ``z_{t+k} = z_t + dz_k``, one decoder.
The paper decodes the five future frames (``n_next=5``); the suite's default pipeline
uses t and t+1 (``n_next=1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from grip_bench.core.constants import (
    ANET_NOISY_FUTURE,
    GRIP_DROPOUT,
    GRIP_LATENT,
    N_ARM_JOINTS,
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


@dataclass
class ANetConfig:
    n_joints: int = N_ARM_JOINTS  # left/right shoulder, left/right elbow
    rot_dim: int = ROT6D_DIM
    n_future: int = ANET_NOISY_FUTURE  # noisy future frames in
    n_next: int = 1  # frames decoded after t (paper: 5)
    context_dim: int = 0  # optional extra features of frame t
    # Widths are not given in the paper; arms are a 24-number signal, so ANet is kept
    # narrower than CNet. Sup. Mat. 7: encoder and decoder have 4 residual layers each.
    hidden: int = 1024
    width: int = 512
    latent: int = GRIP_LATENT
    n_enc_blocks: int = 4
    n_dec_blocks: int = 4
    dropout: float = GRIP_DROPOUT
    consistency: str = "latent"  # "latent" | "output" | "none"
    # Feed the noisy future frames as differences from the current frame. The correction is
    # a small difference of nearly equal poses, which a network reading absolute 6D poses
    # learned only slowly (an ANet trained the profile's way stayed at the zero correction);
    # False keeps the absolute input of checkpoints written before this field existed.
    relative_future: bool = False

    def __post_init__(self) -> None:
        check_mode(self.consistency)
        check_config(self, may_be_zero=("context_dim",))
        if self.n_next > self.n_future:
            raise ValueError(f"ANetConfig.n_next={self.n_next} exceeds n_future={self.n_future}")

    @property
    def n_frames(self) -> int:
        """Frames decoded: t .. t+n_next, or t alone without consistency."""
        return n_frames_out(self.consistency, self.n_next)

    @property
    def pose_dim(self) -> int:
        return self.n_joints * self.rot_dim

    @property
    def in_dim(self) -> int:
        return (1 + self.n_future) * self.pose_dim + self.context_dim

    def build(self) -> ANet:
        return ANet(self)


@dataclass
class ANetOutput:
    arms: torch.Tensor  # (B, F, J, 6) denoised arms for frames t .. t+F-1
    z: torch.Tensor  # (B, F, L) per-frame global latents
    dz: torch.Tensor | None  # (B, F-1, L) latent residuals (latent mode only)

    @property
    def arms_t(self) -> torch.Tensor:
        return self.arms[:, 0]  # (B, J, 6)

    @property
    def arms_t1(self) -> torch.Tensor | None:
        return self.arms[:, 1] if self.arms.shape[1] > 1 else None  # (B, J, 6)


class ANet(nn.Module):
    """Encoder ``E_A`` + shared decoder ``D_A`` with latent temporal consistency."""

    def __init__(self, cfg: ANetConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder, self.decoder = encoder_decoder(cfg, cfg.pose_dim)

    def pack_inputs(
        self, current: torch.Tensor, noisy_future: torch.Tensor, context: torch.Tensor | None
    ) -> torch.Tensor:
        """Check shapes and concatenate the encoder input ``(B, in_dim)``."""
        c = self.cfg
        check_shape(current, (None, c.n_joints, c.rot_dim), "ANet current")
        b = current.shape[0]
        check_shape(noisy_future, (b, c.n_future, c.n_joints, c.rot_dim), "ANet noisy_future")
        if c.relative_future:
            noisy_future = noisy_future - current[:, None]
        parts = [current.flatten(1), noisy_future.flatten(1)]
        if c.context_dim:
            if context is None:
                raise InputError(
                    f"ANet expects context of size {c.context_dim}", where="ANet context"
                )
            check_shape(context, (b, c.context_dim), "ANet context")
            parts.append(context)
        return torch.cat(parts, dim=-1)

    def forward(
        self,
        current: torch.Tensor,
        noisy_future: torch.Tensor,
        context: torch.Tensor | None = None,
    ) -> ANetOutput:
        """Denoise the arms.

        current (B, J, 6) arms at t; noisy_future (B, n_future, J, 6) arms at t+1..t+n_future;
        context (B, context_dim) or None. Returns arms (B, F, J, 6), F = cfg.n_frames.
        """
        lat = self.encode(current, noisy_future, context)  # z (B, F, L)
        return ANetOutput(arms=self.decode(lat.z), z=lat.z, dz=lat.dz)

    def encode(
        self,
        current: torch.Tensor,
        noisy_future: torch.Tensor,
        context: torch.Tensor | None = None,
    ) -> Latents:
        """Per-frame latents ``z (B, F, L)`` of the inputs of :meth:`forward`."""
        codes = self.encoder(self.pack_inputs(current, noisy_future, context))  # (B, F*L)
        return split_codes(codes, self.cfg.latent, self.cfg.consistency)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Shared decoder: latents ``(..., L)`` -> arms ``(..., J, 6)``."""
        return decode_frames(self.decoder, z).unflatten(-1, (self.cfg.n_joints, self.cfg.rot_dim))
