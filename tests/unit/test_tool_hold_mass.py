"""tools/hold_mass.py: scaling the compiled object's mass and inertia is the same test as
building the scene at that density (a constructed pinch held at 1x, dropped at 64x), the
model comes back unchanged, and the summary's groups (docs/physics_hold.md, "Measured in
s43")."""

from __future__ import annotations

import pytest

from grip_bench.core import constants as C
from tools.hold_mass import _scales, results_at, summarise

APERTURE = 0.03  # m


@pytest.fixture(scope="module")
def heavy_pinch():
    """The 30 mm constructed pinch's scene around a sphere 0.5 mm from both pads, at 64 times
    the suite's density (~0.4 kg: beyond what the capped servos carry)."""
    from tools.constructed_pinches import pinch_pose, pinch_scene
    from tools.pinch_opposition import PinchModel

    model = PinchModel()
    local, _ = pinch_pose(model, APERTURE, starts=1, seed=0)
    return pinch_scene(model, local, "sphere", 0.0005, density=64.0)[2]


@pytest.mark.slow  # ~20 s: the pinch's pose solve, its pieces and three held seconds
def test_a_lighter_object_is_the_same_test_at_a_lower_density(heavy_pinch):
    from grip_bench.metrics.hold import hold

    before = hold(heavy_pinch, C.UP)[0]
    # x1: dropped (tools/constructed_pinches: from ~200 g up); x1/64: the 1x density, held
    assert [r.held for r in results_at(heavy_pinch, C.UP, (1.0, 1.0 / 64.0))] == [False, True]
    assert hold(heavy_pinch, C.UP)[0] == before  # mass, inertia and constants restored


def test_groups_and_shares():
    rows = [("cup", [True, True]), ("cup", [False, True]), ("box", [False, False]),
            ("box", [False, True])]
    s = summarise(rows)
    assert s["held_pct"] == [25.0, 75.0]
    assert s["groups"] == {"held": 1, "held only lighter": 2, "dropped at every scale": 1}
    assert s["per_object"]["box"] == {"dropped at every scale": 1, "held only lighter": 1}
    assert summarise([])["held_pct"] == []


def test_scales_are_positive():
    assert _scales("1,0.1") == (1.0, 0.1)
    with pytest.raises(ValueError, match="positive"):
        _scales("1,0")
