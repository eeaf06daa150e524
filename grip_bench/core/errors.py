"""Error types shared by the library and the CLI.

The CLI prints ``error: <where>: <what>`` on one line and exits 1 for any
:class:`GripBenchError`; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import os


class GripBenchError(Exception):
    """Bad input or an unmet precondition the user can fix.

    ``where`` is a file path, a field name, or both (``file: key``).
    """

    def __init__(self, what: str, where: str | os.PathLike | None = None):
        self.what = what
        self.where = None if where is None else str(where)
        super().__init__(self.message)

    @property
    def message(self) -> str:
        return f"{self.where}: {self.what}" if self.where else self.what


class InputError(GripBenchError, ValueError):
    """A file, array or argument is malformed (wrong shape, NaN, missing key...)."""


class UnsafeFileError(InputError):
    """A data file carries pickled objects that are not plain data."""


class MissingModelError(GripBenchError, FileNotFoundError):
    """Licensed body/hand model files are not where the user said they are."""
