"""grip-bench baselines (GrabNet-, TOCH-, ManipNet-style and reference rows).

Lives in the top-level ``baselines/`` folder of the repository and is imported as
``grip_baselines`` so that it cannot collide with other installed packages.
"""

from __future__ import annotations

import importlib
from typing import Any

# Public names -> submodule. Resolved on first access so that importing the package
# stays cheap (no torch / igl until a model or feature function is used).
_EXPORTS = {
    "basis_points": "bps",
    "bps_encode": "bps",
    "bps_encode_many": "bps",
    "object_centre": "bps",
    "CoarseNet": "grabnet",
    "CoarseNetConfig": "grabnet",
    "GrabNetLossConfig": "grabnet",
    "GraspParams": "grabnet",
    "RefineNet": "grabnet",
    "RefineNetConfig": "grabnet",
    "grabnet_losses": ("grabnet", "losses"),
    "CorrespondenceField": "toch",
    "FitConfig": "toch",
    "TemporalAE": "toch",
    "TemporalAEConfig": "toch",
    "correspondence_field": "toch",
    "field_losses": "toch",
    "fit_hand_to_field": "toch",
    "ManipNet": "manipnet",
    "ManipNetConfig": "manipnet",
    "manipnet_features": "manipnet",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    target = _EXPORTS.get(name)
    if target is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module, attr = target if isinstance(target, tuple) else (target, name)
    value = getattr(importlib.import_module(f"{__name__}.{module}"), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
