"""tools/hold_depth.py: the deepest hand vertex follows the bodies; at the start it is the
exact signed distance the scene was built from, and a squeezed constructed pinch keeps its
pads within the object's collision shell during the whole hold (docs/physics_hold.md,
"Measured in s44")."""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.core import constants as C
from tools.hold_depth import _frames, deepest, summarise


def test_summary_takes_the_deepest_and_counts_shell_crossings():
    rows = [{"start_mm": -1.0, "settle_mm": -0.2, "hold_mm": -0.5, "deeper_than_shell": 0,
             "diverged": False},
            {"start_mm": 0.0, "settle_mm": -3.5, "hold_mm": -4.0, "deeper_than_shell": 7,
             "diverged": False},
            {"start_mm": -0.1, "diverged": True}]
    s = summarise(rows)
    assert s["frames"] == 3 and s["diverged"] == 1
    assert (s["deepest_start_mm"], s["deepest_settle_mm"], s["deepest_hold_mm"]) == (
        -1.0, -3.5, -4.0)
    assert s["median_hold_mm"] == -2.25 and s["frames_deeper_than_shell"] == 1


@pytest.mark.slow  # ~15 s: the pinch's pose solve, its pieces and a held second
def test_a_squeezed_pinch_stays_in_the_shell():
    import mujoco

    from grip_bench.geometry.pieces import ExactDistance
    from grip_bench.metrics import hold as H
    from tools.constructed_pinches import pinch_pose, pinch_scene
    from tools.pinch_opposition import PinchModel

    model = PinchModel()
    local, _ = pinch_pose(model, 0.03, starts=1, seed=0)
    hand, obj, scene = pinch_scene(model, local, "sphere", -0.001)  # pads 1 mm inside
    sdf = ExactDistance(np.asarray(obj.vertices), np.asarray(obj.faces))
    m, d = scene.model, mujoco.MjData(scene.model)
    m.opt.gravity[:] = 0.0
    mujoco.mj_forward(m, d)
    start = _frames(m, d, ["object", *(f"h0_b{b}" for b in range(16))])
    first, _ = deepest(m, d, [hand], start, sdf)
    assert first == pytest.approx(min(0.0, float(hand.signed_dist.min())), abs=1e-9)
    assert first < -0.0009
    assert H._settle(m, d, scene.targets)
    m.opt.gravity[:] = -C.GRAVITY * np.asarray(C.UP)
    for _ in range(int(round(C.SIM_HOLD_SECONDS / C.SIM_DT))):
        mujoco.mj_step(m, d)
    mujoco.mj_kinematics(m, d)
    worst, deep = deepest(m, d, [hand], start, sdf)
    assert -C.PIECE_DEPTH < worst < 0.0 and deep == 0  # pressed in, never through the shell
