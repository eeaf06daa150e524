"""Stage unit ``metrics``: one prediction set scored against the clean ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ...results.layout import MAIN_SPLIT

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit


def _relabel(path: Path, labels: dict) -> None:
    """Set the method / dataset / split / perturbation columns the runner owns."""
    from ...results.schema import read_results, write_results

    if path.is_file():
        df = read_results(path)
        for col, value in labels.items():
            df[col] = value
        write_results(df, path)


def evaluate_set(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Metrics of one prediction set against the clean ground truth (metrics.aggregate)."""
    from ...metrics.aggregate import default_workers, evaluate_dirs
    from ...metrics.evaluate import EvalOptions

    p, s = unit.params, st.cfg.settings
    # as planned, and part of the key (JSON-like: lists back to tuples)
    options = EvalOptions(**{k: tuple(v) if isinstance(v, list) else v
                             for k, v in p["inputs"]["options"].items()})
    info = evaluate_dirs(st.unit_dir(p["prediction"]), st.data_dir(p["gt"]), tmp,
                         method=p["labels"]["method"], metrics=p["inputs"]["metrics"],
                         per_frame=s["per_frame"], workers=st.cfg.workers or default_workers(),
                         progress=st.cfg.progress, split=MAIN_SPLIT,
                         options=options, contact_stats=True)
    for name in ("results.csv", "frames.csv"):
        _relabel(tmp / name, p["labels"])
    return {"sequences": info.get("n_sequences"), "failures": info.get("failures")}
