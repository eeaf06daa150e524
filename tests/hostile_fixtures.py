"""Hostile sequence files for the hostile-input and fuzzing tests (docs/hostile_inputs.md).

Everything starts from a valid GRAB-layout file written by ``write_grab`` (the tiny random
:func:`tests.grab_fixtures.make_sequence`), read back member by member with the safe loader,
changed, and written again with plain ``np.savez`` (object arrays pickled as GRAB does).
"""

from __future__ import annotations

import copy
import os
from pathlib import Path
from typing import Any

import numpy as np

from grip_bench.core.safe_pickle import load_npz
from grip_bench.data.grab_io import write_grab
from tests.grab_fixtures import make_sequence

# The members of a sequence file stored as 0-d object arrays (pickled dicts).
OBJECT_FIELDS = ("body", "rhand", "lhand", "object", "table", "contact")


class Payload:
    """Unpickling this would run ``os.system('touch <marker>')``: the marker proves it ran."""

    def __init__(self, marker: str | os.PathLike):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch '{self.marker}'",))

    # copy.deepcopy goes through __reduce__ too, and would run the command: copies are self
    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self


def valid_members(T: int = 12, seed: int = 0) -> dict[str, Any]:
    """The members of a valid sequence file (dicts unwrapped), as ``load_npz`` returns them."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = write_grab(make_sequence(T, seed=seed), Path(tmp) / "seq.npz")
        return load_npz(path)


def _wrap(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value
    if isinstance(value, str | int | float | bool | np.generic):
        return np.asarray(value)
    a = np.empty((), dtype=object)  # dicts, lists, arbitrary objects: pickled like GRAB's dicts
    a[()] = value
    return a


def write_members(path: str | os.PathLike, members: dict[str, Any]) -> Path:
    """Write ``members`` with plain ``np.savez`` (non-arrays as 0-d object arrays)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        np.savez(f, **{k: _wrap(v) for k, v in members.items()})
    return path


def edited(members: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """A deep copy of ``members`` with ``dotted`` (``body.params.transl``) set to ``value``;
    ``value=DELETE`` removes the entry."""
    out = copy.deepcopy(members)
    *parents, last = dotted.split(".")
    node = out
    for p in parents:
        node = node[p]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return out


DELETE = object()


def hostile_file(path: str | os.PathLike, dotted: str, value: Any, T: int = 12) -> Path:
    """A valid file with one entry replaced (or deleted with ``DELETE``)."""
    return write_members(path, edited(valid_members(T), dotted, value))
