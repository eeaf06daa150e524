"""Stage unit ``perturbed``: the test split of the dataset with GRAB-T / GRAB-R noise."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ...results.layout import MAIN_SPLIT

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit


def make_perturbed(st: RunState, unit: Unit, tmp: Path) -> dict:
    """The test split of the dataset with GRAB-T / GRAB-R noise (data.perturb)."""
    from ...data.perturb import perturb_dataset

    p = unit.params
    perturb_dataset(st.data_dir(unit.deps[0]), tmp / "data", p["noise"], p["sigma"],
                    seed=st.cfg.settings["perturb_seed"], split=MAIN_SPLIT,
                    source=unit.deps[0])  # the dataset unit's key, not its cache path
    return {"perturbation": p["label"]}
