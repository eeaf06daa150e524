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

``int8`` (the stream's batch-1 option, :mod:`grip_bench.grip.stream`): the folded weights
are quantized per output channel (symmetric, 8 bits) and each GEMM is torch's dynamic
quantized linear (activations quantized per call, int8 dot products, float32 out). At
batch 1 a frame streams every weight once, so 1 byte a weight instead of 4 (or 2 for bf16,
whose batch-1 GEMV torch runs slowly on CPU) is what sets the latency.
"""

from __future__ import annotations

import copy
import warnings
import weakref

import torch
from torch import nn
from torch.nn import functional as F

from ..core.cpu import CpuInfo, cpu_info
from ..nn.blocks import ResBlock, ResMLP

PRECISIONS = {"fp32": torch.float32, "bf16": torch.bfloat16}
PRECISION_CHOICES = ("auto", *PRECISIONS)
INT8 = "int8"  # dynamic int8 GEMMs (batch-1 streaming; not offered for whole sequences)
STREAM_PRECISION_CHOICES = (*PRECISION_CHOICES, INT8)


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


def resolve_stream_precision(requested: str, cpu: CpuInfo | None = None
                             ) -> tuple[str, str | None]:
    """(precision to run, a warning or None) for the stream's ``--precision`` (CPU, batch 1).

    At batch 1 the latency is the weights' memory traffic, not GEMM FLOPs, so ``auto``
    differs from :func:`resolve_precision`'s: int8 where the CPU has int8 dot products
    (AVX512-VNNI, AVX-VNNI, AMX-INT8, Arm i8mm), else fp32. bf16 (half the bytes, but a slow
    batch-1 kernel in torch) and int8 are honoured when asked for, with a warning when emulated.
    """
    if requested not in STREAM_PRECISION_CHOICES:
        raise ValueError(
            f"precision must be one of {STREAM_PRECISION_CHOICES}, got {requested!r}")
    info = cpu or cpu_info()
    if requested == "auto":
        return (INT8 if info.native_int8 else "fp32"), None
    if requested == INT8:
        warning = None if info.native_int8 else (
            f"int8 dot products are emulated on this CPU ({info.model}): expect little gain")
        return INT8, warning
    return resolve_precision(requested, "cpu", info)


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

    def __init__(self, mlp: ResMLP, dtype: torch.dtype | str = torch.float32,
                 gemv: bool = False):
        super().__init__()
        self.gemv = gemv  # batch-1 kernels (module docstring of grip.stream)
        self.int8 = dtype == INT8  # float32 weights, then packed for the int8 GEMMs below
        dtype = torch.float32 if self.int8 else dtype
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
        if self.int8:
            self.packed = [(_pack_int8(w1, b1), hidden, _pack_int8(w2, b2))
                           for w1, b1, hidden, w2, b2 in self.blocks]
            self.packed_head = _pack_int8(self.head_w, self.head_b)
            self.blocks, self.head_w, self.head_b = [], None, None  # 1/4 of the memory

    def _block(self, b: ResBlock) -> tuple:
        """(stacked fc1+skip weight, its bias, hidden size, fc2 weight, fc2 bias)."""
        w1, b1 = _folded(b.fc1, b.bn1)
        w2, b2 = _folded(b.fc2, b.bn2)
        hidden = len(w1)
        if isinstance(b.skip, nn.Linear):  # one GEMM for both readers of x
            w1 = torch.cat([w1, b.skip.weight.double()])
            b1 = torch.cat([b1, torch.zeros(len(b.skip.weight), dtype=torch.float64,
                                            device=b1.device)])
        cast = lambda t: t.detach().to(self.dtype).contiguous()  # noqa: E731
        return cast(w1), cast(b1), hidden, cast(w2), cast(b2)

    @torch.no_grad()
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        lead = x.shape[:-1]
        x = x.reshape(-1, x.shape[-1])  # (N, d_in)
        if self.in_scale is not None:
            x = x * self.in_scale + self.in_shift
        if self.int8:
            out = self._forward_int8(x)
            return out.reshape(*lead, out.shape[-1])
        x = x.to(self.dtype)
        if self.gemv and len(x) == 1 and x.dtype == torch.float32:
            out = self._forward_gemv(x)
            return out.reshape(*lead, out.shape[-1])
        for w1, b1, hidden, w2, b2 in self.blocks:
            h = self._mm(b1, x, w1)  # (N, hidden [+ d_out])
            skip = h[:, hidden:] if len(w1) > hidden else x
            h = F.leaky_relu(h[:, :hidden], self.slope)
            x = F.leaky_relu(self._mm(b2, h, w2) + skip, self.slope)  # (N, width)
        out = self._mm(self.head_b, x, self.head_w).float()  # (N, d_out)
        return out.reshape(*lead, out.shape[-1])

    def _forward_gemv(self, x: torch.Tensor) -> torch.Tensor:
        """The fp32 blocks at batch 1 (``gemv``): ``(1, d_in)`` -> ``(1, d_out)`` float32, the
        values of :meth:`_mm`'s ``F.linear`` path, with the second GEMM's output finished in
        place (two fewer temporaries per block)."""
        for w1, b1, hidden, w2, b2 in self.blocks:
            h = F.linear(x, w1, b1)  # (1, hidden [+ d_out])
            skip = h[:, hidden:] if len(w1) > hidden else x
            h = F.leaky_relu(h[:, :hidden], self.slope)
            x = F.linear(h, w2, b2).add_(skip)
            F.leaky_relu_(x, self.slope)
        return F.linear(x, self.head_w, self.head_b)

    def _mm(self, b: torch.Tensor, x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """``b + x @ w.T`` ``(N, out)``. With ``gemv`` and one row, the kernel that reads
        ``w (out, in)`` fastest at batch 1 on CPU (measured, 1 thread: ``F.linear`` 15 %
        faster than ``addmm`` in fp32, ``addmv`` 1.5x faster in bf16); otherwise ``addmm``,
        which the offline results were recorded with (other kernels round differently)."""
        if not self.gemv or len(x) != 1:
            return torch.addmm(b, x, w.T)
        if x.dtype == torch.float32:
            return F.linear(x, w, b)
        return torch.addmv(b, w, x[0])[None]

    def _forward_int8(self, x: torch.Tensor) -> torch.Tensor:
        """The blocks with int8 GEMMs: ``(N, d_in)`` float32 -> ``(N, d_out)`` float32.

        The op's overload is called directly (the packet's Python dispatch cost ~15 us a call,
        37 calls a streamed frame) and the second GEMM's output is finished in place.
        Activations are quantized to 7 bits (``reduce_range``): on x86 CPUs without VNNI,
        fbgemm's u8 x s8 products saturate 16-bit sums with 8-bit activations (measured on an
        AVX2 EPYC: a test RNet's error 24 % of its output range, 1.8 % with 7 bits)."""
        lin = torch.ops.quantized.linear_dynamic.default
        for p1, hidden, p2 in self.packed:
            h = lin(x.contiguous(), p1, True)  # (N, hidden [+ d_out])
            skip = h[:, hidden:] if h.shape[1] > hidden else x
            h = F.leaky_relu(h[:, :hidden], self.slope)
            x = lin(h.contiguous(), p2, True).add_(skip)
            F.leaky_relu_(x, self.slope)
        return lin(x.contiguous(), self.packed_head, True)


