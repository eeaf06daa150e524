"""The hold test (grip_bench.metrics.hold, the physics table's hold_sim) on analytic scenes."""

from __future__ import annotations

import numpy as np
import pytest
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


def _free_fall(n: int) -> float:
    """Semi-implicit Euler free fall after n steps of SIM_DT: g dt^2 n (n + 1) / 2."""
    return 0.5 * C.GRAVITY * C.SIM_DT**2 * n * (n + 1)


def test_free_fall_fails_and_is_counted():
    ball = trimesh.creation.icosphere(3, radius=0.02)
    far = trimesh.creation.box(extents=[0.02] * 3)
    far.apply_translation([0.5, 0, 0])
    r = H.static_hold([far], ball, (np.eye(3), np.zeros(3)))
    assert not r.held and not r.diverged
    # the run stops at the first free-fall check past the cap: n steps, a multiple of the
    # check interval, whose state before the last step was already past it
    n = next(k for k in range(H._FALL_CHECK, 10**4, H._FALL_CHECK)
             if _free_fall(k - 1) >= C.HOLD_DISP_CAP)
    assert n < round(C.SIM_HOLD_SECONDS / C.SIM_DT)
    assert abs(r.displacement - _free_fall(n)) < 1e-6


def test_free_fall_stop_keeps_the_verdict_and_the_capped_displacement(monkeypatch):
    ball = trimesh.creation.icosphere(3, radius=0.02)
    far = trimesh.creation.box(extents=[0.02] * 3)
    far.apply_translation([0.5, 0, 0])
    scenes = [([far], ball, (np.eye(3), np.zeros(3)))]
    cube = trimesh.creation.box(extents=[0.04] * 3)
    pads = [trimesh.creation.box(extents=[0.02, 0.015, 0.015]) for _ in range(2)]
    for sign, pad in zip((1, -1), pads, strict=True):
        pad.apply_translation([sign * (0.03 - 0.0005), 0, 0])
    scenes.append((pads, cube, (np.eye(3), np.zeros(3))))
    early = [H.static_hold(*s) for s in scenes]
    monkeypatch.setattr(H, "_FALL_CHECK", 10**9)  # never checks: the whole second
    full = [H.static_hold(*s) for s in scenes]
    assert full[0].displacement == pytest.approx(_free_fall(round(C.SIM_HOLD_SECONDS / C.SIM_DT)))
    for a, b in zip(early, full, strict=True):
        assert (a.held, a.diverged, a.settle) == (b.held, b.diverged, b.settle)
        assert min(a.displacement, C.HOLD_DISP_CAP) == min(b.displacement, C.HOLD_DISP_CAP)
    assert early[1].displacement == full[1].displacement  # a held object runs the whole second


def test_cube_pinched_by_two_fingers_holds():
    cube = trimesh.creation.box(extents=[0.04] * 3)
    fingers = []
    for sign in (1, -1):
        f = trimesh.creation.box(extents=[0.02, 0.015, 0.015])
        f.apply_translation([sign * (0.03 - 0.0005), 0, 0])  # 0.5 mm into the cube
        fingers.append(f)
    r = H.static_hold(fingers, cube, (np.eye(3), np.zeros(3)))
    assert r.held and r.displacement < 0.001



def test_static_hands_sunk_past_the_depth_bound_do_not_hold():
    """The depth rule of the articulated test holds for static hands too: pads 6 mm into
    the cube wedge it (it settles and stays, as at 0.5 mm), but a hand vertex deeper than
    HOLD_MAX_DEPTH fails the test; 4 mm in is within the bound and holds."""
    cube = trimesh.creation.box(extents=[0.04] * 3)
    pose = (np.eye(3), np.array([0.1, 0.2, 0.3]))  # placed away from the origin

    def pads(depth):
        out = []
        for sign in (1, -1):
            f = trimesh.creation.box(extents=[0.02, 0.015, 0.015])
            f.apply_translation(pose[1] + [sign * (0.03 - depth), 0, 0])
            out.append(f)
        return out

    deep = H.static_scene(pads(0.006), cube, pose)
    assert deep.depth == pytest.approx(0.006, abs=1e-9)
    sunk = H.hold(deep)[0]
    assert not sunk.held and not sunk.diverged
    assert sunk.displacement < C.HOLD_DISP and sunk.settle <= C.HOLD_SETTLE_FAIL  # wedged
    within = H.static_hold(pads(0.004), cube, pose)
    assert within.held and within.displacement < 0.001


def test_support_test_free_fall_reference():
    assert abs(C.SIM_FREE_FALL_5 - 0.00255) < 1e-5
