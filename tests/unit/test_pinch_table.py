"""SynthGRAB's exact-pinch table (data.synth.pinch_table, written by tools/pinch_table.py):
every row is, on the current procedural hand, a pulp pinch of its aperture whose pads face each
other, inside the joint limits; the left hand's mirror has the same geometry. A hand model
change that breaks this needs the table rewritten (python tools/pinch_table.py)."""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.bodies.pinch import MOVED, PinchModel
from grip_bench.data.synth import pinch_table as T


@pytest.fixture(scope="module")
def poses():
    from grip_bench.data.synth.grasp import exact_pinch_poses

    return exact_pinch_poses("right", 1.0, "precision")


def test_each_row_is_an_opposed_pinch_of_its_aperture(poses):
    local, thumb, index = poses
    model = PinchModel()
    assert len(T.APERTURES_MM) == len(T.MOVED_ANGLES) == len(local)
    assert np.all(np.diff(T.APERTURES_MM) > 0)
    for a, row, pose in zip(T.APERTURES_MM, T.MOVED_ANGLES, local, strict=True):
        g = model.geometry(pose)
        assert g["distance_mm"] == pytest.approx(a, abs=0.3)
        assert g["normals_deg"] > 170.0  # pads face each other (a human pinch: ~180)
        assert g["thumb_off_deg"] < 10.0 and g["index_off_deg"] < 10.0
        for (jj, ax), x in zip(MOVED, row, strict=True):
            assert model.lower[jj, ax] - 1e-6 <= x <= model.upper[jj, ax] + 1e-6
    # the generator's pad points are the model's pads in the same poses
    np.testing.assert_allclose(1e3 * np.linalg.norm(index - thumb, axis=1), T.APERTURES_MM,
                               atol=0.3)


def test_the_left_hand_mirrors_the_right_and_widths_scale():
    from grip_bench.data.synth.grasp import exact_pinch_poses

    _, rt, ri = exact_pinch_poses("right", 1.0, "precision")
    _, lt, li = exact_pinch_poses("left", 1.0, "precision")
    _, st, si = exact_pinch_poses("right", 0.9, "precision")
    np.testing.assert_allclose(lt * [-1.0, 1.0, 1.0], rt, atol=1e-9)
    np.testing.assert_allclose(li * [-1.0, 1.0, 1.0], ri, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(si - st, axis=1),
                               0.9 * np.linalg.norm(ri - rt, axis=1), rtol=1e-6)


def test_the_tool_renders_the_committed_table_format():
    import ast

    from tools.pinch_table import APERTURES_MM, render

    text = render(APERTURES_MM[:2], np.zeros((2, len(MOVED))))
    ns = {node.targets[0].id: ast.literal_eval(node.value) for node in ast.parse(text).body
          if isinstance(node, ast.Assign)}
    assert ns["APERTURES_MM"] == (10.0, 12.5)
    assert ns["MOVED_ANGLES"] == ((0.0,) * 8, (0.0,) * 8)
    assert tuple(T.APERTURES_MM) == APERTURES_MM
