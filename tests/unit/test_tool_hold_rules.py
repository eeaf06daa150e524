"""tools/hold_rules.py: the rules against their bounds, the summary against hand-made frames,
and (slow) the probe on the grasp fixture agreeing with the test's own ``ruled_out``."""

from __future__ import annotations

import pytest

from tests.eval_fixtures import grasp_dataset
from tools.hold_rules import finger_servos, probe, summarise


def test_summary_counts_each_rule_and_the_first_per_object():
    rows = [{"object": "glass", "held": False, "diverged": False, "rules": ["wedge"]},
            {"object": "glass", "held": True, "diverged": False, "rules": []},
            {"object": "cube", "held": False, "diverged": False, "rules": ["depth", "settle"]},
            {"object": "cube", "held": False, "diverged": False, "rules": ["settle"]},
            {"object": "cube", "held": False, "diverged": True, "rules": []}]
    s = summarise(rows)
    assert (s["frames"], s["held"], s["diverged"], s["ruled_out"]) == (5, 1, 1, 3)
    assert (s["depth"], s["settle"], s["wedge"]) == (1, 2, 1)
    assert (s["depth_first"], s["settle_first"], s["wedge_first"]) == (1, 1, 1)
    assert s["objects"]["glass"]["wedge_first"] == 1 and s["objects"]["cube"]["ruled_out"] == 2


@pytest.mark.slow  # one scene and a hold per tested frame (~15 s)
def test_probe_agrees_with_the_tests_ruled_out(tmp_path):
    data = tmp_path / "data"
    grasp_dataset(data, T=40)  # a one-handed mug lift, a two-handed cylinder pass
    res = probe(data)
    assert res["frames"] > 0 and res["diverged"] == 0
    for r in res["rows"]:
        assert r["ruled_out"] == bool(r["rules"])
        assert not (r["held"] and r["rules"])


def test_finger_servos_are_set_for_the_block_and_restored():
    """s51's human-strength probe: the gain and cap set, the damping scaled with the gain's
    square root (the same damping ratio), everything restored after, even on an error."""
    from grip_bench.core import constants as C

    before = C.HOLD_FINGER_KP, C.HOLD_FINGER_KV, C.HOLD_FINGER_TORQUE
    with pytest.raises(RuntimeError), finger_servos(4 * before[0], 1.0):
        assert C.HOLD_FINGER_KP == 4 * before[0] and C.HOLD_FINGER_TORQUE == 1.0
        assert C.HOLD_FINGER_KV == pytest.approx(2 * before[1])
        raise RuntimeError
    assert (C.HOLD_FINGER_KP, C.HOLD_FINGER_KV, C.HOLD_FINGER_TORQUE) == before
    with finger_servos():
        assert (C.HOLD_FINGER_KP, C.HOLD_FINGER_KV, C.HOLD_FINGER_TORQUE) == before
