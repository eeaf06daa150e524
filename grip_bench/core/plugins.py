"""Installed plug-ins: modules named by entry points of the ``grip_bench.*`` groups.

Three groups (docs/architecture.md, "How to add a method/metric/table"):

- ``grip_bench.methods``: a module whose import registers methods (``methods.api``);
- ``grip_bench.metrics``: a module whose import registers metrics with
  ``metrics.registry.metric`` (``metrics.registry``);
- ``grip_bench.tables``: a package whose resource folder holds table ``*.toml`` files, or
  ``module:attribute`` naming table paths (``report.tables``).

A plug-in that fails is an :class:`InputError` naming its module and group, never a
traceback. Plug-in code is part of the cache keys of the units it affects
(``bench.codehash.installed_roots``, ``bench.plan.stage_code``).
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from types import ModuleType

from .errors import InputError

METHODS_GROUP = "grip_bench.methods"
METRICS_GROUP = "grip_bench.metrics"
TABLES_GROUP = "grip_bench.tables"
GROUPS = (METHODS_GROUP, METRICS_GROUP, TABLES_GROUP)


def entry_values(group: str) -> list[str]:
    """The values (``module`` or ``module:attribute``) of ``group``'s entry points, sorted."""
    return sorted({ep.value.strip() for ep in entry_points(group=group)})


def plugin_modules(group: str) -> list[str]:
    """Modules named by installed entry points of ``group``, sorted."""
    return sorted({v.split(":")[0].strip() for v in entry_values(group)})


def import_plugin(module: str, group: str) -> ModuleType:
    """Import a plug-in module; any failure is one :class:`InputError` naming it."""
    try:
        return importlib.import_module(module)
    except InputError as e:  # already one line: say which plug-in raised it
        raise InputError(f"plug-in module {module!r} failed: {e.message}",
                         f"entry points {group}") from e
    except Exception as e:  # noqa: BLE001 - any failure of third-party code
        raise InputError(f"plug-in module {module!r} failed to import: "
                         f"{type(e).__name__}: {e}", f"entry points {group}") from e


def load_group(group: str) -> list[ModuleType]:
    """Import every module of ``group`` (for groups whose import registers entries)."""
    return [import_plugin(m, group) for m in plugin_modules(group)]


def plugin_top_packages() -> list[str]:
    """Top-level packages of every installed plug-in of every group (their code is hashed)."""
    return sorted({m.split(".")[0] for g in GROUPS for m in plugin_modules(g)})
