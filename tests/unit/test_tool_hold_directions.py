"""tools/hold_directions.py: the direction labels on analytic points, the summary against a
naive count, the probe on the grasp fixture (slow: it simulates), a one-line error on bad
data."""

from __future__ import annotations

import numpy as np
import pytest

from tests.eval_fixtures import grasp_dataset
from tools.hold_directions import LABELS, label, main, probe, summarise


def test_label_by_the_angle_to_the_palm():
    com, palm = np.zeros(3), np.array([0.0, 0.05, 0.0])  # the palm above the object
    assert label(np.array([0.0, 9.8, 0.0]), com, palm) == "toward"  # pulled into the palm
    assert label(np.array([0.0, -9.8, 0.0]), com, palm) == "away"
    assert label(np.array([9.8, 0.0, 0.0]), com, palm) == "across"
    assert label(np.array([9.8, 9.8, 0.0]), com, palm) == "toward"  # 45 degrees: cos 0.71
    assert label(np.array([9.8, -5.0, 0.0]), com, palm) == "across"  # cos -0.45
    assert label(np.array([0.0, 9.8, 0.0]), com, None) == "two hands"


def test_summary_matches_a_naive_count():
    rng = np.random.default_rng(0)
    directions = ["world", "+x", "-x", "+y", "-y", "+z", "-z"]
    rows = [{"sequence": f"s{i % 5}", "frame": i // 5, "direction": d,
             "label": LABELS[rng.integers(4)], "held": bool(rng.random() < 0.4)}
            for i in range(30) for d in directions]
    got = summarise(rows)
    assert got["frames"] == 30
    for which, dirs in (("world", ["world"]), ("axes", directions[1:])):
        sel = [r for r in rows if r["direction"] in dirs]
        assert got[which]["n"] == len(sel)
        assert got[which]["held_pct"] == round(100 * sum(r["held"] for r in sel) / len(sel), 1)
        for lab in LABELS:
            part = [r["held"] for r in sel if r["label"] == lab]
            assert got[which][lab]["n"] == len(part)
            if part:
                assert got[which][lab]["held_pct"] == round(100 * sum(part) / len(part), 1)


@pytest.mark.slow  # simulates 7 gravity directions of every tested frame (~1 min)
def test_probe_on_the_grasp_fixture(tmp_path):
    grasp_dataset(tmp_path, T=40)  # a one-handed mug lift, a two-handed cylinder pass
    res = probe(tmp_path)
    assert res["frames"] > 0 and res["axes"]["n"] == 6 * res["world"]["n"]
    assert res["world"]["two hands"]["n"] > 0  # the cylinder pass
    assert sum(res["axes"][lab]["n"] for lab in LABELS) == res["axes"]["n"]


def test_bad_data_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "splits.json" in err and err.startswith("error: ")
