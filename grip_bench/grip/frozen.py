"""Inference form of GRIP's networks: BatchNorm folded into the Linear layers, one GEMM per
block input, weights in float32 or bfloat16.

In eval mode a ``ResBlock`` is ``act(bn2(W2 act(bn1(W1 x))) + S x)``. BatchNorm is then an
affine map per channel, so ``bn(W x) = (s * W) x + t`` with ``s = gamma / sqrt(var + eps)``
and ``t = beta - mean * s``: the block needs two biased GEMMs and no normalisation pass.
``W1`` and the skip projection ``S`` read the same input, so they are stacked into one GEMM.

``freeze(net)`` returns a copy of a CNet, ANet or RNet whose every :class:`ResMLP` is a
:class:`FrozenMLP`; the network's own ``forward``/``encode``/``decode`` run unchanged on it.
In float32 it equals the eval-mode network up to float rounding (tested); bfloat16 runs the
GEMMs ~4x faster on CPUs with AVX512-BF16 at ~3 significant digits (``grip-bench predict
--precision``; the benchmark reports both). Inputs and outputs stay float32.
"""

from __future__ import annotations

import copy
import weakref

import torch
from torch import nn
from torch.nn import functional as F

from ..core.cpu import CpuInfo, cpu_info
from ..nn.blocks import ResBlock, ResMLP

PRECISIONS = {"fp32": torch.float32, "bf16": torch.bfloat16}
PRECISION_CHOICES = ("auto", *PRECISIONS)


def native_bf16(device: str = "cpu", cpu: CpuInfo | None = None) -> bool:
    """Whether ``device`` runs bfloat16 GEMMs in hardware (CPU: AVX512-BF16, AMX-BF16 or
    Arm BF16, from ``cpu`` or this machine's :func:`core.cpu.cpu_info`; CUDA: torch's
    ``is_bf16_supported``)."""
    if str(device).startswith("cuda"):
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    return (cpu or cpu_info()).native_bf16


def resolve_precision(requested: str, device: str = "cpu",
                      cpu: CpuInfo | None = None) -> tuple[str, str | None]:
    """(precision to run, a warning or None) for ``--precision`` ``requested``.

    ``auto`` picks bf16 where the hardware runs it natively and fp32 elsewhere (emulated
    bf16 GEMMs are ~4x slower than fp32). An explicit ``bf16`` is honoured, with a warning
    when it is emulated; ``fp32`` is always honoured.
    """
    if requested not in PRECISION_CHOICES:
        raise ValueError(f"precision must be one of {PRECISION_CHOICES}, got {requested!r}")
    native = native_bf16(device, cpu)
    if requested == "auto":
        return ("bf16" if native else "fp32"), None
    if requested == "bf16" and not native:
        where = "this GPU" if str(device).startswith("cuda") else \
            f"this CPU ({(cpu or cpu_info()).model})"
        return "bf16", (f"bf16 is emulated on {where}: expect it slower than fp32 "
                        "(--precision auto picks fp32 here)")
    return requested, None


def _bn_affine(bn: nn.BatchNorm1d) -> tuple[torch.Tensor, torch.Tensor]:
    """Eval-mode BatchNorm as ``x * scale + shift`` ``((C,), (C,))``, in float64."""
    scale = bn.weight.double() / torch.sqrt(bn.running_var.double() + bn.eps)
    return scale, bn.bias.double() - bn.running_mean.double() * scale


def _folded(linear: nn.Linear, bn: nn.BatchNorm1d) -> tuple[torch.Tensor, torch.Tensor]:
    """``bn(linear(x))`` as one ``(weight (out, in), bias (out,))`` in float64."""
    scale, shift = _bn_affine(bn)
    bias = shift if linear.bias is None else linear.bias.double() * scale + shift
    return linear.weight.double() * scale[:, None], bias


class FrozenMLP(nn.Module):
    """A :class:`ResMLP` in inference form: ``(..., d_in) -> (..., d_out)`` float32."""

    def __init__(self, mlp: ResMLP, dtype: torch.dtype = torch.float32):
        super().__init__()
        self.dtype, self.slope = dtype, mlp.blocks[0].act.negative_slope
        if isinstance(mlp.norm, nn.BatchNorm1d):
            scale, shift = _bn_affine(mlp.norm)
            self.register_buffer("in_scale", scale.float())
            self.register_buffer("in_shift", shift.float())
        else:
            self.in_scale = self.in_shift = None
        self.blocks = [self._block(b) for b in mlp.blocks]
        self.head_w = mlp.head.weight.detach().to(dtype)
        self.head_b = mlp.head.bias.detach().to(dtype)

    def _block(self, b: ResBlock) -> tuple:
        """(stacked fc1+skip weight, its bias, hidden size, fc2 weight, fc2 bias)."""
        w1, b1 = _folded(b.fc1, b.bn1)
        w2, b2 = _folded(b.fc2, b.bn2)
        hidden = len(w1)
        if isinstance(b.skip, nn.Linear):  # one GEMM for both readers of x
            w1 = torch.cat([w1, b.skip.weight.double()])
            b1 = torch.cat([b1, torch.zeros(len(b.skip.weight), dtype=torch.float64)])
        cast = lambda t: t.detach().to(self.dtype).contiguous()  # noqa: E731
        return cast(w1), cast(b1), hidden, cast(w2), cast(b2)

    @torch.no_grad()
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        lead = x.shape[:-1]
        x = x.reshape(-1, x.shape[-1])  # (N, d_in)
        if self.in_scale is not None:
            x = x * self.in_scale + self.in_shift
        x = x.to(self.dtype)
        for w1, b1, hidden, w2, b2 in self.blocks:
            h = torch.addmm(b1, x, w1.T)  # (N, hidden [+ d_out])
            skip = h[:, hidden:] if len(w1) > hidden else x
            h = F.leaky_relu(h[:, :hidden], self.slope)
            x = F.leaky_relu(torch.addmm(b2, h, w2.T) + skip, self.slope)  # (N, width)
        out = torch.addmm(self.head_b, x, self.head_w.T).float()  # (N, d_out)
        return out.reshape(*lead, out.shape[-1])


def freeze(net: nn.Module, precision: str = "fp32") -> nn.Module:
    """Eval-mode copy of ``net`` with every :class:`ResMLP` replaced by a :class:`FrozenMLP`."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
    out = copy.deepcopy(net).eval()
    for name, child in list(out.named_children()):
        if isinstance(child, ResMLP):
            setattr(out, name, FrozenMLP(child, PRECISIONS[precision]))
    return out


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def frozen(net: nn.Module, precision: str = "fp32") -> nn.Module:
    """:func:`freeze` once per network object and precision (the pipeline is built per
    sequence). The copy does not follow later changes to ``net``'s weights."""
    per = _CACHE.setdefault(net, {})
    if precision not in per:
        per[precision] = freeze(net, precision)
    return per[precision]
