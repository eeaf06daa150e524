"""Run manifest (docs/contract.md, "Results"): what produced a report, so a number can be traced.

Versions of the suite and its key dependencies, git revision (and whether the tree had
uncommitted changes), platform, profile and config, seeds, data hash, wall time per stage.
Deliberately no timestamp: the same run on the same machine gives the same file.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from collections.abc import Iterable
from importlib import metadata
from pathlib import Path

from ..core.cpu import cpu_info
from ..core.errors import InputError
from ..core.io import atomic_write_text, jsonable
from ..core.numerics import state as numerics_state
from ..core.version import __version__

MANIFEST_SCHEMA = 1
# distribution names (as pip knows them), reported as-is; missing ones are null
PACKAGES = ("grip-bench", "numpy", "torch", "trimesh", "manifold3d", "mujoco", "pandas",
            "matplotlib", "scipy", "coacd", "numba", "smplx")
_GIT_TIMEOUT_S = 5  # git on a network file system can hang; a manifest must not


def package_versions(names: Iterable[str] = PACKAGES) -> dict[str, str | None]:
    """Installed version per distribution name, ``None`` when not installed."""
    out: dict[str, str | None] = {}
    for name in names:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def _git(args: list[str], cwd: Path) -> str | None:
    try:
        res = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True,
                             timeout=_GIT_TIMEOUT_S, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return res.stdout.strip() if res.returncode == 0 else None


def git_info(path: str | os.PathLike | None = None) -> dict:
    """``{"revision": sha | None, "dirty": bool | None}`` of the checkout holding the code."""
    cwd = Path(path) if path is not None else Path(__file__).resolve().parent
    rev = _git(["rev-parse", "HEAD"], cwd)
    if rev is None:
        return {"revision": None, "dirty": None}
    status = _git(["status", "--porcelain", "--untracked-files=no"], cwd)
    return {"revision": rev, "dirty": None if status is None else bool(status)}


def platform_info() -> dict:
    """The OS, the processor (model, the flags that decide GEMM speed, native bf16 / int8:
    ``core.cpu``) and the core count: timings mean nothing without them."""
    return {"system": platform.system(), "release": platform.release(),
            "machine": platform.machine(), "python_implementation":
            platform.python_implementation(), "cpu_count": os.cpu_count(),
            "cpu": cpu_info().as_dict()}


def peak_memory_mib() -> dict:
    """Peak resident memory (MiB) of this process and of its largest finished child
    (evaluation and generation workers), from ``getrusage``; empty where unavailable."""
    try:
        import resource
    except ImportError:  # not on Windows
        return {}
    scale = 1 / 1024 if sys.platform != "darwin" else 1 / 2**20  # KiB on Linux, bytes on macOS
    return {"self": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale, 1),
            "children": round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * scale, 1)}


def build_manifest(profile: dict, config: dict, seeds: dict, data_hash: str,
                   stage_times: dict) -> dict:
    """The manifest as a plain dict (JSON-ready); ``stage_times`` are seconds per stage,
    ``peak_memory_mib`` the peak resident memory up to now."""
    versions = package_versions()
    versions["python"] = platform.python_version()
    return {
        "schema": MANIFEST_SCHEMA,
        "grip_bench_version": __version__,
        "versions": versions,
        "git": git_info(),
        "platform": platform_info(),
        "numerics": numerics_state(),
        "cpu_count": os.cpu_count(),
        "python_executable": sys.executable,
        "profile": jsonable(profile),
        "config": jsonable(config),
        "seeds": jsonable(seeds),
        "data_hash": data_hash,
        "stage_times": jsonable(stage_times),
        "peak_memory_mib": peak_memory_mib(),
    }


def manifest_text(manifest: dict) -> str:
    """Sorted keys, 2-space indent, trailing newline: stable bytes for equal manifests."""
    try:
        return json.dumps(jsonable(manifest), sort_keys=True, indent=2, allow_nan=False) + "\n"
    except (TypeError, ValueError) as e:
        raise InputError(f"manifest is not plain JSON data: {e}") from e


def write_manifest(path: str | os.PathLike, manifest: dict) -> Path:
    """Write ``manifest.json`` atomically."""
    return atomic_write_text(path, manifest_text(manifest))


def read_manifest(path: str | os.PathLike) -> dict:
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(f"cannot read manifest: {e}", where=path) from None
