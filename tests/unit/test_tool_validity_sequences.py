"""tools/validity_sequences.py: per-sequence responses on the grasp fixture match the validity
report's own mean and the degraded sequence evaluated by hand (draw 1); draws differ;
bad input is one error line."""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.data.grab_io import read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.metrics import validity as V
from grip_bench.metrics.evaluate import EvalOptions, evaluate_sequence
from tests.eval_fixtures import grasp_dataset
from tools.validity_sequences import main, probe


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("validity_probe")
    grasp_dataset(root, T=24)  # a one-handed mug lift, a two-handed cylinder pass
    return root


def test_per_sequence_values_are_the_reports_and_an_independent_evaluation(data):
    res = probe(data, degradation="jitter", level=0.0025, metric="mpvpe", sequences=2, draws=2)
    assert [r["sequence"] for r in res] == [
        f"{p.parent.name}/{p.stem}" for p in V.spread_over_objects(
            sorted((data / "grab").rglob("*.npz")), 2)]
    for r in res:
        assert all(v == 0.0 for v, _ in r["gt"].values() if not np.isnan(v))  # gt vs itself
        assert len(r["draws"]) == 2
    # draw 0 is the report's: its mean over sequences of the per-sequence mean of the hands
    df = V.metric_validity(str(data), sequences=2, degradations=["jitter"],
                           levels={"jitter": (0.0, 0.0025)},
                           options=EvalOptions(metrics=("mpvpe",), physics=False))
    report = df[(df.level == 2.5) & (df.metric == "mpvpe")].value.iloc[0]
    means = [np.nanmean([v for v, _ in r["draws"][0].values()]) for r in res]
    assert np.mean(means) == pytest.approx(report, rel=1e-9)
    # draw 1 by hand: degrade the file with seed 1 and score it (report units)
    lib = ObjectLibrary(data)
    path = V.spread_over_objects(sorted((data / "grab").rglob("*.npz")), 2)[0]
    gt = read_grab(path)
    rows, _ = evaluate_sequence(V.temporal_jitter(gt, 0.0025, lib, 1), gt, lib,
                                options=EvalOptions(metrics=("mpvpe",), physics=False))
    for row in rows:
        assert res[0]["draws"][1][row.hand][0] == pytest.approx(row.value, rel=1e-9)
    assert res[0]["draws"][0] != res[0]["draws"][1]  # another draw, other noise


def test_bad_input_is_one_line(tmp_path, capsys, data):
    assert main([str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error: ") and "splits.json" in err
    assert main([str(data), "--degradation", "melt"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "melt" in err
