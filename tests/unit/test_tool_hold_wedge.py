"""tools/hold_wedge.py: the summary against hand-made frames, and the probe on the grasp
fixture (slow: it simulates) reporting the verdict's own wedge figure beside its own."""

from __future__ import annotations

import pytest

from tests.eval_fixtures import grasp_dataset
from tools.hold_wedge import WEDGED_FORCE, probe, summarise


def test_summary_counts_wedged_frames_per_object():
    rows = [{"object": "glass", "held": True, "diverged": False, "force_over_weight": 4000.0},
            {"object": "glass", "held": False, "diverged": False, "force_over_weight": 2.0},
            {"object": "cube", "held": True, "diverged": False, "force_over_weight": 5.0},
            {"object": "cube", "held": False, "diverged": True}]
    s = summarise(rows)
    assert (s["frames"], s["held"], s["wedged"], s["wedged_held"], s["diverged"]) == (
        3, 2, 1, 1, 1)
    assert s["median_force_over_weight"] == 5.0
    assert s["objects"]["glass"] == {"frames": 2, "held": 1, "wedged": 1, "wedged_held": 1,
                                     "median_force_over_weight": 2001.0}
    assert s["objects"]["cube"]["wedged"] == 0 and WEDGED_FORCE > 5.0


@pytest.mark.slow  # one scene, a hold and a second settle per tested frame (~20 s)
def test_probe_on_the_grasp_fixture(tmp_path):
    from grip_bench.core.constants import HOLD_WEDGE_WEIGHTS

    data = tmp_path / "data"
    grasp_dataset(data, T=40)  # a one-handed mug lift, a two-handed cylinder pass
    res = probe(data)
    assert res["frames"] > 0 and res["diverged"] == 0
    for r in res["rows"]:
        assert r["force_over_weight"] >= 0.0 and 0.0 <= r["inward_share"] <= 1.0
        assert r["rule_weights"] >= 0.0  # measured on every settled scene
        assert not (r["held"] and r["rule_weights"] > HOLD_WEDGE_WEIGHTS)  # the rule's verdict
