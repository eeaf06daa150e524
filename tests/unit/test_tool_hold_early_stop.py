"""tools/hold_early_stop.py: the rest rule stops a run only after ``REST_AFTER`` and
``REST_CHECKS`` quiet checks, extrapolates the second at the last speeds, and is scored
against the full run; on a constructed pinch the recorded full hold gives ``hold``'s own
verdict (docs/physics_hold.md, "Measured in s44")."""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.core import constants as C
from tools.hold_early_stop import (
    REST_AFTER,
    REST_CHECKS,
    REST_SPEED,
    Check,
    compare,
    early_stop,
    fall_exit,
    record,
    summarise,
    verdict,
)

STEPS = int(round(C.SIM_HOLD_SECONDS / C.SIM_DT))


class _Scene:  # verdict reads only the depth
    depth = 0.0


def quiet(n: int, speed: float = 0.0, disp: float = 0.001, ncon: int = 4) -> list[Check]:
    """n checks, 6 steps apart, the object still (``speed`` m/s) ``disp`` m from the start."""
    return [Check(6 * (i + 1), disp, 0.5, speed, 0.0, 0.0, ncon) for i in range(n)]


def test_the_rule_waits_for_rest_after_and_enough_quiet_checks():
    first = int(np.ceil(REST_AFTER / C.SIM_DT / 6))  # the first check at or after REST_AFTER
    stop = early_stop(quiet(STEPS // 6))
    assert stop is not None and stop[0] == 6 * max(first, REST_CHECKS)
    left = C.SIM_HOLD_SECONDS - stop[0] * C.SIM_DT
    moving = early_stop(quiet(STEPS // 6, speed=0.5 * REST_SPEED))
    assert moving[1] == pytest.approx(0.001 + 0.5 * REST_SPEED * left)  # extrapolated
    assert early_stop(quiet(STEPS // 6, speed=2 * REST_SPEED)) is None  # never quiet
    assert early_stop(quiet(first - 1)) is None  # too early


def test_a_quiet_run_that_falls_later_is_a_disagreement():
    checks = quiet(STEPS // 6)
    falls = checks[:20] + [Check(c.step, 0.5, 40.0, 2.0, 0.0, 0.0, 0) for c in checks[20:]]
    r = compare(_Scene(), 0.001, falls)
    assert r["stopped"] and r["rule"] and not r["full"]
    assert r["failed_at"] == falls[20].step
    s = summarise([r, compare(_Scene(), 0.001, checks)])
    assert s["disagree"] == 1 and s["held_full"] == 1 and s["held_rule"] == 2
    assert s["disagreements"] == [{"stopped_s": round(r["steps_rule"] * C.SIM_DT, 3),
                                   "failed_s": round(falls[20].step * C.SIM_DT, 3)}]


def test_free_fall_exit_and_diverged_runs():
    fall = [Check(6 * (i + 1), 0.02 * i, 0.0, 1.0, 0.0, 0.0, 0) for i in range(STEPS // 6)]
    assert fall_exit(fall) == fall[5].step  # the first check 10 cm away with no contact
    r = compare(_Scene(), 0.001, fall)
    assert not r["full"] and not r["stopped"] and r["steps"] == fall[5].step
    d = compare(_Scene(), 0.001, [])
    assert d["steps"] == STEPS and not d["full"] and not d["rule"]
    assert not verdict(_Scene(), 2 * C.HOLD_SETTLE_FAIL, 0.0, 0.0)  # the settle rule


@pytest.mark.slow  # ~15 s: the pinch's pose solve, its pieces and two held seconds
def test_the_recorded_hold_is_the_hold_test():
    from grip_bench.metrics.hold import hold
    from tools.constructed_pinches import pinch_pose, pinch_scene
    from tools.pinch_opposition import PinchModel

    model = PinchModel()
    local, _ = pinch_pose(model, 0.03, starts=1, seed=0)
    scene = pinch_scene(model, local, "sphere", 0.0005)[2]
    settle, (checks,) = record(scene, C.UP)
    ref = hold(scene, C.UP)[0]
    assert settle == ref.settle
    assert checks[-1].step == STEPS and checks[-1].disp == pytest.approx(ref.displacement)
    assert verdict(scene, settle, checks[-1].disp, checks[-1].rot) == ref.held is True
    r = compare(scene, settle, checks)
    assert r["stopped"] and r["rule"] == r["full"]  # a squeezed pinch comes to rest
