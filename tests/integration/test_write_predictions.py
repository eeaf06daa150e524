"""Predictions written elsewhere (docs/predictions.md): the doc's snippet and
``examples/write_predictions.py`` write folders that ``grip-bench evaluate`` scores, with
the expected values; a prediction of another body model is refused in one line."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

from grip_bench.cli.main import main
from grip_bench.core.safe_pickle import load_npz
from grip_bench.data.grab_io import list_sequences, read_grab
from grip_bench.data.splits import write_splits
from tests.eval_fixtures import grasp_dataset
from tests.hostile_fixtures import write_members

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "predictions.md"


@pytest.fixture(scope="module")
def gt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """DATA with the mug in test (one sequence) and the cylinder in train."""
    root = tmp_path_factory.mktemp("pred-gt") / "DATA"
    grasp_dataset(root, T=30)
    write_splits(root, {"train": ["cylindermedium"], "val": [], "test": ["mug"]})
    return root


@pytest.fixture(scope="module")
def writer():
    spec = importlib.util.spec_from_file_location("_write_predictions",
                                                  REPO / "examples" / "write_predictions.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _results(capsys: pytest.CaptureFixture[str], pred: Path, gt: Path, out: Path) -> dict:
    """{(hand, metric): value} of ``evaluate`` on MPVPE and MPJPE."""
    import csv

    rc = main(["evaluate", "--pred", str(pred), "--gt", str(gt), "--out", str(out),
               "--metrics", "mpvpe,mpjpe", "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    with open(out / "results.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    return {(r["hand"], r["metric"]): float(r["value"]) for r in rows} | {
        "method": rows[0]["method"], "perturbation": rows[0]["perturbation"]}


def test_the_docs_snippet_writes_what_evaluate_scores(gt: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    (snippet,) = re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    (tmp_path / "DATA").symlink_to(gt, target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    exec(compile(snippet, str(DOC), "exec"), {"__name__": "snippet"})
    pred = tmp_path / "preds" / "my-method"
    assert [p.relative_to(pred) for p in list_sequences(pred)] == [
        Path("grab/s1/mug_lift_1.npz")]  # the test split only, at the GT's relative path
    res = _results(capsys, pred, gt, tmp_path / "eval")
    assert res["method"] == "my-method" and res["perturbation"] == "none"
    for hand in ("right", "left"):  # the ground truth's own hands: no error
        assert res[(hand, "mpvpe")] == pytest.approx(0.0, abs=1e-6)


def test_the_example_script_writes_numpy_hands(gt: Path, tmp_path: Path, writer,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert writer.main([str(gt), str(tmp_path / "as-gt"), "--method", "as-gt"]) == 0
    assert json.loads((tmp_path / "as-gt" / "manifest.json").read_text())["method"] == "as-gt"
    # a method whose right wrist is 1 cm off along x, its left hand the ground truth's
    pred = tmp_path / "shifted"
    (gt_file,) = [p for p in list_sequences(gt) if "mug" in p.name]
    seq = read_grab(gt_file)
    right = {k: np.array(v) for k, v in seq.hand_params("right").items()
             if k in writer.HAND_KEYS}
    right["transl"] = right["transl"] + [0.01, 0.0, 0.0]
    written = writer.write_prediction(gt_file, gt, pred, {"right": right})
    assert written == pred / gt_file.relative_to(gt)
    writer.write_manifest(pred, "shifted", perturbation="T0.01")
    res = _results(capsys, pred, gt, tmp_path / "eval")
    assert res["perturbation"] == "T0.01"
    assert res[("right", "mpvpe")] == pytest.approx(10.0, abs=1e-6)  # mm: a rigid 1 cm shift
    assert res[("right", "mpjpe")] == pytest.approx(10.0, abs=1e-6)
    assert res[("left", "mpvpe")] == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError, match="unknown hand keys"):
        writer.write_prediction(gt_file, gt, pred, {"right": {"fullpose": right["transl"]}})


def test_a_prediction_of_another_body_model_is_refused(gt: Path, tmp_path: Path, writer,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    pred = tmp_path / "pred"
    writer.main([str(gt), str(pred)])
    (path,) = list_sequences(pred)
    members = dict(load_npz(path))
    members["body_model"] = np.asarray("smplx")
    members["hand_transl"] = np.asarray("wrist")
    write_members(path, members)
    out = tmp_path / "eval"
    rc = main(["evaluate", "--pred", str(pred), "--gt", str(gt), "--out", str(out),
               "--metrics", "mpvpe", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and err[-1].startswith(f"error: {path}: body model 'smplx', but the "
                                          "ground truth"), err
    assert err[-1].endswith("has 'procedural'")
    assert not (out / "results.csv").exists()
