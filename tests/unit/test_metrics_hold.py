"""The experimental hold test (grip_bench.metrics.hold) on analytic scenes."""

from __future__ import annotations

import numpy as np
import trimesh

from grip_bench.core import constants as C
from grip_bench.metrics import hold as H
from tests.unit.test_geometry_pieces import bowl_mesh


def test_ball_resting_in_a_bowl_stays():
    ball = trimesh.creation.icosphere(3, radius=0.02)
    rest = np.array([0.0, -0.045 + 0.02 + 1e-4, 0.0])  # touching the inner wall's bottom
    r = H.static_hold([bowl_mesh()], ball, (np.eye(3), rest))
    assert r.held and not r.diverged
    assert r.displacement < 0.001  # concave stays concave: no hull pushes the ball out


def test_free_fall_fails_and_is_counted():
    ball = trimesh.creation.icosphere(3, radius=0.02)
    far = trimesh.creation.box(extents=[0.02] * 3)
    far.apply_translation([0.5, 0, 0])
    r = H.static_hold([far], ball, (np.eye(3), np.zeros(3)))
    assert not r.held
    t = C.SIM_HOLD_SECONDS
    # semi-implicit Euler free fall over the hold's steps: g dt^2 n (n + 1) / 2
    n = round(t / C.SIM_DT)
    assert abs(r.displacement - 0.5 * C.GRAVITY * C.SIM_DT**2 * n * (n + 1)) < 1e-6


def test_cube_pinched_by_two_fingers_holds():
    cube = trimesh.creation.box(extents=[0.04] * 3)
    fingers = []
    for sign in (1, -1):
        f = trimesh.creation.box(extents=[0.02, 0.015, 0.015])
        f.apply_translation([sign * (0.03 - 0.0005), 0, 0])  # 0.5 mm into the cube
        fingers.append(f)
    r = H.static_hold(fingers, cube, (np.eye(3), np.zeros(3)))
    assert r.held and r.displacement < 0.001


def test_support_test_free_fall_reference():
    assert abs(C.SIM_FREE_FALL_5 - 0.00255) < 1e-5
