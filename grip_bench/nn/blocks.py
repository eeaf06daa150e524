"""Residual MLP building blocks shared by GRIP's networks (ANet, CNet, RNet).

A residual block is Linear-BN-LeakyReLU-Dropout-Linear-BN plus a skip, then LeakyReLU
(docs/contract.md, "Definitions", networks). BatchNorm1d normalises over (N, C), so every
module here accepts ``(..., C)`` and flattens the leading dimensions (batch x time) into N.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import torch
from torch import nn

from grip_bench.core.constants import GRIP_DROPOUT, GRIP_LEAKY_SLOPE
from grip_bench.core.errors import InputError


def flat_apply(fn: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor) -> torch.Tensor:
    """Apply ``fn`` on ``(N, C)`` to ``x (..., C)``; returns ``(..., C_out)``."""
    lead = x.shape[:-1]
    y = fn(x.reshape(-1, x.shape[-1]))  # (N, C_out)
    return y.reshape(*lead, y.shape[-1])


def check_shape(x: torch.Tensor, shape: tuple, name: str) -> None:
    """Raise ``InputError`` unless ``x.shape`` matches ``shape`` (None = any size)."""
    ok = x.ndim == len(shape) and all(
        s is None or s == d for s, d in zip(shape, x.shape, strict=True)
    )
    if not ok:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"expected shape {want}, got {tuple(x.shape)}", where=name)


def check_config(cfg: Any, may_be_zero: tuple[str, ...] = ()) -> None:
    """Validate a network config: int fields >= 1 (or >= 0 if named), dropout in [0, 1)."""
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if f.name == "dropout":
            if not (isinstance(value, float | int) and 0.0 <= value < 1.0):
                raise ValueError(f"{type(cfg).__name__}.dropout must be in [0, 1), got {value!r}")
        elif f.type in ("int", int):
            low = 0 if f.name in may_be_zero else 1
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(
                    f"{type(cfg).__name__}.{f.name} must be an int >= {low}, got {value!r}"
                )


class ResBlock(nn.Module):
    """``(N, d_in) -> (N, d_out)`` residual block with a ``d_hidden`` bottleneck.

    The skip is the identity when ``d_in == d_out`` and a bias-free Linear otherwise.
    """

    def __init__(self, d_in: int, d_out: int, d_hidden: int, dropout: float = GRIP_DROPOUT):
        super().__init__()
        # Biases before BatchNorm are redundant (BN re-centres), so they are left out.
        self.fc1 = nn.Linear(d_in, d_hidden, bias=False)
        self.bn1 = nn.BatchNorm1d(d_hidden)
        self.fc2 = nn.Linear(d_hidden, d_out, bias=False)
        self.bn2 = nn.BatchNorm1d(d_out)
        self.act = nn.LeakyReLU(GRIP_LEAKY_SLOPE)
        self.drop = nn.Dropout(dropout)
        self.skip = nn.Identity() if d_in == d_out else nn.Linear(d_in, d_out, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.drop(self.act(self.bn1(self.fc1(x))))  # (N, d_hidden)
        h = self.bn2(self.fc2(h))  # (N, d_out)
        return self.act(h + self.skip(x))


class ResMLP(nn.Module):
    """Encoder/decoder: optional input BN, ``n_blocks`` residual blocks, a Linear head.

    ``(..., d_in) -> (..., d_out)``. Blocks map ``d_in -> width -> ... -> width``, each
    with a ``hidden``-wide bottleneck; the head is ``Linear(width, d_out)``.
    """

    def __init__(
        self,
        d_in: int,
        d_out: int,
        *,
        width: int,
        hidden: int,
        n_blocks: int,
        dropout: float = GRIP_DROPOUT,
        input_norm: bool = True,
    ):
        super().__init__()
        if min(d_in, d_out, width, hidden) < 1 or n_blocks < 1:
            raise ValueError(
                f"ResMLP sizes must be positive: d_in={d_in} d_out={d_out} "
                f"width={width} hidden={hidden} n_blocks={n_blocks}"
            )
        # Sensor features (exp(-w d) in [0, 1]) and 6D poses live on different scales;
        # a BN on the raw input puts them on one footing without hand-tuned scaling.
        self.norm = nn.BatchNorm1d(d_in) if input_norm else nn.Identity()
        dims = [d_in] + [width] * n_blocks
        self.blocks = nn.Sequential(
            *(ResBlock(a, b, hidden, dropout) for a, b in zip(dims[:-1], dims[1:], strict=True))
        )
        self.head = nn.Linear(width, d_out)

    def trunk(self, x: torch.Tensor) -> torch.Tensor:
        """``(N, d_in) -> (N, width)`` features before the head."""
        return self.blocks(self.norm(x))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return flat_apply(lambda n: self.head(self.trunk(n)), x)
