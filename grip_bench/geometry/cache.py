"""Persistent on-disk cache of derived object geometry (distance-field grids, convex pieces).

Building an object's distance field takes ~1 s and its CoACD decomposition several
seconds; every evaluation, training and synthesis process needs them again. Results are
stored as plain numpy arrays (``np.savez``, read back with ``allow_pickle=False``) under

    $GRIP_BENCH_CACHE, else $XDG_CACHE_HOME/grip-bench, else ~/.cache/grip-bench

in ``<kind>/<key[:2]>/<key>.npz``. The key is a SHA-256 of the cache version, the kind,
the mesh bytes (float64 vertices, int64 faces, with their shapes), the build
parameters and the numerics in effect (``core/numerics.py``: entries built with another
processor's native kernels are not read as portable ones), so a changed mesh or parameter
never reads a stale entry; bump
``CACHE_VERSION`` when a builder's output changes for the same inputs.

``GRIP_BENCH_CACHE=off`` (or ``0``, ``none``, ``false``, ``no``) disables the cache. Writes
go to a temporary file in the target folder and are moved into place with ``os.replace``,
so parallel processes never see a half-written entry (at worst two build the same entry
and the last one wins, with identical content). An unreadable entry (truncated, corrupt,
wrong arrays) is ignored and rebuilt, with one ``RuntimeWarning`` per process; a cache
folder that cannot be written is skipped the same way. Cached and freshly built results
are bit-identical: entries hold exactly the arrays the builders produce.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from ..core.io import atomic_file
from ..core.numerics import key as numerics_key

__all__ = ["CACHE_VERSION", "ENV_VAR", "cache_root", "mesh_key", "bytes_key", "load_arrays",
           "save_arrays", "cached_arrays", "package_version"]

CACHE_VERSION = "geom-2"  # bump when any cached builder changes its output for the same inputs
ENV_VAR = "GRIP_BENCH_CACHE"
_OFF = {"0", "off", "none", "false", "no"}
_warned: set[str] = set()


def _warn_once(what: str, msg: str) -> None:
    if what not in _warned:
        _warned.add(what)
        warnings.warn(msg, RuntimeWarning, stacklevel=3)


@functools.cache
def package_version(dist: str) -> str:
    """Installed version of a distribution, "?" if unknown.

    Part of the keys of entries whose builder is a library.
    """
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "?"


def cache_root() -> Path | None:
    """The cache folder (not created here), or None when the cache is switched off."""
    raw = os.environ.get(ENV_VAR, "").strip()
    if raw:
        return None if raw.lower() in _OFF else Path(raw).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "grip-bench"


def mesh_key(
    kind: str, vertices: np.ndarray, faces: np.ndarray, params: Mapping | None = None
) -> str:
    """Hex SHA-256 of (version, kind, mesh bytes, build parameters).

    params: plain JSON data (floats are written with ``repr`` precision by ``json``).
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    h = hashlib.sha256()
    h.update(f"{CACHE_VERSION}|{kind}|{v.shape}|{f.shape}|".encode())
    h.update(v.tobytes())
    h.update(f.tobytes())
    h.update(json.dumps(params or {}, sort_keys=True).encode())
    h.update(json.dumps(numerics_key(), sort_keys=True).encode())
    return h.hexdigest()


def bytes_key(kind: str, parts: tuple[bytes, ...], params: Mapping | None = None) -> str:
    """Hex SHA-256 of (version, kind, byte strings, build parameters): entries derived from
    files (e.g. a repaired mesh: the file's bytes and the code that repairs it)."""
    h = hashlib.sha256()
    h.update(f"{CACHE_VERSION}|{kind}|{len(parts)}|".encode())
    for part in parts:
        h.update(f"{len(part)}|".encode())
        h.update(part)
    h.update(json.dumps(params or {}, sort_keys=True).encode())
    h.update(json.dumps(numerics_key(), sort_keys=True).encode())
    return h.hexdigest()


def _path(root: Path, kind: str, key: str) -> Path:
    return root / kind / key[:2] / f"{key}.npz"


def load_arrays(kind: str, key: str, names: tuple[str, ...] | None = None,
                validate: Callable[[dict], bool] | None = None) -> dict[str, np.ndarray] | None:
    """The arrays stored under ``(kind, key)``, or None when absent, disabled or unreadable.

    names: arrays that must be present; validate: a check of the arrays (shapes, sizes). An
    entry failing either counts as corrupt.
    """
    root = cache_root()
    if root is None:
        return None
    path = _path(root, kind, key)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        missing = [n for n in names or () if n not in arrays]
        if missing:
            raise KeyError(f"missing arrays {missing}")
        if validate is not None and not validate(arrays):
            raise ValueError("arrays of unexpected shape or size")
    except Exception as e:  # noqa: BLE001 - any unreadable entry is rebuilt
        _warn_once("corrupt", f"grip-bench geometry cache: ignoring unreadable entry {path} "
                              f"({type(e).__name__}: {e}); rebuilding it")
        return None
    return arrays


def save_arrays(kind: str, key: str, arrays: Mapping[str, np.ndarray]) -> None:
    """Store ``arrays`` under ``(kind, key)`` atomically; a failing write only warns."""
    root = cache_root()
    if root is None:
        return
    path = _path(root, kind, key)
    try:
        with atomic_file(path) as f:
            np.savez(f, **{k: np.asarray(a) for k, a in arrays.items()})
    except OSError as e:
        _warn_once("write", f"grip-bench geometry cache: cannot write {path} ({e}); not caching")


def cached_arrays(kind: str, key: str, build: Callable[[], Mapping[str, np.ndarray]],
                  names: tuple[str, ...] | None = None,
                  validate: Callable[[dict], bool] | None = None) -> dict[str, np.ndarray]:
    """The cached arrays of ``(kind, key)``, else ``build()``'s (then stored); ``names`` and
    ``validate`` as in :func:`load_arrays`."""
    arrays = load_arrays(kind, key, names, validate)
    if arrays is None:
        arrays = dict(build())
        save_arrays(kind, key, arrays)
    return arrays
