"""The one atomic file writer: readers see the old file or the new one, never half of one.

Every file the suite writes for later reading (sequences, checkpoints, caches, results,
reports) goes through :func:`atomic_file`: a temp file in the target folder, flushed and
fsynced, given the permissions an ordinary ``open`` would give (``0666 & ~umask``: results
are meant to be shared, while ``mkstemp`` makes ``0600``), then moved into place with
``os.replace``. A crash or an exception leaves any previous file untouched and no temp file.

A write the system refuses (disk full, quota, read-only folder, no permission) is a
one-line :class:`WriteError` naming the file, not a traceback: the CLI prints it as
``error: <file>: cannot write (No space left on device)`` and exits 1.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from .errors import GripBenchError


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


class WriteError(GripBenchError, OSError):
    """The system refused to write a file (``where`` is the file); ``errno`` is kept."""


# Errors of the write itself wherever they surface (the caller's ``f.write`` included);
# other OSErrors inside the ``with`` block may be the caller's own reads and pass through.
WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS}


def ensure_writable_dir(path: str | os.PathLike) -> Path:
    """Create the folder ``path`` (and parents) and prove a file can be written in it, before
    any work whose results would land there: a read-only or full output folder is then one
    line up front, not a traceback after the computing. Raises :class:`WriteError`."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-probe-", dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise _write_error(e, path) from None
    return path


def _write_error(e: OSError, path: Path) -> WriteError:
    err = WriteError(f"cannot write ({e.strerror or e})", path)
    err.errno = e.errno
    return err


def _fdopen(fd: int, mode: str, **kwargs: Any) -> IO:
    """``os.fdopen``; a seam the disk-full tests replace with a file that fills up."""
    return os.fdopen(fd, mode, **kwargs)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """Open a temp file beside ``path`` for writing; on success it replaces ``path``.

    ``mode`` is ``"wb"`` or ``"w"`` (UTF-8, ``\\n`` line endings on every platform).
    Raises :class:`WriteError` (one line, naming ``path``) when the system refuses the
    write; the previous file is then untouched and the temp file removed.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_file mode must be 'wb' or 'w', not {mode!r}")
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as e:
        raise _write_error(e, path) from None
    try:
        text = {"encoding": "utf-8", "newline": "\n"} if mode == "w" else {}
        with _fdopen(fd, mode, **text) as f:
            try:
                yield f
            except OSError as e:
                if e.errno in WRITE_ERRNOS and not isinstance(e, GripBenchError):
                    raise _write_error(e, path) from None
                raise
            try:
                f.flush()
                os.fsync(f.fileno())
            except OSError as e:
                raise _write_error(e, path) from None
        try:
            os.chmod(tmp, 0o666 & ~_UMASK)
            os.replace(tmp, path)
        except OSError as e:
            raise _write_error(e, path) from None
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_file(path, "wb") as f:
        f.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """UTF-8, ``\\n`` line endings on every platform (byte-identical outputs)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def jsonable(obj: Any) -> Any:
    """Map inputs to plain JSON types; arrays are represented by a digest of their bytes."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        digest = hashlib.sha256(a.tobytes()).hexdigest()
        return {"__ndarray__": digest, "dtype": a.dtype.str, "shape": list(a.shape)}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, bytes):
        return {"__bytes__": hashlib.sha256(obj).hexdigest()}
    return obj
