"""Portable numerics: one seed gives the same bits on any x86-64 processor with AVX2.

Why: four libraries choose their kernels by the processor they run on, and each choice
changes the last bits of what they compute, which the data generator's searches and the
networks' training then turn into different data and different scores. Measured in s54 on
an AVX-512 Xeon (the smoke data's hash, one library pinned at a time, each changed it):
numpy's SIMD loops (its AVX-512 dispatch targets), OpenBLAS's kernels (numpy's BLAS),
torch's vectorised ATen kernels and MKL's code branches (torch's BLAS and LAPACK). s53
found the consequence: the same seed made different data on that Xeon and on an AVX2 EPYC.

So the suite pins all four, before any of them loads, to what every x86-64 processor with
AVX2 and FMA runs the same way (``PINS``):

- numpy: its x86-64-v3 (AVX2) loops, the AVX-512 targets disabled;
- OpenBLAS: its Haswell kernels and block sizes;
- torch: the AVX2 ATen kernels;
- MKL: the ``COMPATIBLE`` branch, the one Intel documents as giving the same results on
  Intel and non-Intel processors (its ``AVX2`` branch does so on Intel processors only).

A variable the user has already set is left as it is. ``GRIP_BENCH_NUMERICS=native`` turns
the pins off (every library's fastest kernels; results then repeat on one processor family
only). Processors below x86-64-v3 (AVX2, FMA, BMI2, MOVBE...) and non-x86 machines run
natively: pinning a kernel they lack would crash. :func:`state` records what is in effect
(every manifest) and :func:`key` enters every cache key, so units computed natively on one
processor and units computed portably are never mixed (docs/architecture.md, "Cache
keys").

The pins must be set before numpy and torch load: ``grip_bench/__init__.py`` calls
:func:`pin` first, spawned workers inherit the environment, and :func:`state` names a
library that loaded before the pins (then they did not reach it).
"""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path

from .cpu import cpu_info, parse_cpuinfo

MODE_VAR = "GRIP_BENCH_NUMERICS"  # "portable" (default) or "native"
MODES = ("portable", "native")
PINS = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "OPENBLAS_CORETYPE": "Haswell",
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_CBWR": "COMPATIBLE",
}
# x86-64-v3, the level of every pinned kernel (Linux flag names; "abm" is LZCNT)
NEEDS = ("avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe", "xsave")
LIBRARIES = ("numpy", "torch")  # those that read the pins when they load or first compute

_late: tuple[str, ...] | None = None  # the libraries already loaded when pin() ran


def requested_mode(environ=os.environ) -> str:
    """The mode the environment asks for; an unknown value is an error naming the variable."""
    mode = environ.get(MODE_VAR, "portable").strip().lower() or "portable"
    if mode not in MODES:
        raise ValueError(f"{MODE_VAR}={environ[MODE_VAR]!r}: expected one of {', '.join(MODES)}")
    return mode


