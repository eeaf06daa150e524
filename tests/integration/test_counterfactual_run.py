"""``grip-bench run`` with the counterfactual geometry split ([run] counterfactual_sources):
SynthGRAB's tiny data, two source episodes of its test object, two cheap methods scored on
the pairs, the table with its sanity gate in ``OUT/tables`` and in the log.

Both scored methods are blind to the object's shape: ``mean-pose`` (a fixed finger pose on
the input wrists) and ``nearest-arm`` (fingers retrieved by arm motion alone). A pair's
members share body, wrists and object motion, so each method gets the same input twice,
must output the same hands twice, and reproduces exactly 0 % of the change. About 30 s on
2 shared cores.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from grip_bench.cli.main import main
from grip_bench.data.grab_io import read_grab
from grip_bench.report.sensitivity import read_pairs_csv
from grip_bench.report.write import write_report
from tests.run_fixtures import tiny_run_profile

pytestmark = pytest.mark.slow

CF_METHODS = ["mean-pose", "nearest-arm"]


def _units(out, kind):
    return sorted((out / "cache" / kind).glob("*/*"))


def test_run_scores_the_counterfactual_split(tmp_path, capsys):
    profile = tiny_run_profile(tmp_path / "cf.toml", methods=["gt", *CF_METHODS],
                               counterfactual_sources=2, counterfactual_methods=CF_METHODS)
    out = tmp_path / "out"
    assert main(["run", "--profile", str(profile), "--out", str(out), "--quiet",
                 "--workers", "2"]) == 0
    capsys.readouterr()
    (cf_unit,) = _units(out, "counterfactual")
    doc = json.loads((cf_unit / "data" / "pairs.json").read_text(encoding="utf-8"))
    pairs = {p["id"]: p for p in doc["pairs"]}
    assert doc["sources"] == 2 and len(pairs) >= 1

    rows = read_pairs_csv(out / "sensitivity_pairs.csv")
    assert set(rows["method"]) == {"gt", "same-hands", *CF_METHODS}
    assert set(rows["pair"]) == set(pairs)
    for method in CF_METHODS:  # blind: the same hands for A and B, none of the change
        assert (rows.loc[rows["method"] == method, "reproduced"] == 0).all()
    assert (rows.loc[rows["method"] == "gt", "reproduced"] == 1).all()
    assert (rows.loc[rows["method"] == "gt", "aperture_error"] == 0).all()
    # ... because their predictions of A and B are the same (the scores read these folders)
    preds = {json.loads((u / "unit.json").read_text(encoding="utf-8"))["inputs"]["method"]: u
             for u in _units(out, "prediction")
             if json.loads((u / "unit.json").read_text(encoding="utf-8"))["inputs"]["input"]
             == cf_unit.name}
    assert sorted(preds) == CF_METHODS
    for pair in pairs.values():
        side = pair["side"]
        for folder in preds.values():
            a, b = read_grab(folder / pair["a"]), read_grab(folder / pair["b"])
            for key in ("global_orient", "hand_pose", "transl"):
                np.testing.assert_array_equal(a.hand_params(side)[key], b.hand_params(side)[key])

    md = (out / "tables" / "geometry_sensitivity.md").read_text(encoding="utf-8")
    assert md.count("- PASS:") == 3 and "FAIL" not in md
    for name in ("geometry_sensitivity.csv", "geometry_sensitivity.html"):
        assert (out / "tables" / name).is_file()
    assert '<section id="geometry_sensitivity">' in \
        (out / "leaderboard.html").read_text(encoding="utf-8")
    log = (out / "run.log").read_text(encoding="utf-8")
    assert f"geometry sensitivity: {len(pairs)} pairs, 2 method(s); sanity gate PASS" in log
    assert log.count("  PASS: ") == 3

    # the split does not leak into the main results: only the main test split's sequences
    results = (out / "results.csv").read_text(encoding="utf-8")
    assert "_cf" not in results and "counterfactual" not in results
    assert {line.split(",")[2] for line in results.splitlines()[1:]} == {"test"}

    # the report from OUT alone writes the same bytes
    tables = sorted((out / "tables").glob("geometry_sensitivity.*")) + [out / "leaderboard.html"]
    before = {p: p.read_bytes() for p in tables}
    for p in tables:
        p.unlink()
    write_report(out)
    assert {p: p.read_bytes() for p in tables} == before

    # a second run reuses every unit and writes the same table
    assert main(["run", "--profile", str(profile), "--out", str(out), "--quiet"]) == 0
    assert "sensitivity 1/1" in capsys.readouterr().out
    assert (out / "tables" / "geometry_sensitivity.md").read_text(encoding="utf-8") == md

    # turned off, the run removes the pairs file and the table of the earlier run
    off = tiny_run_profile(tmp_path / "off.toml", methods=["gt", *CF_METHODS])
    assert main(["run", "--profile", str(off), "--out", str(out), "--quiet"]) == 0
    assert not (out / "sensitivity_pairs.csv").exists()
    assert not list((out / "tables").glob("geometry_sensitivity.*"))
    assert "geometry_sensitivity" not in (out / "leaderboard.html").read_text(encoding="utf-8")
