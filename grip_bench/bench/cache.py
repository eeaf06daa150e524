"""Content-addressed cache of work units, so an interrupted ``grip-bench run`` resumes.

A *unit* is a directory ``<root>/<kind>/<hh>/<key>/`` holding the files one step produced
(predictions of one sequence, metric values of one sequence...). Units appear atomically:
they are written into ``<root>/.tmp/`` and renamed into place only when the writer finished,
so killing the process at any moment leaves either the complete unit or nothing.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ..core.constants import CACHE_SCHEMA_VERSION
from ..core.errors import InputError
from ..core.io import jsonable
from ..core.version import __version__

# Part of every key: a new release or cache layout invalidates old units instead of
# silently reusing results computed by different code.
CODE_VERSION = f"grip-bench-{__version__}-cache{CACHE_SCHEMA_VERSION}"

_KIND_RE = re.compile(r"^[a-z0-9_]+$")
_KEY_RE = re.compile(r"^([a-z0-9_]+)-([0-9a-f]{64})$")
_TMP = ".tmp"
UNIT_FILE = "unit.json"  # each unit's record: kind, label, inputs, info, seconds


def canonical_json(obj: Any) -> str:
    """Sorted keys, no whitespace, shortest float repr: equal inputs give equal text."""
    try:
        return json.dumps(jsonable(obj), sort_keys=True, separators=(",", ":"),
                          ensure_ascii=True, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise InputError(f"cache key inputs are not plain data: {e}") from e


def unit_key(kind: str, inputs: dict) -> str:
    """``<kind>-<sha256>`` of the canonical JSON of ``inputs``, ``kind`` and the code version."""
    if not _KIND_RE.match(kind):
        raise InputError(f"cache unit kind '{kind}' must match [a-z0-9_]+")
    payload = canonical_json({"code": CODE_VERSION, "inputs": inputs, "kind": kind})
    return f"{kind}-{hashlib.sha256(payload.encode('ascii')).hexdigest()}"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


class Cache:
    """Content-addressed store of work units under ``root`` (see the module docstring)."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self._first_lookup: dict[str, bool] = {}
        self.written = 0
        self.removed_stale = self.clean_stale()

    # -- lookup --------------------------------------------------------------
    def path(self, key: str) -> Path:
        """Folder of unit ``key`` (exists only once the unit is complete)."""
        m = _KEY_RE.match(key)
        if not m:
            raise InputError(f"malformed cache key '{key}'")
        kind, digest = m.groups()
        return self.root / kind / digest[:2] / key

    def has(self, key: str) -> bool:
        """Whether the unit is complete; the first answer per key feeds :meth:`summary`."""
        found = self.path(key).is_dir()
        self._first_lookup.setdefault(key, found)
        return found

    # -- writing -------------------------------------------------------------
    @contextlib.contextmanager
    def atomic(self, key: str) -> Iterator[Path]:
        """Yield a fresh temp folder; on success it becomes the unit, on error it is removed.

        If another writer finished the same unit first, its copy is kept (same inputs,
        same content) and ours is discarded.
        """
        final = self.path(key)
        tmp = self._new_tmp(key)
        try:
            yield tmp
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        final.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.rename(tmp, final)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if not final.is_dir():
                raise
        else:
            self.written += 1

    def put_bytes(self, key: str, data: bytes, name: str = "data.bin") -> Path:
        """Store ``data`` as the single file ``name`` of a new unit."""
        with self.atomic(key) as tmp:
            (tmp / name).write_bytes(data)
        return self.path(key) / name

    def put_json(self, key: str, obj: Any, name: str = "data.json") -> Path:
        """Store ``obj`` as sorted-key JSON (deterministic bytes)."""
        text = json.dumps(obj, sort_keys=True, indent=1, allow_nan=True) + "\n"
        return self.put_bytes(key, text.encode("utf-8"), name)

    def put_file(self, key: str, src: str | os.PathLike, name: str | None = None) -> Path:
        """Copy file ``src`` into a new unit (keeping its name unless ``name`` is given)."""
        src = Path(src)
        if not src.is_file():
            raise InputError("no such file to cache", where=src)
        name = name or src.name
        with self.atomic(key) as tmp:
            shutil.copyfile(src, tmp / name)
        return self.path(key) / name

    def get_json(self, key: str, name: str = "data.json") -> Any:
        """Load a JSON file of a complete unit."""
        path = self.path(key) / name
        if not path.is_file():
            raise InputError("cache unit has no such file", where=path)
        return json.loads(path.read_text(encoding="utf-8"))

    # -- housekeeping --------------------------------------------------------
    def _new_tmp(self, key: str) -> Path:
        # host and pid in the name tell clean_stale() whether the writer is still alive
        base = self.root / _TMP
        base.mkdir(parents=True, exist_ok=True)
        prefix = f"{socket.gethostname()}__{os.getpid()}__{key}__"
        return Path(tempfile.mkdtemp(prefix=prefix, dir=base))

    def clean_stale(self, own: bool = False) -> int:
        """Remove temp folders left by killed writers on this host; returns how many.

        Temp folders of live processes (a parallel worker) and of other hosts sharing the
        folder are left alone: they may still be renamed into place. ``own``: this process's
        too (it is stopping, so none of them will be).
        """
        base = self.root / _TMP
        if not base.is_dir():
            return 0
        host, removed = socket.gethostname(), 0
        for d in sorted(base.iterdir()):
            parts = d.name.split("__")
            if len(parts) < 3 or parts[0] != host or not parts[1].isdigit():
                continue
            pid = int(parts[1])
            if (own and pid == os.getpid()) or not _pid_alive(pid):
                shutil.rmtree(d, ignore_errors=True)
                removed += 1
        return removed

    def summary(self) -> dict:
        """Hits (reused) and misses (computed) per unit kind, from each key's first lookup."""
        by_kind: dict[str, dict[str, int]] = {}
        for key, hit in sorted(self._first_lookup.items()):
            counts = by_kind.setdefault(key.split("-", 1)[0], {"hits": 0, "misses": 0})
            counts["hits" if hit else "misses"] += 1
        hits = sum(c["hits"] for c in by_kind.values())
        misses = sum(c["misses"] for c in by_kind.values())
        return {"hits": hits, "misses": misses, "written": self.written,
                "stale_removed": self.removed_stale, "by_kind": by_kind}

    def summary_line(self) -> str:
        """One line for the run log: ``cache: reused 10 of 40 units (metrics 0/30, ...)``."""
        s = self.summary()
        parts = ", ".join(f"{k} {c['hits']}/{c['hits'] + c['misses']}"
                          for k, c in s["by_kind"].items())
        total = s["hits"] + s["misses"]
        return f"cache: reused {s['hits']} of {total} units" + (f" ({parts})" if parts else "")
