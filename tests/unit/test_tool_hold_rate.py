"""tools/hold_rate.py: the summary against hand-made timings, the probe on the grasp fixture
(slow: it simulates), a one-line error on bad data and on a malformed --pred."""

from __future__ import annotations

import shutil

import pytest

from tests.eval_fixtures import grasp_dataset
from tools.hold_rate import main, probe, summarise


def test_summary_of_known_timings():
    tests = [{"scene_s": 0.3, "sim_s": 0.1, "held": True},
             {"scene_s": 0.5, "sim_s": 0.3, "held": False},
             {"scene_s": 0.1, "sim_s": 0.2, "held": False},
             {"scene_s": 0.3, "sim_s": 0.2, "held": True}]
    got = summarise(tests)  # 2.0 s in all: 1.2 building scenes, 0.8 simulating
    assert got == {"tests": 4, "held_pct": 50.0, "ms_per_test": 500.0, "scene_ms": 300.0,
                   "sim_ms": 200.0, "tests_per_s": 2.0}
    assert summarise([]) == {"tests": 0}


@pytest.mark.slow  # one scene and one simulated hold per tested frame, twice (~20 s)
def test_probe_on_the_grasp_fixture(tmp_path):
    data = tmp_path / "data"
    grasp_dataset(data, T=40)  # a one-handed mug lift, a two-handed cylinder pass
    pred = tmp_path / "pred"
    shutil.copytree(data, pred)  # the ground truth again, read as a prediction folder
    res = probe(data, preds={"copy": pred})
    assert set(res) == {"gt", "copy"} and res["gt"]["tests"] > 0
    assert res["copy"]["tests"] == res["gt"]["tests"]
    assert res["copy"]["held_pct"] == res["gt"]["held_pct"]  # the same scenes, the same verdicts
    for r in res.values():
        assert r["ms_per_test"] == pytest.approx(r["scene_ms"] + r["sim_ms"], abs=0.11)


def test_bad_data_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "splits.json" in err and err.startswith("error: ")


def test_a_pred_without_a_name_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path), "--pred", str(tmp_path)])
    assert e.value.code == 2 and "NAME=DIR" in capsys.readouterr().err
