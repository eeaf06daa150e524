"""tools/pinch_opposition.py: pad angles on analytic pads, the SynthGRAB pinch pose's pads
(opposed since the thumb's CMC is framed for opposition, SynthGRAB 2.3), and one optimised
pinch (reaches its aperture inside the joint limits with the pads facing each other: the
acceptance check of docs/physics_hold.md, "Measured in s33")."""

from __future__ import annotations

import numpy as np
import pytest

from tools.pinch_opposition import MOVED, PinchModel, best_pinch, pad_angles


def test_pad_angles_on_analytic_pads():
    x = np.eye(3)
    facing = pad_angles(np.zeros(3), x[0], 0.02 * x[0], -x[0])  # pads face each other
    assert facing["distance_mm"] == pytest.approx(20.0)
    assert facing["normals_deg"] == pytest.approx(180.0)
    assert facing["thumb_off_deg"] == pytest.approx(0.0, abs=1e-6)
    assert facing["index_off_deg"] == pytest.approx(0.0, abs=1e-6)
    side = pad_angles(np.zeros(3), x[1], 0.02 * x[0], x[1])  # both press the same side
    assert side["normals_deg"] == pytest.approx(0.0, abs=1e-6)
    assert side["thumb_off_deg"] == pytest.approx(90.0) and side["index_off_deg"] == \
        pytest.approx(90.0)
    tilted = pad_angles(np.zeros(3), x[0], x[0], -(x[0] + x[1]) / np.sqrt(2))
    assert tilted["normals_deg"] == pytest.approx(135.0) and tilted["index_off_deg"] == \
        pytest.approx(45.0)


@pytest.fixture(scope="module")
def model():
    return PinchModel()


def test_the_synthgrab_pinch_pads_face_each_other(model):
    from grip_bench.data.synth.grasp import _PINCH, _PINCH_CLOSED, preshape_local

    g = model.geometry(preshape_local("precision", _PINCH_CLOSED))
    assert g["distance_mm"] < 20.0  # the tips meet...
    assert g["normals_deg"] > 150.0  # ...pad to pad (s33: 166 degrees; 2.2's pose: 43)
    opened = model.geometry(preshape_local("precision", _PINCH))
    assert opened["distance_mm"] > 60.0 and opened["normals_deg"] > 140.0  # open, still facing
    # the pad normal is the full mesh's vertex normal (pose() uses vertex_normals)
    v, _, n = model.pose(preshape_local("precision", _PINCH_CLOSED))
    assert np.allclose(model._normal(v, model.thumb_pad), n[model.thumb_pad])


def test_best_pinch_reaches_its_aperture_within_the_limits(model):
    from grip_bench.data.synth.grasp import _PINCH_CLOSED, preshape_local

    base = preshape_local("precision", _PINCH_CLOSED)
    local, g = best_pinch(model, 0.03, base, index="natural", starts=1, seed=0)
    assert g["distance_mm"] == pytest.approx(30.0, abs=1.0)
    for jj, ax in MOVED:
        assert model.lower[jj, ax] - 1e-9 <= local[jj, ax] <= model.upper[jj, ax] + 1e-9
    assert g["normals_deg"] > 150.0  # the acceptance bound (s33: 176 degrees)
    assert g["thumb_off_deg"] < 30.0 and g["index_off_deg"] < 30.0
    assert np.array_equal(local, best_pinch(model, 0.03, base, starts=1, seed=0)[0])
