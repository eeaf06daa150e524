"""tools/cut_depth.py: the object's surface read densely enough for a rim, and its summary
(docs/physics_hold.md, "Measured in s59")."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grip_bench.data.synth import grasp as G
from tools.cut_depth import summarise


def test_the_probe_reads_the_generators_surface_points_along_a_rim():
    from scipy.spatial import cKDTree

    mesh = trimesh.creation.box(extents=(0.04, 0.002, 0.04))  # a plate with a 2 mm rim
    pts = G.surface_points(mesh)
    d, _ = cKDTree(pts).query(pts, k=2)
    assert d[:, 1].max() <= G.CUT_EDGE + 1e-12
    rim = pts[np.isclose(pts[:, 0], 0.02)]
    assert len(rim) >= 20 and np.ptp(rim[:, 2]) == pytest.approx(0.04)


def test_summary_counts_frames_past_the_limit_per_side_and_names_the_cut_sequences():
    rows = [{"sequence": "s1/a", "frame": 1, "object_in_hand_mm": 6.0, "hand_in_object_mm": 1.0},
            {"sequence": "s1/a", "frame": 2, "object_in_hand_mm": 8.5, "hand_in_object_mm": 1.2},
            {"sequence": "s2/b", "frame": 3, "object_in_hand_mm": 0.5, "hand_in_object_mm": 2.5},
            {"sequence": "s3/c", "frame": 4, "object_in_hand_mm": 0.0, "hand_in_object_mm": 0.0}]
    s = summarise(rows, 2.0)
    assert s["frames"] == 4
    assert s["object_in_hand_mm"]["max"] == 8.5 and s["object_in_hand_mm"]["over_limit"] == 2
    assert s["object_in_hand_mm"]["median"] == pytest.approx(3.25)
    assert s["hand_in_object_mm"]["over_limit"] == 1
    assert s["cut_sequences"] == {"s1/a": {"frames": 2, "max_mm": 8.5}}
    assert summarise([], 2.0) == {"frames": 0, "cut_sequences": {}}
