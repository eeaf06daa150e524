"""Hyper-parameter profiles as data: ``smoke``, ``default``, ``paper``, ``ablation`` (one TOML
file each).

A profile is a TOML file of sections (``[grip]``, later ``[data]``, ``[grabnet]``, ...).
The loader is generic: the allowed keys of each section and their types are those of the
``default`` profile, so a typo in any profile (or in a user's own file) is an
:class:`InputError` naming the file and the key instead of a silently ignored value.
"""

from __future__ import annotations

import difflib
import tomllib
from pathlib import Path

from ..core.errors import InputError

PROFILE_DIR = Path(__file__).parent
NAMES = ("smoke", "default", "paper", "ablation")
_SCHEMA = "default"  # the profile whose keys and types every profile must follow


def profile_path(name: str | Path) -> Path:
    """Path of a built-in profile name or of a user's ``.toml`` file."""
    if str(name) in NAMES:
        return PROFILE_DIR / f"{name}.toml"
    path = Path(name)
    if path.suffix == ".toml" and path.is_file():
        return path
    raise InputError(f"unknown profile {str(name)!r} (known: {', '.join(NAMES)}, or a .toml file)",
                     "profile")


def _read(path: Path) -> dict:
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise InputError(f"not a readable TOML profile ({_one_line(e)})", path) from None


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())


def _type_name(value: object) -> str:
    """TOML's name for the type of ``value`` (what the user wrote, not Python's)."""
    names = {bool: "boolean", int: "integer", float: "float", str: "string", list: "array",
             dict: "table"}
    return next((n for t, n in names.items() if type(value) is t), type(value).__name__)


def _a(noun: str) -> str:
    return f"{'an' if noun[0] in 'aeiou' else 'a'} {noun}"


def _type_ok(value: object, ref: object) -> bool:
    if isinstance(ref, bool) or isinstance(value, bool):
        return type(value) is type(ref)
    if isinstance(ref, float):
        return isinstance(value, int | float)
    if isinstance(ref, list):
        return isinstance(value, list)
    return isinstance(value, type(ref))


def _did_you_mean(name: str, known: object) -> str:
    """`` (did you mean 'x'?)`` for a close known name (a typo), else ``""``."""
    close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def validate_profile(data: dict, schema: dict, where: Path) -> dict:
    """Check ``data``'s sections and keys against ``schema``; return a copy with floats fixed."""
    out = {}
    for section, values in data.items():
        if section not in schema:
            hint = _did_you_mean(section, schema) or f" (known: {', '.join(sorted(schema))})"
            raise InputError(f"unknown section [{section}]{hint}", f"{where}: [{section}]")
        if not isinstance(values, dict):
            raise InputError(f"[{section}] should be a table of keys", where)
        out[section] = {}
        for key, value in values.items():
            if key not in schema[section]:
                raise InputError(f"unknown key {key!r} in [{section}]"
                                 f"{_did_you_mean(key, schema[section])}",
                                 f"{where}: {section}.{key}")
            ref = schema[section][key]
            if not _type_ok(value, ref):
                raise InputError(f"{value!r} should be {_a(_type_name(ref))}, not "
                                 f"{_a(_type_name(value))}", f"{where}: {section}.{key}")
            out[section][key] = float(value) if isinstance(ref, float) else value
    return out


# Keys added after profiles were in users' hands: a profile without them gets the default's
# value (or, for OFF_WHEN_ABSENT, its off value).
OPTIONAL_KEYS = {"grip": ("anet_max_train_frames",),
                 "run": ("averaging", "validity_sequences", "viewer_sequences",
                         "shard_sequences", "train_nproc", "seeds", "capture_noise",
                         "counterfactual_sources", "counterfactual_methods")}
# Optional keys whose absence means "off", not the default profile's value: the default
# profile turns the counterfactual split on (minutes of generation), and a profile written
# before the key existed keeps planning exactly the units it planned.
OFF_WHEN_ABSENT = {"run": {"counterfactual_sources": 0}}


def load_profile(name: str | Path = "default") -> dict:
    """``{section: {key: value}}`` of a profile, validated against the default profile's keys.

    Sections missing from a profile are taken whole from the default profile, so later
    issues can add sections to ``default.toml`` first.
    """
    schema_path = PROFILE_DIR / f"{_SCHEMA}.toml"
    schema = _read(schema_path)
    path = profile_path(name)
    data = validate_profile(_read(path), schema, path)
    for section, values in schema.items():
        data.setdefault(section, dict(values))
        for key in OPTIONAL_KEYS.get(section, ()):
            data[section].setdefault(key, OFF_WHEN_ABSENT.get(section, {}).get(key, values[key]))
        missing = sorted(set(values) - set(data[section]))
        if missing:
            raise InputError(f"missing key(s) {missing} in [{section}]", path)
    data["name"] = path.stem
    return data
