"""What this machine's processor accelerates, read once per process.

Reduced precision only pays where the hardware runs it natively: on a CPU without
AVX512-BF16 or AMX-BF16, torch emulates bfloat16 GEMMs and ``--precision bf16`` runs about
4x *slower* than float32 (measured on an AVX2-only EPYC). So the choice of precision
(``grip.frozen.resolve_precision``) reads :func:`cpu_info`, and every manifest and
benchmark records it (the model name and the flags below), because speed figures mean
nothing without the machine they came from.
"""

from __future__ import annotations

import functools
import platform
from dataclasses import asdict, dataclass
from pathlib import Path

# The instruction-set flags that decide GEMM speed per precision (Linux /proc/cpuinfo names).
ACCEL_FLAGS = ("avx2", "fma", "avx512f", "avx512_bf16", "avx512_fp16", "avx512_vnni",
               "avx_vnni", "amx_tile", "amx_bf16", "amx_int8",
               "asimd", "bf16", "i8mm", "sve")  # the last four: aarch64 "Features"
BF16_FLAGS = ("avx512_bf16", "amx_bf16", "bf16")  # x86 AVX512-BF16 / AMX, Arm BF16
INT8_FLAGS = ("avx512_vnni", "avx_vnni", "amx_int8", "i8mm")


@dataclass(frozen=True)
class CpuInfo:
    """``model``: the processor's name; ``flags``: those of :data:`ACCEL_FLAGS` it has;
    ``capability``: torch's dispatch level (e.g. ``AVX512``); ``native_bf16`` /
    ``native_int8``: whether bfloat16 GEMMs / int8 dot products run in hardware."""

    model: str
    flags: tuple[str, ...]
    capability: str
    native_bf16: bool
    native_int8: bool

    def as_dict(self) -> dict:
        d = asdict(self)
        d["flags"] = list(self.flags)
        return d


def parse_cpuinfo(text: str) -> tuple[str, set[str]]:
    """(model name, every flag) from the text of ``/proc/cpuinfo`` (x86 ``flags`` or aarch64
    ``Features``; the first processor's lines)."""
    model, flags = "", set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key = key.strip().lower()
        if key in ("model name", "hardware", "cpu model") and not model:
            model = value.strip()
        elif key in ("flags", "features") and not flags:
            flags = set(value.split())
    return model, flags


def _torch_flags() -> set[str]:
    """The bf16 / int8 flags as torch sees them, where /proc/cpuinfo is not there (macOS,
    Windows); empty when torch has no such probes."""
    try:
        import torch.cpu as tc
    except ImportError:
        return set()
    probes = {"avx512_bf16": "_is_avx512_bf16_supported", "amx_tile": "_is_amx_tile_supported",
              "avx512_vnni": "_is_vnni_supported", "avx2": "_is_avx2_supported",
              "avx512f": "_is_avx512_supported"}
    return {flag for flag, fn in probes.items() if getattr(tc, fn, lambda: False)()}


def _capability() -> str:
    try:
        import torch
        return str(torch.backends.cpu.get_cpu_capability())
    except (ImportError, AttributeError):
        return "unknown"


def info_from(model: str, flags: set[str], capability: str) -> CpuInfo:
    """:class:`CpuInfo` from a model name and a flag set (separate from the probing, so the
    decision is tested on any machine)."""
    kept = tuple(f for f in ACCEL_FLAGS if f in flags)
    return CpuInfo(model=model or platform.processor() or platform.machine(), flags=kept,
                   capability=capability, native_bf16=any(f in flags for f in BF16_FLAGS),
                   native_int8=any(f in flags for f in INT8_FLAGS))


@functools.cache
def cpu_info() -> CpuInfo:
    """This machine's :class:`CpuInfo` (``/proc/cpuinfo`` where it exists, else torch's
    probes)."""
    path = Path("/proc/cpuinfo")
    try:
        model, flags = parse_cpuinfo(path.read_text(errors="replace"))
    except OSError:
        model, flags = "", set()
    if not flags:
        flags = _torch_flags()
    return info_from(model, flags, _capability())
