"""Shards of the ``prediction`` and ``metrics`` units (``[run] shard_sequences`` > 0).

A shard unit carries ``sequences``: test-sequence paths relative to the test set's data
folder. It predicts, or evaluates, those sequences only, with the stage functions of
``predict`` and ``evaluate``; the runner merges the shards' outputs
(``runner.pool_shard_stats``, and ``results.csv`` rows are sorted by key), which equal the
unsharded unit's since every metric is computed per sequence.

This module is separate so that unsharded units keep their keys: their code is the
closure of ``predict`` / ``evaluate`` alone, and a shard unit's code adds this module
(``bench.plan.SHARD_MODULE``). :func:`predict_unit` / :func:`evaluate_unit` pick the
function by the unit.
"""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from ...results.layout import MAIN_SPLIT
from .evaluate import _relabel, evaluate_set
from .predict import _predict_context, loaded_method, predict_files, predict_set

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit


def predict_shard(st: RunState, unit: Unit, tmp: Path) -> dict:
    """One method on the shard's sequences of one test set: a GRAB-layout folder with
    those sequences, the set's meshes and splits (as :func:`predict.predict_set`)."""
    p = unit.params
    method = loaded_method(st, p["method"], p["checkpoint"])
    in_dir = st.data_dir(p["input"])
    files = [in_dir / rel for rel in p["sequences"]]
    predict_files(method, files, in_dir, tmp, _predict_context(st, in_dir, p["perturbation"]),
                  st.cfg.progress, p["method"])
    return {"sequences": len(files)}


@contextlib.contextmanager
def ground_truth_view(gt_dir: Path, sequences: list[str]) -> Iterator[Path]:
    """A temporary folder that looks like ``gt_dir`` but holds only ``sequences``
    (symbolic links: meshes, splits, manifest and the shard's sequence files), so the
    evaluation matches the shard's predictions and nothing else."""
    with tempfile.TemporaryDirectory(prefix="grip-bench-shard-gt-") as tmp:
        view = Path(tmp) / "data"
        view.mkdir()
        for entry in sorted(gt_dir.iterdir()):
            if entry.name != "grab":
                (view / entry.name).symlink_to(entry.resolve())
        for rel in sequences:
            (view / rel).parent.mkdir(parents=True, exist_ok=True)
            (view / rel).symlink_to((gt_dir / rel).resolve())
        yield view


def evaluate_shard(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Metrics of the shard's predictions against the same sequences of the clean ground
    truth; ``evaluation.json`` describes the shard (its ground truth is the view)."""
    from ...metrics.aggregate import default_workers, evaluate_dirs
    from ...metrics.evaluate import EvalOptions

    p, s = unit.params, st.cfg.settings
    options = EvalOptions(**{k: tuple(v) if isinstance(v, list) else v
                             for k, v in p["inputs"]["options"].items()})
    workers = min(st.cfg.workers or default_workers(), len(p["sequences"]))
    with ground_truth_view(st.data_dir(p["gt"]), p["sequences"]) as gt_dir:
        info = evaluate_dirs(st.unit_dir(p["prediction"]), gt_dir, tmp,
                             method=p["labels"]["method"], metrics=p["inputs"]["metrics"],
                             per_frame=s["per_frame"], workers=workers,
                             progress=st.cfg.progress, split=MAIN_SPLIT,
                             options=options, contact_stats=True)
    for name in ("results.csv", "frames.csv"):
        _relabel(tmp / name, p["labels"])
    return {"sequences": info.get("n_sequences"), "failures": info.get("failures")}


def predict_unit(st: RunState, unit: Unit, tmp: Path) -> dict:
    """A ``prediction`` unit: a shard (it has ``sequences``) or the whole test set."""
    if unit.params.get("sequences") is not None:
        return predict_shard(st, unit, tmp)
    return predict_set(st, unit, tmp)


def evaluate_unit(st: RunState, unit: Unit, tmp: Path) -> dict:
    """A ``metrics`` unit: a shard (it has ``sequences``) or the whole prediction set."""
    if unit.params.get("sequences") is not None:
        return evaluate_shard(st, unit, tmp)
    return evaluate_set(st, unit, tmp)
