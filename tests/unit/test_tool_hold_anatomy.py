"""tools/hold_anatomy.py: grasp labels from SynthGRAB's manifest, the summary by label against
hand-made rows, the contacts of a constructed pinch through the settle (slow: it simulates)
and a one-line error on bad data."""

from __future__ import annotations

import json

import pytest

from tools.hold_anatomy import contacts_through, grasp_labels, main, summarise


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


def test_bad_data_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 1
    assert capsys.readouterr().err.count("\n") == 1
