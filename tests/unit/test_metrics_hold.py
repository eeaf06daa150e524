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


def _pinching_fingers(depth: float = 0.0005) -> list[trimesh.Trimesh]:
    """Two static box fingers ``depth`` (m) into opposite faces of a 4 cm cube at the origin."""
    fingers = []
    for sign in (1, -1):
        f = trimesh.creation.box(extents=[0.02, 0.015, 0.015])
        f.apply_translation([sign * (0.03 - depth), 0, 0])
        fingers.append(f)
    return fingers


def test_cube_pinched_by_two_fingers_holds():
    cube = trimesh.creation.box(extents=[0.04] * 3)
    r = H.static_hold(_pinching_fingers(), cube, (np.eye(3), np.zeros(3)))
    assert r.held and r.displacement < 0.001



def test_static_hands_sunk_past_the_depth_bound_do_not_hold():
    """The depth rule of the articulated test holds for static hands too: pads 6 mm into
    the cube wedge it (it settles and stays, as at 0.5 mm), but a hand vertex deeper than
    HOLD_MAX_DEPTH fails the test before its hold (not simulated: the capped displacement,
    as a diverged run's, not the wedged object's near-zero one); 4 mm in is within the
    bound and holds."""
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
    assert sunk.settle <= C.HOLD_SETTLE_FAIL  # wedged: it settles and stays
    assert (sunk.displacement, sunk.rotation) == (C.HOLD_DISP_CAP, 180.0) and sunk.ruled_out
    within = H.static_hold(pads(0.004), cube, pose)
    assert within.held and within.displacement < 0.001


def test_support_test_free_fall_reference():
    assert abs(C.SIM_FREE_FALL_5 - 0.00255) < 1e-5


def _shell(wall: float) -> trimesh.Trimesh:
    """Hemispherical shell, outer radius 5 cm, open side up (+y)."""
    from grip_bench.geometry.meshes import from_manifold, to_manifold

    outer = trimesh.creation.icosphere(4, radius=0.05)
    inner = trimesh.creation.icosphere(4, radius=0.05 - wall)
    lid = trimesh.creation.box(extents=[0.2, 0.1, 0.2])
    lid.apply_translation([0, 0.05, 0])
    return from_manifold(to_manifold(outer) - to_manifold(inner) - to_manifold(lid))


def _plate(x0: float, x1: float) -> trimesh.Trimesh:
    """A static "hand piece": a plate spanning x0..x1 (m) on the shell's +x side."""
    p = trimesh.creation.box(extents=[x1 - x0, 0.01, 0.01])
    p.apply_translation([(x0 + x1) / 2, -0.004, 0.0])
    return p


def _inward_at_start(plate: trimesh.Trimesh, shell: trimesh.Trimesh) -> tuple[float, int]:
    import mujoco

    scene = H.static_scene([plate], shell, (np.eye(3), np.zeros(3)))
    data = mujoco.MjData(scene.model)
    mujoco.mj_forward(scene.model, data)
    return H.inward_force(scene.model, data, scene.patches), int(data.ncon)


def test_inward_force_counts_a_piece_pushed_in_through_the_back_of_a_prism():
    """The wedge rule's measure (docs/physics_hold.md, "Measured in s49"). An 8 mm wall
    collides as 3 mm prisms under each face (PIECE_DEPTH: they do not overlap). A thin plate
    0.4 mm into the outer face is pushed out the way it came: no inward force. A thin plate
    inside the outer prism near its back (2.8-3.3 mm in) leaves it the short way, deeper into
    the wall: that contact pushes the hand into the object, its force counted in weights."""
    shell = _shell(0.008)
    assert set(np.round(H.object_pieces(shell).depth, 6)) == {C.PIECE_DEPTH}
    outside, n_out = _inward_at_start(_plate(0.0496, 0.0520), shell)
    assert n_out > 0 and outside == 0.0
    behind, n_in = _inward_at_start(_plate(0.0467, 0.0472), shell)
    assert n_in > 0 and behind > 0.0


def test_the_wedge_rule_fails_a_scene_past_its_bound(monkeypatch):
    """hold() fails a settled scene whose inward force exceeds HOLD_WEDGE_WEIGHTS before its
    hold (not simulated: the capped displacement, as a diverged run's): the cube pinch holds
    with no inward force, and fails when the bound is below it, with the same settle."""
    cube = trimesh.creation.box(extents=[0.04] * 3)
    held = H.static_hold(_pinching_fingers(), cube, (np.eye(3), np.zeros(3)))
    assert held.held and held.wedge == 0.0 and not held.ruled_out
    monkeypatch.setattr(C, "HOLD_WEDGE_WEIGHTS", -1.0)
    wedged = H.static_hold(_pinching_fingers(), cube, (np.eye(3), np.zeros(3)))
    assert not wedged.held and not wedged.diverged and wedged.settle == held.settle
    assert (wedged.displacement, wedged.rotation) == (C.HOLD_DISP_CAP, 180.0)
    assert wedged.ruled_out


@pytest.mark.parametrize("depth, settle, wedge, broken", [
    (0.0, 0.0, 0.0, ()),
    (C.HOLD_MAX_DEPTH, C.HOLD_SETTLE_FAIL, C.HOLD_WEDGE_WEIGHTS, ()),  # the bounds pass
    (C.HOLD_MAX_DEPTH + 1e-4, 0.0, 0.0, ("depth",)),
    (0.0, C.HOLD_SETTLE_FAIL + 1e-4, 0.0, ("settle",)),
    (0.0, 0.0, C.HOLD_WEDGE_WEIGHTS + 1.0, ("wedge",)),
    (0.01, 0.01, 1e4, ("depth", "settle", "wedge")),
    (0.0, 0.0, float("nan"), ()),  # the wedge not measured
    (float("nan"), float("nan"), 0.0, ("depth", "settle")),  # as _may_hold always read it
])
def test_broken_rules_at_and_past_each_bound(depth, settle, wedge, broken):
    """The rules a settled scene breaks, in HOLD_RULES order, against hand-set values at and
    past each bound; a scene may hold exactly when it breaks none."""
    assert H.broken_rules(depth, settle, wedge) == broken
    assert H._may_hold(depth, settle, wedge) == (not broken)
