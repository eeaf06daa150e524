"""The hold test's physics on analytic cases: MuJoCo's friction with the hold test's contact
settings is Coulomb's (a pinched box holds iff 2 mu N >= m g), the quasi-static force check
(``wrench.plan_forces``) reproduces the same bound, a good grasp ranks above its degradations,
and a run is deterministic."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grip_bench.core import constants as C
from grip_bench.geometry import wrench as W
from grip_bench.metrics import hold as H

SIDE = 0.04  # m, the pinched cube


def _pinch_displacement(mu: float, factor: float) -> float:
    """A cube (own weight m g) between two box pads on slide joints, each pressed with
    ``factor * m g / (2 mu)`` N; 0.2 s without gravity, then 1 s with it. Returns the cube's
    displacement (m) during that second. Built with the hold test's own contact settings."""
    import mujoco

    cube = trimesh.creation.box(extents=[SIDE] * 3)
    spec = H._spec(C.UP)
    H._add_object(spec, cube, [np.asarray(cube.vertices)], None, C.DEFAULT_DENSITY)
    squeeze = factor * cube.volume * C.DEFAULT_DENSITY * C.GRAVITY / (2.0 * mu)
    for sign in (1, -1):
        pad = spec.worldbody.add_body()
        pad.pos = [sign * (SIDE / 2 + 0.005), 0.0, 0.0]
        joint = pad.add_joint()
        joint.name, joint.type, joint.axis = f"slide{sign}", mujoco.mjtJoint.mjJNT_SLIDE, [1, 0, 0]
        geom = pad.add_geom()
        geom.type, geom.size = mujoco.mjtGeom.mjGEOM_BOX, [0.005, 0.01, 0.01]
        H._contact_params(geom, hand=True)
        pad.explicitinertial, pad.mass, pad.inertia = True, 0.01, [1e-6] * 3
    model = spec.compile()
    model.geom_friction[:, 0] = mu
    data = mujoco.MjData(model)
    for sign in (1, -1):
        data.qfrc_applied[model.jnt_dofadr[model.joint(f"slide{sign}").id]] = -sign * squeeze
    model.opt.gravity[:] = 0.0
    assert H._step(model, data, int(round(C.HOLD_SETTLE_SECONDS / C.SIM_DT)))
    start = H._pose_of(model, data)[0]
    model.opt.gravity[:] = -C.GRAVITY * np.asarray(C.UP)
    assert H._step(model, data, int(round(C.SIM_HOLD_SECONDS / C.SIM_DT)))
    return float(np.linalg.norm(H._pose_of(model, data)[0] - start))


@pytest.mark.parametrize("mu", [0.5, 1.0, 3.0])
def test_pinched_box_holds_iff_friction_carries_the_weight(mu):
    # measured: 0.07 mm at 1.05 x the Coulomb bound, > 2 m of fall at 0.95 x, for every mu
    assert _pinch_displacement(mu, 1.05) < 1e-3
    assert _pinch_displacement(mu, 0.95) > C.HOLD_DISP


def test_plan_forces_two_pads_analytic():
    pts = np.array([[SIDE / 2, 0, 0], [-SIDE / 2, 0, 0]])
    normals = np.array([[-1.0, 0, 0], [1.0, 0, 0]])  # into the object
    weight = np.array([0.0, -2.0, 0.0])  # N
    for mu in (0.25, 0.5, 1.0, 3.0):
        f = W.plan_forces(pts, normals, np.zeros(3), weight, mu)
        normal = np.einsum("kc,kc->k", f, normals)
        assert normal == pytest.approx([2.0 / (2 * mu)] * 2, rel=1e-6)  # 2 mu N = m g
        assert f.sum(0) == pytest.approx(-weight, abs=1e-9)


def test_plan_forces_satisfies_its_constraints_on_random_contacts():
    """Naive reference: check balance and cones of the answer directly."""
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(12, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts, normals = 0.03 * dirs, -dirs  # contacts all around a 3 cm ball
    com, load, mu = np.zeros(3), np.array([0.3, -1.0, 0.2]), 0.6
    f = W.plan_forces(pts, normals, com, load, mu)
    assert f is not None
    assert f.sum(0) == pytest.approx(-load, abs=1e-7)
    assert np.cross(pts - com, f).sum(0) == pytest.approx(np.zeros(3), abs=1e-8)
    fn = np.einsum("kc,kc->k", f, normals)
    ft = np.linalg.norm(f - fn[:, None] * normals, axis=1)
    assert (fn >= -1e-9).all() and (ft <= mu * fn + 1e-9).all()


def test_plan_forces_one_sided_contacts_cannot_hold():
    pts = np.array([[0.02, 0, 0], [0.02, 0.01, 0]])
    normals = np.array([[-1.0, 0, 0]] * 2)
    assert W.plan_forces(pts, normals, np.zeros(3), np.array([0, -1.0, 0]), 1.0) is None
    assert W.plan_forces(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(3),
                         np.array([0, -1.0, 0]), 1.0) is None


def _pads(shift: float) -> list[trimesh.Trimesh]:
    """Two static finger pads 0.5 mm into a 4 cm cube, both moved ``shift`` m along +x."""
    out = []
    for sign in (1, -1):
        pad = trimesh.creation.box(extents=[0.02, 0.015, 0.015])
        pad.apply_translation([sign * (SIDE / 2 + 0.01 - 0.0005) + shift, 0, 0])
        out.append(pad)
    return out


def test_grasp_ranks_above_its_degradations():
    cube = trimesh.creation.box(extents=[SIDE] * 3)
    pose = (np.eye(3), np.zeros(3))
    good = H.static_hold(_pads(0.0), cube, pose)
    # above the cube: the pads' lower faces 2.25 cm over its top face
    away = H.static_hold([p.copy().apply_translation([0, 0.05, 0]) for p in _pads(0.0)],
                         cube, pose)
    assert good.held and good.displacement < 1e-3
    assert not away.held and away.displacement > C.HOLD_DISP
    assert good.displacement < away.displacement


def test_hold_is_deterministic():
    cube = trimesh.creation.box(extents=[SIDE] * 3)
    pose = (np.eye(3), np.array([0.0, 0.1, 0.0]))
    pads = [p.copy().apply_translation([0, 0.1, 0]) for p in _pads(0.0)]
    runs = [H.hold(H.static_scene(pads, cube, pose), directions=(None, "+x"))
            for _ in range(2)]
    assert runs[0] == runs[1]
