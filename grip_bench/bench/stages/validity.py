"""Stage unit ``validity``: each metric's response to controlled degradations of the
dataset's ground truth (``metrics.validity``), as ``validity.csv``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit

VALIDITY_FILE = "validity.csv"


def measure_validity(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Degrade ``sequences`` test sequences (spread over the objects) at every level and
    evaluate each level against the ground truth; the options, levels, seed and split are
    the unit's inputs.
    The evaluations run in the evaluation stage's process pool (the same values for any
    number of workers, so ``--workers`` is not part of the key)."""
    from ...core.io import atomic_write_text
    from ...metrics.aggregate import default_workers
    from ...metrics.evaluate import EvalOptions
    from ...metrics.validity import check_validity, metric_validity

    p = unit.params["inputs"]
    # as planned, and part of the key (JSON-like: lists back to tuples)
    options = EvalOptions(**{k: tuple(v) if isinstance(v, list) else v
                             for k, v in p["options"].items()})
    df = metric_validity(str(st.data_dir(p["data"])), p["split"], int(p["sequences"]),
                         int(p["seed"]), options, degradations=list(p["levels"]),
                         progress=st.cfg.progress, levels=p["levels"],
                         workers=st.cfg.workers or default_workers())
    atomic_write_text(tmp / VALIDITY_FILE, df.to_csv(index=False))
    return {"sequences": int(df["n_sequences"].max()), "broken_claims": check_validity(df)}
