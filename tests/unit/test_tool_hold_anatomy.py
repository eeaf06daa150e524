"""tools/hold_anatomy.py: grasp labels from SynthGRAB's manifest, the summaries by label and
by sequence against hand-made rows, the force reading against an analytic pinch, the contacts
of a constructed pinch through the settle (slow: it simulates) and a one-line error on bad
data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tools.hold_anatomy import by_sequence, contacts_through, grasp_labels, main, summarise


def test_grasp_labels_from_the_manifest(tmp_path):
    assert grasp_labels(tmp_path) == {}  # real GRAB: no manifest
    (tmp_path / "manifest.json").write_text(json.dumps({"sequences": {
        "grab/s1/a.npz": {"grasps": {"right": "power"}},
        "grab/s2/b.npz": {"grasps": {"right": "precision", "left": "tripod"}},
        "grab/s3/c.npz": {"grasps": {}}}}))
    assert grasp_labels(tmp_path) == {"grab/s1/a.npz": "r:power",
                                      "grab/s2/b.npz": "l:tripod+r:precision",
                                      "grab/s3/c.npz": "?"}


def test_summary_by_grasp_label():
    def row(g, held, start, settled, after):
        return {"grasps": g, "held": held, "start": start, "settled": settled, "after": after}

    rows = [row("r:power", True, 40, 30, 30), row("r:power", False, 10, 2, 0),
            row("r:power", False, 12, 4, 0), row("r:tripod", True, 5, 7, 7)]
    s = summarise(rows)
    assert s["r:power"]["frames"] == 3 and s["r:power"]["held"] == 1
    assert s["r:power"]["dropped_contacts"] == {"start": 11.0, "settled": 3.0, "after": 0.0}
    assert s["r:power"]["held_contacts"] == {"start": 40.0, "settled": 30.0, "after": 30.0}
    assert s["r:tripod"]["dropped_contacts"] is None
    assert s["all"]["frames"] == 4 and s["all"]["held"] == 2
    assert summarise([]) == {"all": {"frames": 0, "held": 0, "held_contacts": None,
                                     "dropped_contacts": None}}


def test_by_sequence_splits_the_plans_force_by_verdict():
    def rows(seq, held, plans):
        return [{"sequence": seq, "held": h, "plan_weights": p} for h, p in zip(held, plans,
                                                                            strict=True)]

    r = (rows("a", [True, True], [0.1, 0.3]) + rows("b", [True, False], [0.5, 0.7])
         + rows("c", [False, False], [2.0, float("inf")]) + rows("d", [False], [float("nan")]))
    s = by_sequence(r)
    assert s["held"] == {"sequences": 2, "plan_weights": pytest.approx(0.4)}  # 0.2 and 0.6
    # c's median is inf (no plan on one of two frames); d has no reading: counted, no median
    assert s["failed"] == {"sequences": 2, "plan_weights": float("inf")}
    assert by_sequence([]) == {"held": {"sequences": 0, "plan_weights": None},
                               "failed": {"sequences": 0, "plan_weights": None}}


def test_the_plans_force_of_a_friction_pinch_is_half_the_weight():
    """The quantity ``plan_weights`` reads (``plan_forces``' largest normal force over the
    weight): two opposed pads on a box's sides carry its weight by friction alone, so at
    mu = 1 each presses at least half the weight; with a third pad under the box the least
    largest force shares the weight three ways (the bottom pad's normal and each side's
    friction a third, the sides pressing a third so that friction can)."""
    from grip_bench.geometry.wrench import plan_forces

    com, weight = np.zeros(3), np.array([0.0, -1.0, 0.0])
    pts = np.array([[-0.02, 0.0, 0.0], [0.02, 0.0, 0.0]])
    inward = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])  # hand -> object
    f = plan_forces(pts, inward, com, weight, 1.0, edges=8)
    assert np.max(np.einsum("kc,kc->k", f, inward)) == pytest.approx(0.5, rel=1e-6)
    three = np.vstack([inward, [[0.0, 1.0, 0.0]]])
    f = plan_forces(np.vstack([pts, [[0.0, -0.02, 0.0]]]), three, com, weight, 1.0, edges=8)
    assert np.einsum("kc,kc->k", f, three) == pytest.approx([1 / 3] * 3, rel=1e-6)


@pytest.mark.slow  # the pinch's pose solve, two scenes and two held seconds (~25 s)
def test_a_held_pinch_keeps_its_contacts_and_an_open_one_has_none():
    from grip_bench.core import constants as C
    from grip_bench.metrics.hold import hold
    from tools.constructed_pinches import pinch_pose, pinch_scene
    from tools.pinch_opposition import PinchModel

    model = PinchModel()
    local, _ = pinch_pose(model, 0.03, starts=1, seed=0)
    held = pinch_scene(model, local, "sphere", 0.0005)[2]
    r = contacts_through(held, C.UP)
    assert r["held"] and r["held"] == hold(held, C.UP)[0].held  # the test's own verdict
    assert r["settled"] > 0 and r["after"] > 0 and r["force"] > 0.0
    off = pinch_scene(model, local, "sphere", 0.003)[2]  # pads 3 mm off: nothing touches
    r = contacts_through(off, C.UP)
    assert not r["held"] and r["start"] == r["settled"] == 0  # (falling, it may brush a finger)


@pytest.mark.slow  # the pinch's pose solve and two held seconds (~20 s)
def test_the_verdict_is_the_tests_with_the_wedge_rule(monkeypatch):
    """The verdict reads the wedge rule as ``metrics.hold.hold`` does (until s58 it did not,
    and held 16 wedged wine-glass frames of the default test split the test fails): with the
    rule's bound below zero, any inward contact force fails a held pinch in both."""
    from grip_bench.core import constants as C
    from grip_bench.metrics.hold import hold
    from tools.constructed_pinches import pinch_pose, pinch_scene
    from tools.pinch_opposition import PinchModel

    model = PinchModel()
    local, _ = pinch_pose(model, 0.03, starts=1, seed=0)
    scene = pinch_scene(model, local, "sphere", 0.0005)[2]
    assert contacts_through(scene, C.UP)["held"]
    monkeypatch.setattr(C, "HOLD_WEDGE_WEIGHTS", -1.0)
    assert hold(scene, C.UP)[0].ruled_out and not hold(scene, C.UP)[0].held
    assert not contacts_through(scene, C.UP)["held"]


def test_bad_data_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 1
    assert capsys.readouterr().err.count("\n") == 1
