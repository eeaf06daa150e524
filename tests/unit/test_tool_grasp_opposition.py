"""tools/grasp_opposition.py: the squeeze tests (without and with friction) on analytic
contacts and against linear-programme references, the thumb-index angle on analytic points,
and the probe on the grasp fixture (a two-handed cylinder pass squeezes without friction, a
one-handed mug lift only with it)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from tests.eval_fixtures import grasp_dataset
from tools.grasp_opposition import angle_about, probe, squeezes, squeezes_with_friction


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


def test_squeezes_with_friction_on_analytic_contacts():
    x, c = np.eye(3), np.zeros(3)
    pads = np.array([[-0.02, 0, 0], [0.02, 0, 0]])
    assert squeezes_with_friction(pads, np.array([x[0], -x[0]]), c, 0.1)  # head-on pinch
    assert not squeezes_with_friction(pads, np.array([x[1], x[1]]), c, 1.0)  # one side
    assert not squeezes_with_friction(pads[:1], x[:1], c, 1.0)  # one contact
    # each push 60 degrees off the line between the pads: inside a cone of mu = 2 (63.4
    # degrees), outside mu = 1 (45 degrees); torque-free since the forces meet on that line
    tilt = np.array([[np.cos(np.pi / 3), np.sin(np.pi / 3), 0.0],
                     [-np.cos(np.pi / 3), np.sin(np.pi / 3), 0.0]])
    assert squeezes_with_friction(pads, tilt, c, 2.0)
    assert not squeezes_with_friction(pads, tilt, c, 1.0)
    # two head-on pushes whose lines of action do not meet (offset 1 cm) make a torque
    offset = np.array([[-0.02, 0.01, 0], [0.02, -0.01, 0]])
    assert not squeezes_with_friction(offset, np.array([x[0], -x[0]]), c, 0.05)


def _lp_squeezes_with_friction(p: np.ndarray, d: np.ndarray, c: np.ndarray, mu: float) -> bool:
    """Reference: forces f_k = n_k + t_k with |t_k| <= mu (each a cone, second-order) are
    not an LP; the pyramid of 8 edges is: w >= 0, sum over edges of w e = 0 in force and
    torque, sum w = 1, written out edge by edge here."""
    rows = []
    for pk, dk in zip(p, d, strict=True):
        n = dk / np.linalg.norm(dk)
        t1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        for a in 2 * np.pi * np.arange(8) / 8:
            e = n + mu * (np.cos(a) * t1 + np.sin(a) * t2)
            rows.append(np.concatenate([e, np.cross(pk - c, e), [1.0]]))
    a_eq = np.array(rows).T
    res = linprog(np.zeros(a_eq.shape[1]), A_eq=a_eq, b_eq=[0, 0, 0, 0, 0, 0, 1],
                  bounds=(0, None), method="highs")
    return res.status == 0


def test_squeezes_with_friction_matches_a_linear_programme():
    rng = np.random.default_rng(1)
    agree = []
    for k in (2, 3, 4):
        for _ in range(30):
            p = rng.normal(scale=0.03, size=(k, 3))
            d = -p / np.linalg.norm(p, axis=1, keepdims=True) + rng.normal(scale=0.6, size=(k, 3))
            mu = float(rng.choice([0.3, 1.0]))
            agree.append(squeezes_with_friction(p, d, np.zeros(3), mu)
                         == _lp_squeezes_with_friction(p, d, np.zeros(3), mu))
    assert np.mean(agree) == 1.0


def test_angle_about_a_centre():
    c = np.array([0.1, 0.0, 0.0])
    assert angle_about(c, c + [0, 1, 0], c + [0, -2, 0]) == pytest.approx(180.0)
    assert angle_about(c, c + [1, 0, 0], c + [0, 0, 3]) == pytest.approx(90.0)


def test_probe_on_the_grasp_fixture(tmp_path, monkeypatch):
    import tools.grasp_opposition as G

    grasp_dataset(tmp_path, T=40)  # a one-handed mug lift, a two-handed cylinder pass
    # the real verdict on one frame is the metric's own (hold.hand_scene, hold.hold) ...
    from grip_bench.metrics.evaluate import object_pose, posed_hands
    from grip_bench.metrics.hold import hand_scene, hold
    from tools.probe_cli import tested_frames

    pair, frames = next(iter(tested_frames(tmp_path)))
    t = frames[0]
    scene = hand_scene(posed_hands(pair, t), pair.mesh, object_pose(pair, t), pair.options.up)
    assert G.holds(pair, t) is hold(scene, pair.options.up)[0].held
    # ... and a stand-in that holds even frames keeps the rest to the grouping (~12 s less)
    monkeypatch.setattr(G, "holds", lambda pair, t: t % 2 == 0)
    res = probe(tmp_path, hold=True)
    assert res["frames"] > 0 and res["thumb_index_hands"] > 0
    # both hands round the cylinder push against each other; the mug's one hand does not
    assert res["squeeze_share_per_object"] == {"cylindermedium": 1.0, "mug": 0.0}
    assert 0.0 <= res["thumb_index_angle_median_deg"] <= 180.0
    # with friction (and the palm) the mug's hand squeezes too
    assert res["squeeze_with_friction_share"] == 1.0
    # --hold: every frame tested once, grouped by squeeze with friction, mass (both light)
    # and the number of holding hands
    groups = res["held_by_group"]
    assert set(groups) == {"squeezes with friction, light, 2 hand(s)",
                           "squeezes with friction, light, 1 hand(s)"}
    assert sum(g["frames"] for g in groups.values()) == res["frames"]
    assert groups["squeezes with friction, light, 2 hand(s)"]["frames"] == round(
        res["squeeze_share"] * res["frames"])  # the cylinder's frames
    assert all(0 <= g["held"] <= g["frames"] for g in groups.values())
    assert 0 < sum(g["held"] for g in groups.values()) < res["frames"]


@pytest.mark.parametrize("tool", ["grasp_opposition", "synth_leak"])
def test_tools_fail_bad_data_with_one_line(tool, tmp_path, capsys):
    """A folder without splits.json: exit 1 and one line naming the file, no traceback."""
    import importlib

    main = importlib.import_module(f"tools.{tool}").main
    assert main([str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "splits.json" in err and err.startswith("error: ")
