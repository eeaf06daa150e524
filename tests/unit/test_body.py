"""ProceduralBody: FK against a naive loop, arm IK, hand attachment, scaling, validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from grip_bench.bodies.body import ProceduralBody
from grip_bench.bodies.layouts import SMPLX_INDEX, SMPLX_PARENTS
from grip_bench.core import constants
from grip_bench.core.errors import InputError
from grip_bench.geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle

D = torch.float64
ARM = {s: tuple(SMPLX_INDEX[f"{s}_{n}"] for n in ("shoulder", "elbow", "wrist"))
       for s in ("left", "right")}


@pytest.fixture(scope="module")
def body():
    return ProceduralBody(height=1.7, hand_scale=1.0)


def random_pose(b: int, seed: int, scale: float = 0.4):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g, dtype=D)  # noqa: E731
    return dict(global_orient=r(b, 3), body_pose=r(b, 21, 3) * scale, transl=r(b, 3),
                left_hand_pose=r(b, 15, 3) * scale, right_hand_pose=r(b, 15, 3) * scale,
                jaw_pose=r(b, 3) * 0.1)


def naive_fk(template: np.ndarray, full_pose: np.ndarray, transl: np.ndarray):
    """Per-joint loop with scipy rotations: (55, 3) template, (55, 3) axis-angle."""
    rot, pos = [None] * 55, [None] * 55
    for j in range(55):
        local = Rotation.from_rotvec(full_pose[j]).as_matrix()
        p = SMPLX_PARENTS[j]
        if p < 0:
            rot[j], pos[j] = local, transl + local @ template[j]
        else:
            rot[j] = rot[p] @ local
            pos[j] = pos[p] + rot[p] @ (template[j] - template[p])
    return np.stack(pos), np.stack(rot)


def test_fk_matches_naive_loop(body):
    pose = random_pose(3, seed=0)
    out = body(**pose)
    tmpl = body.template_joints.double().numpy()
    for i in range(3):
        full = np.concatenate([pose["global_orient"][i, None], pose["body_pose"][i],
                               pose["jaw_pose"][i, None], np.zeros((2, 3)),
                               pose["left_hand_pose"][i], pose["right_hand_pose"][i]])
        pos, rot = naive_fk(tmpl, full, pose["transl"][i].numpy())
        np.testing.assert_allclose(out.joints[i].numpy(), pos, atol=1e-6)
        np.testing.assert_allclose(out.rotations[i].numpy(), rot, atol=1e-10)


def test_fk_dtypes_flat_pose_and_gradients(body):
    pose = random_pose(2, seed=1)
    out64 = body(**pose)
    flat = {k: v.float() for k, v in pose.items()}
    flat["body_pose"] = flat["body_pose"].reshape(2, 63).requires_grad_()
    flat["right_hand_pose"] = flat["right_hand_pose"].reshape(2, 45)
    out32 = body(**flat)
    assert out32.joints.dtype == torch.float32 and out64.joints.dtype == torch.float64
    torch.testing.assert_close(out32.joints.double(), out64.joints, atol=1e-5, rtol=0)
    out32.joints.sum().backward()
    assert torch.isfinite(flat["body_pose"].grad).all() and flat["body_pose"].grad.abs().sum() > 0


def test_zero_pose_is_the_template(body):
    tr = torch.tensor([[0.1, 0.9, -0.3]])
    out = body(torch.zeros(1, 3), torch.zeros(1, 63), tr)
    torch.testing.assert_close(out.joints[0], body.template_joints + tr[0])
    torch.testing.assert_close(out.rotations[0], torch.eye(3).expand(55, 3, 3))


def test_tpose_conventions(body):
    t = body.template_joints
    j = SMPLX_INDEX
    assert torch.equal(t[0], torch.zeros(3))  # pelvis at the origin: transl = pelvis
    assert t[j["left_wrist"], 0] > t[j["left_elbow"], 0] > t[j["left_shoulder"], 0] > 0
    assert t[j["right_wrist"], 0] < t[j["right_elbow"], 0] < t[j["right_shoulder"], 0] < 0
    assert t[j["head"], 1] > t[j["neck"], 1] > t[j["spine3"], 1] > 0 > t[j["left_knee"], 1]
    assert t[j["left_foot"], 2] > t[j["left_ankle"], 2]  # toes point forward (+z)
    assert t[j["jaw"], 2] > 0 and t[j["left_eye_smplhf"], 0] > 0
    # left/right mirror in x
    mirror = torch.tensor([-1.0, 1.0, 1.0])
    torch.testing.assert_close(t[j["right_elbow"]], t[j["left_elbow"]] * mirror)


def test_height_scaling():
    small, tall = ProceduralBody(height=1.5), ProceduralBody(height=1.9)
    torch.testing.assert_close(small.template_joints[:25] * (1.9 / 1.5), tall.template_joints[:25])
    # the fingers depend on the hand scale only
    for first, wrist in ((25, 20), (40, 21)):
        torch.testing.assert_close(
            small.template_joints[first : first + 15] - small.template_joints[wrist],
            tall.template_joints[first : first + 15] - tall.template_joints[wrist],
        )
    for b in (small, tall):
        rest = b(torch.zeros(1, 3), torch.zeros(1, 63), torch.zeros(1, 3))
        assert b.ground_height(rest).item() == pytest.approx(-b.standing_pelvis_height)
        assert b.standing_pelvis_height == pytest.approx(0.575 * b.height)


def test_hand_scale_scales_the_fingers():
    a, b = ProceduralBody(hand_scale=1.0), ProceduralBody(hand_scale=1.2)
    da = a.template_joints[25:40] - a.template_joints[20]
    db = b.template_joints[25:40] - b.template_joints[20]
    torch.testing.assert_close(da * 1.2, db, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("side", ["left", "right"])
def test_hand_joints_coincide_with_procedural_hand(body, side):
    from grip_bench.bodies.hand import ProceduralHand

    hand = ProceduralHand(side, scale=body.hand_scale)
    first = 25 if side == "left" else 40
    rest = torch.as_tensor(hand.rest_joints, dtype=torch.float32)
    wrist = body.template_joints[SMPLX_INDEX[f"{side}_wrist"]]
    torch.testing.assert_close(body.template_joints[first:first + 15], wrist + rest[1:] - rest[0],
                               atol=1e-6, rtol=0)
    # posed: a hand attached at the wrist frame with the body's hand pose has its fingers
    pose = random_pose(2, seed=2)
    out = body(**pose)
    rot, pos = body.wrist_frame(out, side)
    _, joints = hand.double()(matrix_to_axis_angle(rot), pose[f"{side}_hand_pose"], pos)
    torch.testing.assert_close(joints[:, 1:16].double(), out.joints[:, first:first + 15],
                               atol=1e-6, rtol=0)


def test_ground_height_follows_the_feet(body):
    pose = random_pose(4, seed=3, scale=0.3)
    out = body(**pose)
    low = out.joints[:, [7, 8, 10, 11], 1].amin(dim=1)
    torch.testing.assert_close(body.ground_height(out), low - body.sole_offset)


def test_segments_are_capsules(body):
    out = body(**random_pose(2, seed=4))
    segs = body.segments(out)
    assert len(segs) > 10
    for a, b, r in segs:
        assert a.shape == (2, 3) and b.shape == (2, 3) and 0 < r < 0.2


# ------------------------------------------------------------------ IK
def ik_case(body, side, seed, b=6, reach=0.85):
    """A posed body and wrist targets inside the reachable shell of the ``side`` arm."""
    pose = random_pose(b, seed, scale=0.2)
    g = torch.Generator().manual_seed(seed + 100)
    out = body(**pose)
    shoulder = out.joints[:, ARM[side][0]]
    dmin, dmax = body.arm_reach(side)
    direction = torch.nn.functional.normalize(torch.randn(b, 3, generator=g, dtype=D), dim=-1)
    dist = dmin + (dmax - dmin) * torch.rand(b, generator=g, dtype=D) * reach + 0.01
    target = shoulder + direction * dist[:, None]
    rot = axis_angle_to_matrix(torch.randn(b, 3, generator=g, dtype=D))
    swivel = torch.rand(b, generator=g, dtype=D) * 2 * math.pi - math.pi
    return pose, target, rot, swivel


def solve(body, side, pose, target, rot, swivel=None):
    new_pose, reached = body.solve_arm(side, pose["global_orient"], pose["body_pose"],
                                       pose["transl"], target, rot, swivel)
    out = body(pose["global_orient"], new_pose, pose["transl"])
    return new_pose, reached, out


@pytest.mark.parametrize("side", ["left", "right"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_ik_reaches_target_and_rotation(body, side, dtype):
    pose, target, rot, swivel = ik_case(body, side, seed=5)
    pose = {k: v.to(dtype) for k, v in pose.items()}
    new_pose, reached, out = solve(
        body, side, pose, target.to(dtype), rot.to(dtype), swivel.to(dtype)
    )
    assert reached.all() and new_pose.dtype == dtype
    r, p = body.wrist_frame(out, side)
    tol = 1e-5 if dtype == torch.float32 else 1e-9
    assert (p.double() - target).norm(dim=-1).max() < tol
    assert (r.double() - rot).abs().max() < 10 * tol
    # only the shoulder, elbow and wrist rows changed
    changed = (new_pose - pose["body_pose"]).abs().amax(dim=(0, 2)) > 0
    assert set(torch.nonzero(changed).flatten().tolist()) <= {j - 1 for j in ARM[side]}


@pytest.mark.parametrize("side", ["left", "right"])
def test_swivel_moves_the_elbow_not_the_wrist(body, side):
    pose, target, rot, _ = ik_case(body, side, seed=6, b=1)
    elbows, wrists = [], []
    for s in (-1.0, 0.0, 0.8):
        _, reached, out = solve(body, side, pose, target, rot, torch.tensor([s], dtype=D))
        assert reached.all()
        assert body.arm_swivel(out, side).item() == pytest.approx(s, abs=1e-9)
        elbows.append(out.joints[0, ARM[side][1]])
        wrists.append(out.joints[0, ARM[side][2]])
    assert (elbows[0] - elbows[1]).norm() > 0.05 and (elbows[2] - elbows[1]).norm() > 0.05
    assert max((w - wrists[0]).norm() for w in wrists) < 1e-9


@pytest.mark.parametrize("side", ["left", "right"])
def test_positive_swivel_moves_the_elbow_outward_and_up(body, side):
    zero = dict(global_orient=torch.zeros(1, 3, dtype=D), body_pose=torch.zeros(1, 21, 3, dtype=D),
                transl=torch.zeros(1, 3, dtype=D))
    shoulder = body.template_joints[ARM[side][0]].double()
    target = (shoulder + torch.tensor([0.0, -0.1, 0.45], dtype=D))[None]
    _, _, natural = solve(body, side, zero, target, torch.eye(3, dtype=D)[None])
    _, _, raised = solve(body, side, zero, target, torch.eye(3, dtype=D)[None],
                         torch.tensor([0.6], dtype=D))
    e0, e1 = natural.joints[0, ARM[side][1]], raised.joints[0, ARM[side][1]]
    out = 1.0 if side == "left" else -1.0
    assert e0[1] < shoulder[1]  # the natural elbow hangs below the shoulder
    assert (e1[0] - e0[0]) * out > 0.01 and e1[1] > e0[1]


@pytest.mark.parametrize("side", ["left", "right"])
def test_elbow_is_a_flexing_hinge(body, side):
    pose, target, rot, swivel = ik_case(body, side, seed=7)
    new_pose, _, _ = solve(body, side, pose, target, rot, swivel)
    elbow = new_pose[:, ARM[side][1] - 1]
    hinge = torch.tensor([0.0, -1.0 if side == "left" else 1.0, 0.0], dtype=D)
    angle = elbow @ hinge
    torch.testing.assert_close(elbow, angle[:, None] * hinge)  # about the hinge only
    assert (angle >= 0).all() and (angle <= constants.ELBOW_MAX_FLEXION + 1e-9).all()


@pytest.mark.parametrize("side", ["left", "right"])
def test_unreachable_targets_are_flagged(body, side):
    pose = random_pose(2, seed=8, scale=0.2)
    out = body(**pose)
    shoulder = out.joints[:, ARM[side][0]]
    dmin, dmax = body.arm_reach(side)
    direction = torch.nn.functional.normalize(torch.tensor([[0.2, -0.5, 1.0], [1.0, 0.3, 0.1]],
                                                           dtype=D), dim=-1)
    far = shoulder + direction * (dmax + 0.2)
    near = shoulder + direction * (0.5 * dmin)
    for target, dist in ((far, dmax), (near, dmin)):
        _, reached, posed = solve(body, side, pose, target, torch.eye(3, dtype=D).expand(2, 3, 3))
        assert not reached.any()
        wrist = posed.joints[:, ARM[side][2]]
        torch.testing.assert_close(wrist, shoulder + direction * dist)  # as far as it can
    _, reached, _ = solve(body, side, pose, shoulder + direction * (dmax - 1e-3),
                          torch.eye(3, dtype=D).expand(2, 3, 3))
    assert reached.all()


def test_ik_on_the_shoulder_itself_is_finite(body):
    pose = random_pose(1, seed=9, scale=0.0)
    shoulder = body(**pose).joints[:, ARM["left"][0]]
    new_pose, reached, out = solve(body, "left", pose, shoulder, torch.eye(3, dtype=D)[None])
    assert not reached.any() and torch.isfinite(new_pose).all()


# ---------------------------------------------------------- validation
@pytest.mark.parametrize("name, value", [
    ("global_orient", torch.zeros(2, 4)),
    ("body_pose", torch.zeros(2, 20, 3)),
    ("transl", torch.zeros(3)),
    ("left_hand_pose", torch.zeros(2, 44)),
    ("jaw_pose", torch.zeros(1, 3)),
])
def test_bad_shapes_name_the_argument(body, name, value):
    args = dict(global_orient=torch.zeros(2, 3), body_pose=torch.zeros(2, 21, 3),
                transl=torch.zeros(2, 3))
    args[name] = value
    with pytest.raises(InputError, match=name):
        body(**args)


def test_nan_names_the_argument(body):
    bad = torch.zeros(1, 21, 3)
    bad[0, 3, 1] = float("nan")
    with pytest.raises(InputError, match="body_pose"):
        body(torch.zeros(1, 3), bad, torch.zeros(1, 3))
    with pytest.raises(InputError, match="wrist_pos"):
        body.solve_arm("left", torch.zeros(1, 3), torch.zeros(1, 63), torch.zeros(1, 3),
                       torch.full((1, 3), float("nan")), torch.eye(3)[None])
    with pytest.raises(InputError, match="side"):
        body.solve_arm("middle", torch.zeros(1, 3), torch.zeros(1, 63), torch.zeros(1, 3),
                       torch.zeros(1, 3), torch.eye(3)[None])
    with pytest.raises(InputError, match="height"):
        ProceduralBody(height=170.0)