def _pack_int8(w: torch.Tensor, b: torch.Tensor) -> object:
    """``(out, in)`` float32 weight and bias packed for ``quantized.linear_dynamic``:
    symmetric per-output-channel int8 (scale = max |w| / 127 of each row)."""
    w = w.float().contiguous()
    scale = (w.abs().amax(1).double() / 127).clamp_min(1e-12)
    zero = torch.zeros(len(w), dtype=torch.long)
    with warnings.catch_warnings():  # torch marks quantized tensor creation as deprecated
        warnings.simplefilter("ignore", UserWarning)
        q = torch.quantize_per_channel(w, scale, zero, 0, torch.qint8)
    return torch.ops.quantized.linear_prepack(q, b.float().contiguous())


def freeze(net: nn.Module, precision: str = "fp32", gemv: bool = False) -> nn.Module:
    """Eval-mode copy of ``net`` with every :class:`ResMLP` replaced by a :class:`FrozenMLP`."""
    if precision not in (*PRECISIONS, INT8):
        raise ValueError(
            f"precision must be one of {[*PRECISIONS, INT8]}, got {precision!r}")
    out = copy.deepcopy(net).eval()
    for name, child in list(out.named_children()):
        if isinstance(child, ResMLP):
            setattr(out, name, FrozenMLP(child, PRECISIONS.get(precision, precision), gemv))
    return out


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def frozen(net: nn.Module, precision: str = "fp32", gemv: bool = False) -> nn.Module:
    """:func:`freeze` once per network object and precision (the pipeline is built per
    sequence). The copy does not follow later changes to ``net``'s weights."""
    per = _CACHE.setdefault(net, {})
    if (precision, gemv) not in per:
        per[precision, gemv] = freeze(net, precision, gemv)
    return per[precision, gemv]
