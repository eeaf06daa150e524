"""tools/constructed_pinches.py: the articulated hold test on grasps whose answer is known.
The procedural hand's most opposed pinch (30 mm) holds a sphere and a cylinder placed
0.5 mm from both pads under the world's gravity and all six axis directions; the same
pinch drops them when the pads are 3 mm away (beyond ``HOLD_TOUCH``: nothing squeezes) or
when the object is heavier than the capped servos can squeeze (docs/physics_hold.md,
"Measured in s42")."""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.core import constants as C
from grip_bench.geometry.pieces import ExactDistance
from tools.constructed_pinches import SHAPES, between_pads, hold_case, pinch_pose
from tools.pinch_opposition import PinchModel

APERTURE = 0.03  # m


@pytest.fixture(scope="module")
def pinch():
    model = PinchModel()
    local, geo = pinch_pose(model, APERTURE, starts=1, seed=0)
    assert geo["normals_deg"] > 170.0  # pad to pad: the constructed grasp squeezes
    return model, local


@pytest.mark.parametrize("shape", SHAPES)
def test_the_object_sits_gap_from_both_pads(pinch, shape):
    model, local = pinch
    v, _, _ = model.pose(local)
    thumb, index = v[model.thumb_pad], v[model.index_pad]
    obj = between_pads(thumb, index, shape, 0.0005)
    assert obj.is_watertight
    d = ExactDistance(obj.vertices, obj.faces)(np.stack([thumb, index]))
    assert d == pytest.approx([0.0005, 0.0005], abs=1e-4)  # a 64-gon cylinder, a 4x sphere
    assert np.allclose(obj.bounding_box.centroid, 0.5 * (thumb + index), atol=1e-6)
    with pytest.raises(ValueError, match="no object"):
        between_pads(thumb, index, shape, APERTURE)


@pytest.mark.parametrize("shape", ["sphere", "cylinder"])
def test_a_pinch_that_squeezes_holds_in_every_direction(pinch, shape):
    model, local = pinch
    r = hold_case(model, local, shape, 0.0005)
    assert r["touching"] > 0 and r["min_sd_mm"] > 0.0  # touching, not cut into
    assert all(r["held"].values()), r["held"]  # the world's gravity and the six axes
    assert max(r["disp_mm"].values()) < 1.0
    assert r["force_ratio"] < 1.0  # the quasi-static check agrees (under the weight)


def test_pads_out_of_reach_or_too_weak_drop_it(pinch):
    model, local = pinch
    off = hold_case(model, local, "sphere", 0.003)  # beyond HOLD_TOUCH: nothing tightens
    assert off["touching"] == 0
    assert not off["held"]["world"] and off["disp_mm"]["world"] > 1e3 * C.HOLD_DISP
    assert off["force_ratio"] == np.inf  # nothing within reach: the check agrees
    heavy = hold_case(model, local, "sphere", 0.0005, density=64.0)  # ~0.4 kg
    assert heavy["mass_g"] > 300.0
    assert not heavy["held"]["world"] and heavy["disp_mm"]["world"] > 1e3 * C.HOLD_DISP
    assert heavy["force_ratio"] < 1.0  # the check has no force cap: a pinch holds any weight
