"""Object-level train / val / test splits and ``DATA/splits.json``.

Splits are by object (no object in two splits), as in GRAB and GRIP. Two schemes for
real GRAB data are built in:

- ``"grip"`` (the suite's default for real GRAB): test mug, camera, binoculars, apple,
  toothpaste; val fryingpan, toothbrush, elephant, hand; train the other 42 objects.
- ``"grab"`` (GRAB / GrabNet's default): test mug, wineglass, camera, binoculars,
  fryingpan, toothpaste; val apple, toothbrush, elephant, hand; train the other 41.

SynthGRAB chooses its own held-out instances and families and writes them with
:func:`write_splits`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..core.errors import InputError
from ..core.io import atomic_file
from .grab_io import list_sequences, read_grab_header

SPLIT_NAMES = ("train", "val", "test")
SPLITS_FILE = "splits.json"

# GRAB's 51 objects, as named in its files.
GRAB_OBJECTS: tuple[str, ...] = (
    "airplane", "alarmclock", "apple", "banana", "binoculars", "bowl", "camera", "cubelarge",
    "cubemedium", "cubesmall", "cup", "cylinderlarge", "cylindermedium", "cylindersmall",
    "doorknob", "duck", "elephant", "eyeglasses", "flashlight", "flute", "fryingpan",
    "gamecontroller", "hammer", "hand", "headphones", "knife", "lightbulb", "mouse", "mug",
    "phone", "piggybank", "pyramidlarge", "pyramidmedium", "pyramidsmall", "scissors",
    "spherelarge", "spheremedium", "spheresmall", "stamp", "stanfordbunny", "stapler", "teapot",
    "toothbrush", "toothpaste", "toruslarge", "torusmedium", "torussmall", "train", "watch",
    "waterbottle", "wineglass",
)


def _scheme(test: tuple[str, ...], val: tuple[str, ...]) -> dict[str, list[str]]:
    rest = [o for o in GRAB_OBJECTS if o not in test and o not in val]
    return {"train": rest, "val": list(val), "test": list(test)}


GRIP_SPLITS = _scheme(test=("mug", "camera", "binoculars", "apple", "toothpaste"),
                      val=("fryingpan", "toothbrush", "elephant", "hand"))
GRAB_SPLITS = _scheme(test=("mug", "wineglass", "camera", "binoculars", "fryingpan", "toothpaste"),
                      val=("apple", "toothbrush", "elephant", "hand"))
SCHEMES = {"grip": GRIP_SPLITS, "grab": GRAB_SPLITS}


def validate_splits(splits: object, where: str | os.PathLike = "splits") -> dict[str, list[str]]:
    """Check ``{"train": [...], "val": [...], "test": [...]}`` of object names; return a clean copy.

    Errors: missing or extra split names, non-string entries, duplicates, an object in two splits.
    """
    if not isinstance(splits, dict):
        raise InputError(f"should be an object with keys {list(SPLIT_NAMES)}", where)
    extra = sorted(set(splits) - set(SPLIT_NAMES))
    if extra:
        raise InputError(f"unknown split names {extra} (allowed: {list(SPLIT_NAMES)})", where)
    out: dict[str, list[str]] = {}
    owner: dict[str, str] = {}
    for name in SPLIT_NAMES:
        objects = splits.get(name)
        if not isinstance(objects, list) or not all(isinstance(o, str) and o for o in objects):
            raise InputError("should be a list of object names", f"{where}: {name}")
        for obj in objects:
            if obj in owner:
                raise InputError(f"object {obj!r} is in both {owner[obj]!r} and {name!r}",
                                 f"{where}: {name}")
            owner[obj] = name
        out[name] = list(objects)
    return out


def read_splits(data_dir: str | os.PathLike, *, default: str | None = None) -> dict[str, list[str]]:
    """``DATA/splits.json``, validated. When it is absent: the built-in scheme ``default``
    (``"grip"`` or ``"grab"``, for real GRAB downloads) or an :class:`InputError` if None."""
    path = Path(data_dir) / SPLITS_FILE
    if not path.is_file():
        if default is None:
            raise InputError("no splits.json (expected {\"train\": [...], \"val\": [...], "
                             "\"test\": [...]})", path)
        if default not in SCHEMES:
            raise InputError(
                f"unknown split scheme {default!r} (known: {sorted(SCHEMES)})", "default"
            )
        return validate_splits(SCHEMES[default])
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"not readable JSON ({e})", path) from e
    return validate_splits(data, path)


def write_splits(data_dir: str | os.PathLike, splits: dict[str, list[str]]) -> Path:
    """Validate and write ``DATA/splits.json`` atomically; return its path."""
    clean = validate_splits(splits)
    path = Path(data_dir) / SPLITS_FILE
    with atomic_file(path, "w") as f:
        json.dump(clean, f, indent=2)
        f.write("\n")
    return path


def split_of(obj_name: str, splits: dict[str, list[str]]) -> str:
    """The split holding ``obj_name``; :class:`InputError` if no split lists it."""
    for name in SPLIT_NAMES:
        if obj_name in splits.get(name, ()):
            return name
    raise InputError(f"object {obj_name!r} is in no split", "splits")


def sequences_in_split(data_dir: str | os.PathLike, split: str,
                       splits: dict[str, list[str]] | None = None) -> list[Path]:
    """Sequence files of ``DATA`` whose object is in ``split`` (reads only file headers).

    ``splits`` defaults to :func:`read_splits` of ``data_dir`` (strict: splits.json must exist).
    """
    if split not in SPLIT_NAMES:
        raise InputError(f"unknown split {split!r} (allowed: {list(SPLIT_NAMES)})", "split")
    splits = read_splits(data_dir) if splits is None else validate_splits(splits)
    wanted = set(splits[split])
    return [p for p in list_sequences(data_dir) if read_grab_header(p)["obj_name"] in wanted]
