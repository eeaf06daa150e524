"""Safe checkpoints for GRIP's networks: plain data only, checked on load.

A checkpoint is one ``torch.save`` file holding only tensors, dicts, lists, strings and
numbers, so it loads with ``torch.load(path, weights_only=True)`` (no code runs)::

    {"format": FORMAT, "models": {name: state_dict}, "configs": {name: {field: value}},
     "meta": {"suite_version", "torch_version", "data_hash", "seed", "epoch", ...}}

``load_checkpoint`` rebuilds each config, builds the network on the meta device (no
memory) and compares keys and shapes, so a wrong file fails with a readable
``InputError`` before any weight is copied.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
import typing
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import torch

from grip_bench.core.errors import InputError, UnsafeFileError

from .io import atomic_file
from .version import __version__

FORMAT = "grip-bench-checkpoint/1"
# Exact types: subclasses (torch.__version__ is a TorchVersion str) pickle as classes that
# weights_only refuses.
_PLAIN = (str, int, float, bool, type(None))
_SHOW = 5  # how many offending keys an error message names


def _check_plain(value: object, where: str) -> None:
    """Raise ``InputError`` if ``value`` holds anything ``weights_only`` would refuse."""
    if type(value) in (dict, OrderedDict):
        for k, v in value.items():
            if not isinstance(k, str | int):
                raise InputError(f"key {k!r} is a {type(k).__name__}, not str or int", where=where)
            _check_plain(v, f"{where}.{k}")
    elif type(value) in (list, tuple):
        for i, v in enumerate(value):
            _check_plain(v, f"{where}[{i}]")
    elif type(value) not in _PLAIN and type(value) is not torch.Tensor:
        raise InputError(f"cannot store a {type(value).__name__} (plain data only)", where=where)


def save_checkpoint(
    path: str | os.PathLike, *, model_state: dict, configs: dict, meta: dict | None = None
) -> Path:
    """Write a checkpoint atomically (temp file + ``os.replace``); returns the path.

    model_state: {name: state_dict}; configs: {name: config dataclass} with the same
    names; meta: plain data (data_hash, seed, epoch, optimizer state dict, ...).
    """
    path = Path(path)
    if set(model_state) != set(configs):
        raise InputError(
            f"networks {sorted(model_state)} and configs {sorted(configs)} differ", where=path
        )
    payload = {
        "format": FORMAT,
        "models": {
            name: {k: v.detach().cpu() for k, v in sd.items()} for name, sd in model_state.items()
        },
        "configs": {name: dataclasses.asdict(cfg) for name, cfg in configs.items()},
        "meta": {
            **(meta or {}),
            "suite_version": __version__,
            "torch_version": str(torch.__version__),
        },
    }
    _check_plain(payload, str(path))
    with atomic_file(path) as f:
        torch.save(payload, f)
    return path


@dataclass
class Checkpoint:
    """A loaded, checked checkpoint."""

    configs: dict  # {name: config dataclass}
    state: dict  # {name: state_dict}
    meta: dict

    def models(self) -> dict[str, torch.nn.Module]:
        """Build every network, load its weights, and put it in eval mode."""
        out = {}
        for name, cfg in self.configs.items():
            model = cfg.build()
            model.load_state_dict(self.state[name])
            out[name] = model.eval()
        return out


def _read(path: Path) -> dict:
    """``torch.load(weights_only=True)`` with every failure turned into an InputError."""
    if not path.is_file():
        raise InputError("checkpoint file not found", where=path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        # weights_only refuses arbitrary classes with an UnpicklingError naming the global.
        if "weights_only" in str(e) or "Unsupported global" in str(e):
            detail = next((ln.strip() for ln in str(e).splitlines() if "Unsupported" in ln), "")
            raise UnsafeFileError(f"holds non-plain Python objects: {detail}", where=path) from None
        raise InputError(f"not a readable torch checkpoint (corrupted?): {e}", where=path) from None
    except Exception as e:  # garbage bytes surface as anything (IndexError, KeyError, ...)
        raise InputError(
            f"not a readable torch checkpoint (truncated or corrupted?): {e}", where=path
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise InputError(
            f"not a grip-bench checkpoint (format {found!r}, expected {FORMAT!r})", where=path
        )
    for key in ("models", "configs", "meta"):
        if not isinstance(payload.get(key), dict):
            raise InputError(f"missing or malformed section {key!r}", where=path)
    return payload


def _config_from_dict(cls: type, fields: dict, where: str) -> typing.Any:
    """Rebuild a config dataclass; unknown fields and wrong types are InputErrors."""
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(fields) - known)
    if unknown:
        raise InputError(f"unknown config field(s) {unknown} for {cls.__name__}", where=where)
    hints = typing.get_type_hints(cls)
    for name, value in fields.items():
        want = hints[name]
        ok = isinstance(value, want) if want is not float else isinstance(value, int | float)
        if want is int and isinstance(value, bool):
            ok = False
        if not ok:
            raise InputError(
                f"config field {name!r} is {value!r}, expected {want.__name__}", where=where
            )
    try:
        return cls(**fields)
    except (TypeError, ValueError) as e:
        raise InputError(f"invalid config: {e}", where=where) from None


def _names(keys: Iterable[str]) -> str:
    keys = sorted(keys)
    more = f" (+{len(keys) - _SHOW} more)" if len(keys) > _SHOW else ""
    return ", ".join(keys[:_SHOW]) + more


def _check_state(cfg: typing.Any, state: dict, where: str) -> None:
    """Compare ``state`` to a fresh model's state dict: same keys, same shapes."""
    with torch.device("meta"):
        reference = cfg.build().state_dict()
    missing, unexpected = set(reference) - set(state), set(state) - set(reference)
    if missing or unexpected:
        parts = [f"missing keys: {_names(missing)}"] * bool(missing)
        parts += [f"unexpected keys: {_names(unexpected)}"] * bool(unexpected)
        raise InputError("; ".join(parts), where=where)
    for key, ref in reference.items():
        value = state[key]
        if not isinstance(value, torch.Tensor):
            raise InputError(f"{key} is a {type(value).__name__}, not a tensor", where=where)
        if value.shape != ref.shape:
            raise InputError(
                f"shape mismatch for {key}: checkpoint {tuple(value.shape)}, "
                f"model {tuple(ref.shape)}",
                where=where,
            )


def load_checkpoint(path: str | os.PathLike, expected: dict[str, type]) -> Checkpoint:
    """Load and check a checkpoint.

    expected: {network name: config class} (e.g. ``{"cnet": CNetConfig}``); networks in
    the file but not asked for are ignored. Raises ``InputError`` naming what does not
    match (file, network, config field, key, shapes).
    """
    path = Path(path)
    payload = _read(path)
    missing = sorted(
        set(expected) - set(payload["models"]) | set(expected) - set(payload["configs"])
    )
    if missing:
        raise InputError(
            f"missing network(s) {missing}; file has {sorted(payload['models'])}", where=path
        )
    configs, state = {}, {}
    for name, cls in expected.items():
        where = f"{path}: {name}"
        configs[name] = _config_from_dict(cls, payload["configs"][name], where)
        if not isinstance(payload["models"][name], dict):
            raise InputError("state dict is not a dict", where=where)
        _check_state(configs[name], payload["models"][name], where)
        state[name] = payload["models"][name]
    return Checkpoint(configs=configs, state=state, meta=payload["meta"])
