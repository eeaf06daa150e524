"""Stage unit ``sensitivity``: the per-pair scores of the counterfactual split
(``report.sensitivity.score_pairs``) for the run's prediction folders of that split, with
the reference rows ``gt`` and ``same-hands``, as ``sensitivity_pairs.csv``.

Separate from ``stages.counterfactual`` so that the split's dataset unit does not depend on
the scoring code (an edit of the metrics renews this unit, not the pairs or predictions).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit

PAIRS_FILE = "sensitivity_pairs.csv"


def score_sensitivity(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Score every pair of the unit's counterfactual dataset for each prediction unit
    (``predictions``: method -> prediction unit key) and the reference rows; the rows
    (SI units, ``report.sensitivity.SCORE_COLUMNS``) go to ``tmp/sensitivity_pairs.csv``.
    A split without pairs (every twin rejected) gives a file with a header only."""
    from ...metrics.aggregate import default_workers
    from ...report.sensitivity import read_pairs_doc, score_pairs, write_pairs_csv

    p = unit.params
    data = st.data_dir(p["data"])
    n_pairs = len(read_pairs_doc(data)["pairs"])
    rows = score_pairs(data, {m: st.unit_dir(k) for m, k in p["predictions"].items()},
                       p["inputs"]["model_path"],
                       workers=st.cfg.workers or default_workers()) if n_pairs else None
    write_pairs_csv(tmp / PAIRS_FILE, rows)
    return {"pairs": n_pairs, "methods": sorted(p["predictions"])}
