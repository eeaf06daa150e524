"""One place that knows where each registry lives, so ``ls`` stays light.

Registries import lazily: listing must work without optional extras (smplx). Which tables
show a method is read from the table files (``grip_bench/report/tables/*.toml``), the one
home of that fact.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..core.registry import Registry

# kind -> (module, attribute) of a Registry whose entries have ``describe() -> str``
_SOURCES = {
    "methods": ("grip_bench.methods.api", "load_all"),  # a loader: methods register lazily
    "metrics": ("grip_bench.metrics.registry", "METRICS"),
    "tables": ("grip_bench.report.tables", "TABLES"),
}


def registry(kind: str) -> Registry[Any] | None:
    """The registry of ``kind``, or ``None`` while that part of the suite does not exist yet."""
    module, attr = _SOURCES[kind]
    try:
        found = getattr(importlib.import_module(module), attr)
    except ModuleNotFoundError as e:
        if e.name and module.startswith(e.name):
            return None
        raise
    return found() if callable(found) else found


def method_tables() -> dict[str, tuple[str, ...]]:
    """``{method: ids of the tables that show it}``, from the table files."""
    tables = registry("tables")
    shown: dict[str, list[str]] = {}
    for tid in tables.names():
        for method in tables.get(tid).methods():
            shown.setdefault(method, []).append(tid)
    return {m: tuple(ids) for m, ids in shown.items()}


def describe(kind: str) -> list[str]:
    reg = registry(kind)
    if reg is None:
        return []
    if kind == "methods":
        shown = method_tables()
        return [entry.describe(shown.get(entry.name, ())) for entry in reg]
    return [entry.describe() for entry in reg]
