"""Content-addressed cache of work units, so an interrupted ``grip-bench run`` resumes.

A *unit* is a directory ``<root>/<kind>/<hh>/<key>/`` holding the files one step produced
(predictions of one sequence, metric values of one sequence...). Units appear atomically:
they are written into ``<root>/.tmp/`` and renamed into place only when the writer finished,
so killing the process at any moment leaves either the complete unit or nothing.

Each finished unit carries ``.integrity.json``: the sha256 of every file in it, recorded
just before the rename. A unit is verified when first reused in a process; a flipped byte,
a missing or an extra file makes it count as missing, so the run rebuilds it (the damaged
copy is removed only then, so ``--dry-run`` changes nothing) and says so in
:attr:`Cache.notes`. Units written before integrity records existed are trusted once and
given a record.
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
from ..core.io import WRITE_ERRNOS, WriteError, jsonable
from ..core.numerics import key as numerics_key
from ..core.version import __version__

# Part of every key: a new release or cache layout invalidates old units instead of
# silently reusing results computed by different code.
CODE_VERSION = f"grip-bench-{__version__}-cache{CACHE_SCHEMA_VERSION}"

_KIND_RE = re.compile(r"^[a-z0-9_]+$")
_KEY_RE = re.compile(r"^([a-z0-9_]+)-([0-9a-f]{64})$")
_TMP = ".tmp"
UNIT_FILE = "unit.json"  # each unit's record: kind, label, inputs, info, seconds
INTEGRITY_FILE = ".integrity.json"  # sha256 of each file of the finished unit


def canonical_json(obj: Any) -> str:
    """Sorted keys, no whitespace, shortest float repr: equal inputs give equal text."""
    try:
        return json.dumps(jsonable(obj), sort_keys=True, separators=(",", ":"),
                          ensure_ascii=True, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise InputError(f"cache key inputs are not plain data: {e}") from e


def unit_key(kind: str, inputs: dict) -> str:
    """``<kind>-<sha256>`` of the canonical JSON of ``inputs``, ``kind``, the code version and
    the numerics in effect (``core/numerics.py``: natively computed units name their
    processor, so they are never mixed with another processor's or with portable ones)."""
    if not _KIND_RE.match(kind):
        raise InputError(f"cache unit kind '{kind}' must match [a-z0-9_]+")
    payload = canonical_json({"code": CODE_VERSION, "inputs": inputs, "kind": kind,
                              "numerics": numerics_key()})
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
        self._verified: dict[str, bool] = {}  # key -> the unit passed its integrity check
        self.notes: list[str] = []  # damaged units found (and rebuilt), for the run log
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
        """Whether the unit is complete and intact; the first answer per key feeds
        :meth:`summary`. A damaged unit counts as missing (see the module docstring)."""
        found = self.path(key).is_dir() and self._intact(key)
        self._first_lookup.setdefault(key, found)
        return found

    def _intact(self, key: str) -> bool:
        """Verify the unit's files against its integrity record, once per process."""
        if key not in self._verified:
            unit = self.path(key)
            problem = check_integrity(unit)
            if problem == _NO_RECORD:
                # a unit of an older release: trust it once, check it from now on
                with contextlib.suppress(OSError):
                    write_integrity(unit)
                problem = None
            if problem:
                self.notes.append(f"note: cache unit {unit} is damaged ({problem}): rebuilding it")
            self._verified[key] = problem is None
        return self._verified[key]

    def take_notes(self) -> list[str]:
        """The notes gathered since the last call (each is logged once)."""
        notes, self.notes = self.notes, []
        return notes

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
            write_integrity(tmp)
        except BaseException as e:
            shutil.rmtree(tmp, ignore_errors=True)
            if isinstance(e, OSError) and e.errno in WRITE_ERRNOS:
                raise _unit_write_error(e, tmp, final) from None
            raise
        final.parent.mkdir(parents=True, exist_ok=True)
        if self._verified.get(key) is False:
            self._discard(final)  # the damaged copy this unit replaces
        try:
            os.rename(tmp, final)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if not final.is_dir():
                raise
        else:
            self.written += 1
            self._verified[key] = True

    def _discard(self, unit: Path) -> None:
        """Remove a damaged unit: renamed into ``.tmp`` first, so no reader sees half of it."""
        if not unit.is_dir():
            return
        trash = Path(tempfile.mkdtemp(prefix=f"{socket.gethostname()}__{os.getpid()}__damaged__",
                                      dir=self.root / _TMP))
        os.rename(unit, trash / unit.name)
        shutil.rmtree(trash, ignore_errors=True)

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


def _unit_write_error(e: OSError, tmp: Path, final: Path) -> WriteError:
    """A refused write inside a unit's temp folder, one line, naming the file as it would
    have been in the finished unit (the temp folder is gone)."""
    where = getattr(e, "where", None) or e.filename or tmp
    where = str(where).replace(str(tmp), str(final), 1)
    what = getattr(e, "what", None) or f"cannot write ({e.strerror or e})"
    err = WriteError(what, where)
    err.errno = e.errno
    return err


# --- integrity records ----------------------------------------------------------------------
_NO_RECORD = "no integrity record"


def _file_digests(unit: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``unit`` but the record itself."""
    out = {}
    for p in sorted(unit.rglob("*")):
        rel = p.relative_to(unit).as_posix()
        if rel == INTEGRITY_FILE or not p.is_file():
            continue
        h = hashlib.sha256()
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        out[rel] = h.hexdigest()
    return out


def write_integrity(unit: Path) -> None:
    """Record the digest of each file of ``unit`` (called on the finished temp folder)."""
    text = json.dumps({"files": _file_digests(unit)}, sort_keys=True, indent=1) + "\n"
    (unit / INTEGRITY_FILE).write_text(text, encoding="utf-8")


def check_integrity(unit: Path) -> str | None:
    """None when ``unit`` matches its record, else what is wrong (one short phrase)."""
    record = unit / INTEGRITY_FILE
    if not record.is_file():
        return _NO_RECORD
    try:
        want = json.loads(record.read_text(encoding="utf-8"))["files"]
        if not isinstance(want, dict):
            raise TypeError("files is not a mapping")
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as e:
        return f"unreadable integrity record: {type(e).__name__}"
    try:
        have = _file_digests(unit)
    except OSError as e:
        return f"unreadable: {e.strerror or e}"
    for rel in sorted(set(want) | set(have)):
        if rel not in have:
            return f"{rel} is missing"
        if rel not in want:
            return f"{rel} was not part of it"
        if have[rel] != want[rel]:
            return f"{rel} does not match its recorded sha256"
    return None
