"""GRIP's networks (GRIP Sec. 3.4-3.6): ANet, CNet, RNet, one file each, plus losses and FLOPs."""

from grip_bench.grip.anet import ANet, ANetConfig, ANetOutput
from grip_bench.grip.cnet import CNet, CNetConfig, CNetOutput
from grip_bench.grip.flops import flops_per_frame, macs_per_frame, runtime_floor
from grip_bench.grip.losses import LossConfig
from grip_bench.grip.ltc import CONSISTENCY_MODES
from grip_bench.grip.rnet import RNet, RNetConfig

__all__ = [
    "ANet",
    "ANetConfig",
    "ANetOutput",
    "CNet",
    "CNetConfig",
    "CNetOutput",
    "CONSISTENCY_MODES",
    "LossConfig",
    "RNet",
    "RNetConfig",
    "flops_per_frame",
    "macs_per_frame",
    "runtime_floor",
]
