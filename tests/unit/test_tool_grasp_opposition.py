"""tools/grasp_opposition.py: the squeeze test against a linear-programme reference, the
thumb-index angle on analytic points, and the probe on the grasp fixture (a two-handed
cylinder pass squeezes, a one-handed mug lift does not)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from tests.eval_fixtures import grasp_dataset
from tools.grasp_opposition import angle_about, probe, squeezes


def _lp_squeezes(d: np.ndarray) -> bool:
    """Reference: is there w >= 0, sum w = 1, with sum w_i d_i = 0 (a feasibility LP)."""
    a = np.vstack([d.T, np.ones(len(d))])
    res = linprog(np.zeros(len(d)), A_eq=a, b_eq=[0, 0, 0, 1], bounds=(0, None), method="highs")
    return res.status == 0


def test_squeezes_on_analytic_sets():
    x = np.eye(3)
    assert squeezes(np.array([x[0], -x[0]]))  # a pinch across
    assert not squeezes(np.array([x[0], x[1], x[2]]))  # all in one octant
    assert not squeezes(x[:1])  # one contact cannot squeeze
    tetra = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]) / np.sqrt(3)
    assert squeezes(tetra)
    assert not squeezes(tetra[:3])  # the three push toward one side


def test_squeezes_matches_a_linear_programme():
    rng = np.random.default_rng(0)
    agree = []
    for k in (2, 3, 4, 6):
        for _ in range(40):
            d = rng.normal(size=(k, 3))
            d[:, 2] = np.abs(d[:, 2]) if rng.random() < 0.5 else d[:, 2]  # half one-sided
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            agree.append(squeezes(d) == _lp_squeezes(d))
    assert all(agree)


def test_angle_about_a_centre():
    c = np.array([0.1, 0.0, 0.0])
    assert angle_about(c, c + [0, 1, 0], c + [0, -2, 0]) == pytest.approx(180.0)
    assert angle_about(c, c + [1, 0, 0], c + [0, 0, 3]) == pytest.approx(90.0)


def test_probe_on_the_grasp_fixture(tmp_path):
    grasp_dataset(tmp_path, T=40)  # a one-handed mug lift, a two-handed cylinder pass
    res = probe(tmp_path, hold=True)
    assert res["frames"] > 0 and res["thumb_index_hands"] > 0
    # both hands round the cylinder push against each other; the mug's one hand does not
    assert res["squeeze_share_per_object"] == {"cylindermedium": 1.0, "mug": 0.0}
    assert 0.0 <= res["thumb_index_angle_median_deg"] <= 180.0
    # --hold: every frame tested once, grouped by squeeze, mass (both light) and hands
    groups = res["held_by_group"]
    assert set(groups) == {"squeezes, light, 2 hand(s)", "no squeeze, light, 1 hand(s)"}
    assert sum(g["frames"] for g in groups.values()) == res["frames"]
    assert groups["squeezes, light, 2 hand(s)"]["frames"] == round(
        res["squeeze_share"] * res["frames"])
    assert all(0 <= g["held"] <= g["frames"] for g in groups.values())


@pytest.mark.parametrize("tool", ["grasp_opposition", "synth_leak"])
def test_tools_fail_bad_data_with_one_line(tool, tmp_path, capsys):
    """A folder without splits.json: exit 1 and one line naming the file, no traceback."""
    import importlib

    main = importlib.import_module(f"tools.{tool}").main
    assert main([str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "splits.json" in err and err.startswith("error: ")
