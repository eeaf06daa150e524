"""Analytic multiply-add counts of GRIP's networks, from their configs.

Only Linear layers are counted: in eval mode BatchNorm folds into the preceding Linear
and activations are O(width), so this is the compute floor a runtime cannot beat.
"One frame" is one forward call of a network (CNet's call decodes t and t+1; both decodes
are counted). The inference pipeline decodes only the latent each output frame keeps and
runs RNet only on interaction frames: :func:`pipeline_flops_per_frame` counts that.
"""

from __future__ import annotations

from collections.abc import Iterable

from grip_bench.grip.anet import ANetConfig
from grip_bench.grip.cnet import CNetConfig
from grip_bench.grip.rnet import RNetConfig


def resmlp_macs(d_in: int, d_out: int, *, width: int, hidden: int, n_blocks: int) -> int:
    """Multiply-adds of one ``ResMLP`` row (one sample through blocks and head)."""
    dims = [d_in] + [width] * n_blocks
    macs = 0
    for a, b in zip(dims[:-1], dims[1:], strict=True):
        macs += a * hidden + hidden * b + (a * b if a != b else 0)  # fc1, fc2, skip projection
    return macs + width * d_out  # head


def cnet_macs(cfg: CNetConfig) -> int:
    """One CNet call: the encoder once, the shared decoder once per decoded frame."""
    enc = resmlp_macs(
        cfg.in_dim,
        cfg.n_frames * cfg.latent,
        width=cfg.width,
        hidden=cfg.hidden,
        n_blocks=cfg.n_enc_blocks,
    )
    dec = resmlp_macs(
        cfg.latent, cfg.out_dim, width=cfg.width, hidden=cfg.hidden, n_blocks=cfg.n_dec_blocks
    )
    return enc + cfg.n_frames * dec


def cnet_decoder_macs(cfg: CNetConfig) -> int:
    """One decode of one frame's latent by CNet's shared decoder."""
    return resmlp_macs(cfg.latent, cfg.out_dim, width=cfg.width, hidden=cfg.hidden,
                       n_blocks=cfg.n_dec_blocks)


def anet_decoder_macs(cfg: ANetConfig) -> int:
    """One decode of one frame's latent by ANet's shared decoder."""
    return resmlp_macs(cfg.latent, cfg.pose_dim, width=cfg.width, hidden=cfg.hidden,
                       n_blocks=cfg.n_dec_blocks)


def anet_macs(cfg: ANetConfig) -> int:
    """One ANet call: the encoder once, the shared decoder once per decoded frame."""
    enc = resmlp_macs(
        cfg.in_dim,
        cfg.n_frames * cfg.latent,
        width=cfg.width,
        hidden=cfg.hidden,
        n_blocks=cfg.n_enc_blocks,
    )
    dec = resmlp_macs(
        cfg.latent, cfg.pose_dim, width=cfg.width, hidden=cfg.hidden, n_blocks=cfg.n_dec_blocks
    )
    return enc + cfg.n_frames * dec


def rnet_macs(cfg: RNetConfig) -> int:
    """One RNet call (one frame, both hands)."""
    return resmlp_macs(
        cfg.in_dim, cfg.pose_dim, width=cfg.width, hidden=cfg.hidden, n_blocks=cfg.n_blocks
    )


_COUNTERS = {CNetConfig: cnet_macs, ANetConfig: anet_macs, RNetConfig: rnet_macs}


def macs_per_frame(cfg: CNetConfig | ANetConfig | RNetConfig) -> int:
    """Multiply-adds of one forward call of the network described by ``cfg``."""
    try:
        return _COUNTERS[type(cfg)](cfg)
    except KeyError:
        raise TypeError(f"no MAC counter for {type(cfg).__name__}") from None


def flops_per_frame(cfg: CNetConfig | ANetConfig | RNetConfig) -> int:
    """FLOPs of one forward call (a multiply-add is two FLOPs)."""
    return 2 * macs_per_frame(cfg)


def pipeline_flops_parts(cnet: CNetConfig, anet: ANetConfig, rnet: RNetConfig,
                         interaction_share: float = 1.0) -> dict[str, float]:
    """FLOPs per output frame of each network of the offline pipeline (``anet``, ``cnet``,
    ``rnet``): CNet's encoder and one decode, ANet's encoder and one decode (frame t+1),
    RNet on a share ``interaction_share`` of the frames."""
    cnet_once = cnet_macs(cnet) - (cnet.n_frames - 1) * cnet_decoder_macs(cnet)
    anet_once = anet_macs(anet) - (anet.n_frames - 1) * anet_decoder_macs(anet)
    return {"anet": 2.0 * anet_once, "cnet": 2.0 * cnet_once,
            "rnet": 2.0 * interaction_share * rnet_macs(rnet)}


def pipeline_flops_per_frame(cnet: CNetConfig, anet: ANetConfig, rnet: RNetConfig,
                             interaction_share: float = 1.0) -> float:
    """FLOPs per output frame of the offline pipeline, all networks
    (:func:`pipeline_flops_parts`)."""
    parts = pipeline_flops_parts(cnet, anet, rnet, interaction_share)
    return parts["cnet"] + parts["anet"] + parts["rnet"]  # 2 (c + a + r) exactly: x2 is exact


def runtime_floor(cfgs: Iterable, flops_per_second: float) -> float:
    """Lower bound on seconds per frame for running every network in ``cfgs`` once per
    frame on a device sustaining ``flops_per_second`` (e.g. a measured GEMM rate)."""
    if flops_per_second <= 0:
        raise ValueError(f"flops_per_second must be positive, got {flops_per_second!r}")
    return sum(flops_per_frame(c) for c in cfgs) / flops_per_second
