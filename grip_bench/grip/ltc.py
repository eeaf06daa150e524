"""Latent temporal consistency (LTC, GRIP Sec. 3.4), shared by CNet and ANet.

The encoder emits one code per decoded frame. How those codes become per-frame latents
is the only thing the consistency variant changes (GRIP Tab. 2 ablation):

- ``"latent"``: code 0 is the global latent ``z_t``; codes 1..K are residuals and
  ``z_{t+k} = z_t + dz_k``. Every latent goes through the same decoder.
- ``"output"``: the K+1 codes are independent global latents, decoded by the same
  decoder; consistency comes only from a loss on the output difference.
- ``"none"``: a single frame, one latent, no consistency term.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from ..nn.blocks import ResMLP
    from .anet import ANetConfig
    from .cnet import CNetConfig

CONSISTENCY_MODES = ("latent", "output", "none")


def check_mode(mode: str) -> str:
    """Return ``mode`` or raise ``ValueError`` naming the allowed ones."""
    if mode not in CONSISTENCY_MODES:
        raise ValueError(f"consistency must be one of {CONSISTENCY_MODES}, got {mode!r}")
    return mode


def n_frames_out(mode: str, n_next: int) -> int:
    """Frames decoded per sample: t plus ``n_next`` following ones, or t alone for none."""
    return 1 if check_mode(mode) == "none" else 1 + n_next


@dataclass
class Latents:
    """Per-frame latents. ``z (B, F, L)``; ``dz (B, F-1, L)`` in latent mode, else None."""

    z: torch.Tensor
    dz: torch.Tensor | None


def split_codes(codes: torch.Tensor, latent: int, mode: str) -> Latents:
    """Encoder output ``(B, F*latent) -> Latents`` following the consistency mode."""
    z = codes.reshape(codes.shape[0], -1, latent)  # (B, F, L)
    if check_mode(mode) != "latent":
        return Latents(z=z, dz=None)
    z_t, dz = z[:, :1], z[:, 1:]  # (B, 1, L), (B, F-1, L)
    # Broadcast add: the later frames are *defined* relative to z_t, so the decoder sees
    # them as small moves in latent space rather than unrelated codes.
    return Latents(z=torch.cat([z_t, z_t + dz], dim=1), dz=dz)


def decode_frames(decoder: torch.nn.Module, z: torch.Tensor) -> torch.Tensor:
    """Decode every frame's latent with ONE decoder: ``(B, F, L) -> (B, F, d_out)``.

    Stacking the frames into one batch guarantees one set of parameters for all frames
    (the "shared decoder" of LTC) and costs one matmul per layer instead of F.
    """
    return decoder(z)


def encoder_decoder(cfg: ANetConfig | CNetConfig, out_dim: int) -> tuple[ResMLP, ResMLP]:
    """The LTC pair: an encoder to ``cfg.n_frames`` latents and ONE decoder shared by all frames.

    ``cfg`` provides in_dim, latent, n_frames, width, hidden, dropout, n_enc_blocks and
    n_dec_blocks (CNetConfig and ANetConfig do). Returns ``(encoder, decoder)``.
    """
    from ..nn.blocks import ResMLP

    block = dict(width=cfg.width, hidden=cfg.hidden, dropout=cfg.dropout)
    encoder = ResMLP(cfg.in_dim, cfg.n_frames * cfg.latent, n_blocks=cfg.n_enc_blocks, **block)
    # The latent is the encoder head's output, already on a learned scale: no input BN.
    decoder = ResMLP(cfg.latent, out_dim, n_blocks=cfg.n_dec_blocks, input_norm=False, **block)
    return encoder, decoder