def _cpu_flags() -> set[str]:
    """The x86 flags of ``/proc/cpuinfo`` (``core.cpu.parse_cpuinfo``); empty where it is
    absent."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return set()
    return parse_cpuinfo(text)[1]


def can_pin(machine: str | None = None, flags: set[str] | None = None) -> bool:
    """Whether this processor runs the pinned kernels: x86-64 at level v3 (AVX2, FMA...)."""
    machine = (machine or platform.machine()).lower()
    flags = _cpu_flags() if flags is None else flags
    return machine in ("x86_64", "amd64") and all(f in flags for f in NEEDS)


def pin(environ=os.environ) -> str:
    """Set the pins not already set (portable mode on a processor that runs them); return
    the mode in effect. Call before numpy and torch load."""
    global _late
    # A library loaded before now missed the pins, unless they were in the environment when
    # the process started (a worker inherits them and loads numpy before grip_bench).
    inherited = all(environ.get(k) == v for k, v in PINS.items())
    _late = () if inherited else tuple(lib for lib in LIBRARIES if lib in sys.modules)
    try:
        wanted = requested_mode(environ)
    except ValueError as e:  # at import time: one line and exit 2, as every input error
        print(f"grip-bench: error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    if wanted != "portable" or not can_pin():
        return "native"
    for name, value in PINS.items():
        environ.setdefault(name, value)
    return "portable"


def mode(environ=os.environ) -> str:
    """``portable`` when every pin is set to its value, ``custom`` when some are set
    otherwise, ``native`` when none is."""
    set_ = {k: environ.get(k) for k in PINS}
    if all(set_[k] == v for k, v in PINS.items()):
        return "portable"
    return "native" if not any(set_.values()) else "custom"


def key(environ=os.environ) -> dict:
    """What a cache key holds about the numerics: the pins' values, and outside portable
    mode the processor too (its native kernels are part of what a unit computed)."""
    out = {"mode": mode(environ), "pins": {k: environ.get(k) for k in PINS}}
    if out["mode"] != "portable":
        info = cpu_info()
        out["cpu"] = {"model": info.model, "capability": info.capability,
                      "flags": sorted(info.flags)}
    return out


def _openblas_core() -> str | None:
    """The kernel set numpy's OpenBLAS chose (its ``get_corename``), if it can be found."""
    import ctypes

    try:
        maps = Path("/proc/self/maps").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    paths = sorted({ln.split()[-1] for ln in maps.splitlines() if "openblas" in ln.lower()
                    and ln.split()[-1].startswith("/")})
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename",
                     "openblas_get_corename64_", "openblas_get_corename"):
            fn = getattr(lib, name, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                return fn().decode()
    return None


def state() -> dict:
    """What is in effect in this process (for the manifest): the mode, the pins' values,
    numpy's enabled AVX-512 targets, OpenBLAS's kernel set, torch's ATen level, and the
    libraries that loaded before :func:`pin` (the pins did not reach them)."""
    import numpy as np

    feats = np._core._multiarray_umath.__cpu_features__
    out = key()
    out["numpy_avx512"] = sorted(k for k in ("X86_V4", "AVX512_ICL", "AVX512_SPR")
                                 if feats.get(k))
    out["openblas_core"] = _openblas_core()
    out["loaded_before_pins"] = list(_late or ())
    if "torch" in sys.modules:
        out["torch_capability"] = sys.modules["torch"].backends.cpu.get_cpu_capability()
    out["in_effect"] = in_effect(out)
    return out


def in_effect(s: dict) -> bool:
    """Whether the libraries run what the mode says: outside portable mode always; in it, no
    numpy AVX-512 target on, OpenBLAS on Haswell (where it can say) and torch at AVX2
    (where it has loaded)."""
    if s["mode"] != "portable":
        return True
    return (not s["numpy_avx512"] and s.get("openblas_core") in (None, "Haswell")
            and s.get("torch_capability") in (None, "AVX2"))


def env() -> dict[str, str]:
    """The pins and the mode as set in this process, for workers that do not inherit this
    process's environment (a Ray cluster's nodes)."""
    return {k: os.environ[k] for k in (*PINS, MODE_VAR) if k in os.environ}


def check_worker(expected_mode: str) -> None:
    """Raise a one-line error when this worker does not run the kernels the run's driver
    keys its units by (a worker that loaded numpy before the pins reached it)."""
    s = state()
    if s["mode"] != expected_mode or not s["in_effect"]:
        from .errors import GripBenchError

        raise GripBenchError(
            f"this worker's numerics ({s['mode']}, numpy AVX-512 targets "
            f"{s['numpy_avx512'] or 'off'}, OpenBLAS {s['openblas_core']}) are not the "
            f"driver's ({expected_mode}): start the node's workers with {MODE_VAR} and the "
            f"pins of docs/reproducibility.md set", where="numerics")
