"""One ``grip-bench run`` per output folder: an OS lock on ``OUT/.lock``.

Two runs writing one ``OUT`` would race on its summary files (``results.csv``, the
report) even though cache units are safe. The lock is ``fcntl.flock`` on ``OUT/.lock``:
the kernel drops it when its holder exits, however it dies, so a killed run never leaves a
stale lock behind. The holder writes its PID (and host) into the file so a refused run can
say who holds it; the file itself stays (removing it would race with a waiting run).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import socket
from collections.abc import Iterator
from pathlib import Path

from ..core.errors import InputError

LOCK_FILE = ".lock"


def _holder(fd: int) -> str:
    """What the holder wrote: ``PID 1234 on host``, or a phrase when it is not known yet."""
    with contextlib.suppress(OSError, UnicodeDecodeError):
        text = os.pread(fd, 200, 0).decode("utf-8").strip()
        if text:
            pid, _, host = text.partition(" ")
            return f"PID {pid}" + (f" on {host}" if host and host != socket.gethostname() else "")
    return "PID unknown"


def _open(path: Path) -> int:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    except OSError as e:
        raise InputError(f"cannot write in the output folder ({e.strerror or e})",
                         path.parent) from None


@contextlib.contextmanager
def run_lock(out: str | os.PathLike, wait: bool = False) -> Iterator[Path]:
    """Hold the lock of output folder ``out`` for the ``with`` block; yields the lock path.

    ``wait=False``: raise :class:`InputError` naming the lock file and the holder's PID
    when another process holds it; ``wait=True``: block until it is free.
    """
    path = Path(out) / LOCK_FILE
    fd = _open(path)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except OSError as e:
            if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise InputError(f"cannot lock ({e.strerror or e})", path) from None
            raise InputError(f"another grip-bench run ({_holder(fd)}) is using this output "
                             "folder; wait for it to finish or pass --wait", path) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)
        yield path
    finally:
        os.close(fd)  # closing the last descriptor releases the lock
