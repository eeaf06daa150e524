"""``grip-bench evaluate``: results files, determinism, one-line errors on mismatched folders."""

import json
import math
import shutil

import numpy as np
import pytest

from grip_bench.cli.main import main
from grip_bench.data.grab_io import read_grab, write_grab
from grip_bench.results.schema import FRAME_COLUMNS, RESULT_COLUMNS, read_results
from tests.eval_fixtures import grasp_dataset

FAST = "mpjpe,mpvpe,cc,contact_drift,contact_ratio,pen_depth,jitter,accel_err"
MUG = "grab/s1/mug_lift_1.npz"


@pytest.fixture(scope="module")
def gt(tmp_path_factory):
    root = tmp_path_factory.mktemp("gt")
    grasp_dataset(root, T=30)  # lifted from frame 16: 4 held frames after the 5-frame trims
    return root


@pytest.fixture
def pred(gt, tmp_path):
    """A prediction folder: a copy of the ground truth's sequences (GT evaluated against itself)."""
    out = tmp_path / "pred"
    shutil.copytree(gt / "grab", out / "grab")
    return out


def _evaluate(pred, gt, out, *extra):
    return main(
        [
            "evaluate",
            "--pred",
            str(pred),
            "--gt",
            str(gt),
            "--out",
            str(out),
            "--no-progress",
            *extra,
        ]
    )


def test_gt_against_itself_writes_tidy_results(gt, pred, tmp_path, capsys):
    out = tmp_path / "out"
    assert _evaluate(pred, gt, out, "--metrics", FAST, "--per-frame", "--method", "oracle") == 0
    assert "evaluated 2 sequence(s)" in capsys.readouterr().out
    header = (out / "results.csv").read_text().splitlines()[0]
    assert header == ",".join(RESULT_COLUMNS)
    df = read_results(out / "results.csv")
    assert set(df["method"]) == {"oracle"} and set(df["dataset"]) == {"fixture"}
    assert set(df["split"]) == {"test"} and set(df["perturbation"]) == {"none"}
    assert len(df) == 2 * 2 * len(FAST.split(","))
    units = dict(zip(df["metric"], df["unit"], strict=False))
    assert units == {
        "mpjpe": "mm",
        "mpvpe": "mm",
        "cc": "mm",
        "contact_drift": "mm",
        "contact_ratio": "%",
        "pen_depth": "mm",
        "jitter": "m/s2",
        "accel_err": "m/s2",
    }
    zero = df[df["metric"].isin(["mpjpe", "mpvpe", "cc", "contact_drift", "accel_err"])]
    assert all(
        v == 0.0 or (math.isnan(v) and n == 0)
        for v, n in zip(zero["value"], zero["n_frames"], strict=True)
    )
    ratio = df[(df["metric"] == "contact_ratio") & (df["hand"] == "right")]
    assert list(ratio["value"]) == [100.0, 100.0]
    frames = read_results(out / "frames.csv")
    assert tuple(frames.columns) == FRAME_COLUMNS and "accel_err" in set(frames["metric"])
    info = json.loads((out / "evaluation.json").read_text())
    assert info["n_sequences"] == 2 and info["failures"]["count"] == 0
    assert len(info["gt_dataset_hash"]) == 64


def test_runs_are_byte_identical_for_any_worker_count(gt, pred, tmp_path):
    outs = [tmp_path / f"out{i}" for i in range(3)]
    # physics is left out: its CoACD decomposition would run again in every worker (seconds)
    args = ("--metrics", "mpjpe,cc,contact_drift,iv,pen_depth,jitter", "--per-frame")
    assert _evaluate(pred, gt, outs[0], *args) == 0
    assert _evaluate(pred, gt, outs[1], *args) == 0
    assert _evaluate(pred, gt, outs[2], *args, "--workers", "2") == 0
    for name in ("results.csv", "frames.csv"):
        first = (outs[0] / name).read_bytes()
        assert (outs[1] / name).read_bytes() == first and (outs[2] / name).read_bytes() == first


def test_perturbation_comes_from_the_prediction_manifest(gt, pred, tmp_path):
    (pred / "manifest.json").write_text(json.dumps({"perturbation": "T0.01"}))
    assert _evaluate(pred, gt, tmp_path / "out", "--metrics", "mpjpe") == 0
    assert set(read_results(tmp_path / "out" / "results.csv")["perturbation"]) == {"T0.01"}


def _assert_one_line_error(capsys, out, *needles):
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err
    for n in needles:
        assert n in err
    assert not out.exists()


def test_missing_prediction(gt, pred, tmp_path, capsys):
    (pred / MUG).unlink()
    out = tmp_path / "out"
    assert _evaluate(pred, gt, out) == 1
    _assert_one_line_error(capsys, out, "1 ground-truth sequence(s)", MUG)


def test_extra_prediction(gt, pred, tmp_path, capsys):
    shutil.copy(pred / MUG, pred / "grab/s1/mug_lift_9.npz")
    out = tmp_path / "out"
    assert _evaluate(pred, gt, out) == 1
    _assert_one_line_error(capsys, out, "no ground-truth sequence", "grab/s1/mug_lift_9.npz")


def test_different_frame_count(gt, pred, tmp_path, capsys):
    write_grab(read_grab(gt / MUG).frames(0, 9), pred / MUG)
    out = tmp_path / "out"
    assert _evaluate(pred, gt, out) == 1
    _assert_one_line_error(capsys, out, str(pred / MUG), "9 frames", "has 30")


def test_different_object(gt, pred, tmp_path, capsys):
    seq = read_grab(gt / MUG)
    seq.obj_name = "cylindermedium"
    write_grab(seq, pred / MUG)
    out = tmp_path / "out"
    assert _evaluate(pred, gt, out) == 1
    _assert_one_line_error(capsys, out, str(pred / MUG), "'cylindermedium'", "'mug'")


def test_unknown_metric_and_bad_split(gt, pred, tmp_path, capsys):
    out = tmp_path / "out"
    assert _evaluate(pred, gt, out, "--metrics", "mpjpe,volume") == 1
    _assert_one_line_error(capsys, out, "unknown metric(s) volume")
    assert _evaluate(pred, gt, out, "--split", "holdout") == 1
    _assert_one_line_error(capsys, out, "unknown split")


def test_empty_split_is_an_error(gt, pred, tmp_path, capsys):
    out = tmp_path / "out"
    assert _evaluate(pred, gt, out, "--split", "train") == 1
    _assert_one_line_error(capsys, out, "no ground-truth sequences in split 'train'")


def test_help_lists_metrics_and_masks(capsys):
    with pytest.raises(SystemExit) as e:
        main(["evaluate", "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    for token in ("mpjpe", "contact_drift", "hold_sim", "held", "4.5 mm", "--per-frame"):
        assert token in text


def test_prediction_shifted_by_5mm(gt, pred, tmp_path):
    seq = read_grab(gt / MUG)
    seq.rhand["transl"] = seq.rhand["transl"] + np.array([0.0, 0.003, 0.004])
    write_grab(seq, pred / MUG)
    out = tmp_path / "out"
    assert _evaluate(pred, gt, out, "--metrics", "mpjpe,mpvpe") == 0
    df = read_results(out / "results.csv")
    mug = df[df["object"] == "mug"].set_index(["hand", "metric"])["value"]
    assert mug["right", "mpjpe"] == pytest.approx(5.0, abs=1e-6)
    assert mug["right", "mpvpe"] == pytest.approx(5.0, abs=1e-6)
    assert mug["left", "mpjpe"] == 0.0
