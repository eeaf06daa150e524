"""One place that knows where each registry lives, so ``ls`` stays light.

Registries import lazily: listing must work without optional extras (smplx).
"""

from __future__ import annotations

import importlib

# kind -> (module, attribute) of a Registry whose entries have ``describe() -> str``
_SOURCES = {
    "methods": ("grip_bench.bench.methods", "load_all"),  # a loader: methods register lazily
    "metrics": ("grip_bench.metrics.registry", "METRICS"),
    "tables": ("grip_bench.bench.tables", "TABLES"),
}


def registry(kind: str):
    """The registry of ``kind``, or ``None`` while that part of the suite does not exist yet."""
    module, attr = _SOURCES[kind]
    try:
        found = getattr(importlib.import_module(module), attr)
    except ModuleNotFoundError as e:
        if e.name and module.startswith(e.name):
            return None
        raise
    return found() if callable(found) else found


def describe(kind: str) -> list[str]:
    reg = registry(kind)
    if reg is None:
        return []
    return [entry.describe() for entry in reg]
