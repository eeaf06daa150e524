"""Stage unit ``counterfactual``: the counterfactual geometry split of a SynthGRAB run
(``[run] counterfactual_sources`` > 0; docs/counterfactual.md).

Pairs of one-hand episodes of the test objects of the run's SynthGRAB profile and data seed
whose objects differ only in shape (``data.synth.counterfactual``), written as a GRAB-layout
dataset under the unit's ``data/`` with every object in ``test``, so the run's prediction
stage scores it like any test set. This module imports only the generator: the unit's code
(and so its key) is the closure of ``data.synth.counterfactual``, not of the scoring.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit


def make_counterfactual(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Write the pairs of the unit's profile, seed and source count into ``tmp/data``
    (``pairs.json``, ``splits.json``, ``manifest.json``, ``grab/``, ``tools/``); the
    record keeps the counts (pairs, twins tried and rejected, reasons). The sources run
    over the run's worker processes (``--workers``; unset: one per CPU, as the dataset
    unit's generator); the files do not depend on how many, so the count is not one of
    the unit's inputs. (No import of ``metrics.aggregate.default_workers``: the unit's
    code would then be the scoring's closure too.)"""
    from ...data.grab_io import dataset_hash
    from ...data.synth.counterfactual import counterfactual_pairs

    p = unit.params["inputs"]
    doc = counterfactual_pairs(tmp / "data", profile=p["profile"], seed=int(p["seed"]),
                               n_sources=int(p["sources"]), progress=st.cfg.progress,
                               workers=st.cfg.workers)
    return {"data_hash": dataset_hash(tmp / "data"), "counts": doc["counts"]}
