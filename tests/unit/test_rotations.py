"""Rotation conversions against scipy, round trips, edge angles, gradients."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from grip_bench.geometry import rotations as rot

TOL = 1e-6


def _random_axis_angle(n, seed=0, max_angle=math.pi):
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(0, max_angle, size=(n, 1))


def _wxyz(q_xyzw):
    return np.concatenate([q_xyzw[..., 3:], q_xyzw[..., :3]], -1)


def _t(x):
    return torch.as_tensor(np.asarray(x), dtype=torch.float64)


def _same_rotation_aa(a, b, atol=TOL):
    """Axis-angle vectors equal, or both antipodal representations of a half turn."""
    a, b = np.asarray(a), np.asarray(b)
    close = np.abs(a - b).max(-1) < atol
    half_turn = (np.abs(np.linalg.norm(a, axis=-1) - math.pi) < atol) & (
        np.abs(a + b).max(-1) < atol
    )
    return np.all(close | half_turn)


# --- against scipy ------------------------------------------------------------


def test_axis_angle_to_matrix_matches_scipy():
    aa = _random_axis_angle(500, seed=1, max_angle=3 * math.pi)
    ours = rot.axis_angle_to_matrix(_t(aa)).numpy()
    np.testing.assert_allclose(ours, Rotation.from_rotvec(aa).as_matrix(), atol=TOL)


def test_matrix_to_axis_angle_matches_scipy():
    aa = _random_axis_angle(500, seed=2)
    mats = Rotation.from_rotvec(aa).as_matrix()
    np.testing.assert_allclose(rot.matrix_to_axis_angle(_t(mats)).numpy(), aa, atol=TOL)


def test_quaternion_conversions_match_scipy():
    r = Rotation.random(500, random_state=3)
    q = _wxyz(r.as_quat())
    np.testing.assert_allclose(rot.quaternion_to_matrix(_t(q)).numpy(), r.as_matrix(), atol=TOL)
    ours_q = rot.matrix_to_quaternion(_t(r.as_matrix())).numpy()
    ref_q = rot.standardize_quaternion(_t(q)).numpy()
    np.testing.assert_allclose(ours_q, ref_q, atol=TOL)
    np.testing.assert_allclose(rot.quaternion_to_axis_angle(_t(q)).numpy(), r.as_rotvec(), atol=TOL)
    aa = r.as_rotvec()
    np.testing.assert_allclose(rot.axis_angle_to_quaternion(_t(aa)).numpy(), ref_q, atol=TOL)


def test_rotation_6d_is_first_two_columns():
    r = Rotation.random(50, random_state=4)
    m = r.as_matrix()
    d6 = rot.axis_angle_to_rotation_6d(_t(r.as_rotvec())).numpy()
    np.testing.assert_allclose(d6[:, :3], m[:, :, 0], atol=TOL)
    np.testing.assert_allclose(d6[:, 3:], m[:, :, 1], atol=TOL)


def test_rotation_6d_gram_schmidt_projects_noisy_input():
    r = Rotation.random(50, random_state=5)
    d6 = rot.matrix_to_rotation_6d(_t(r.as_matrix()))
    noisy = 2.5 * d6 + 1e-3 * torch.randn(
        d6.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(0)
    )
    m = rot.rotation_6d_to_matrix(noisy)
    eye = torch.eye(3, dtype=torch.float64).expand_as(m)
    torch.testing.assert_close(m.transpose(-1, -2) @ m, eye, atol=1e-12, rtol=0)
    torch.testing.assert_close(torch.linalg.det(m), torch.ones(50, dtype=torch.float64))
    np.testing.assert_allclose(m.numpy(), r.as_matrix(), atol=2e-3)


def test_hand_worked_quarter_turn_about_z():
    # 90 degrees about z maps x to y: R = [[0,-1,0],[1,0,0],[0,0,1]]; q = (cos 45, 0, 0, sin 45)
    aa = torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64)
    expected = torch.tensor(
        [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64
    )
    torch.testing.assert_close(rot.axis_angle_to_matrix(aa), expected)
    h = math.sqrt(0.5)
    torch.testing.assert_close(
        rot.axis_angle_to_quaternion(aa), torch.tensor([h, 0, 0, h], dtype=torch.float64)
    )
    torch.testing.assert_close(
        rot.axis_angle_to_rotation_6d(aa), torch.tensor([0.0, 1, 0, -1, 0, 0], dtype=torch.float64)
    )


# --- round trips and edge cases ---------------------------------------------------

EDGE_ANGLES = [0.0, 1e-8, 1e-4, 1e-2, 0.5, math.pi - 1e-2, math.pi - 1e-7, math.pi]


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_round_trips_at_edge_angles(angle):
    rng = np.random.default_rng(6)
    axes = rng.normal(size=(64, 3))
    axes = np.concatenate([axes, np.eye(3), -np.eye(3), [[1.0, 1.0, 1.0]]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    aa = _t(axes * angle)
    ref = Rotation.from_rotvec(aa.numpy()).as_matrix()
    m = rot.axis_angle_to_matrix(aa)
    np.testing.assert_allclose(m.numpy(), ref, atol=TOL)
    for back in (
        rot.matrix_to_axis_angle(m),
        rot.quaternion_to_axis_angle(rot.axis_angle_to_quaternion(aa)),
        rot.quaternion_to_axis_angle(rot.matrix_to_quaternion(m)),
        rot.rotation_6d_to_axis_angle(rot.axis_angle_to_rotation_6d(aa)),
    ):
        assert _same_rotation_aa(back.numpy(), aa.numpy())


def test_axis_recovered_near_pi():
    # the skew part of R vanishes at pi; the axis must still come out right
    axis = np.array([0.3, -0.5, 0.81])
    axis /= np.linalg.norm(axis)
    for eps in (1e-3, 1e-7, 1e-10):
        aa = axis * (math.pi - eps)
        back = rot.matrix_to_axis_angle(_t(Rotation.from_rotvec(aa).as_matrix())).numpy()
        np.testing.assert_allclose(back, aa, atol=1e-7)


def test_float32_accuracy_and_dtype():
    aa = _random_axis_angle(1000, seed=7).astype(np.float32)
    aa[:5] *= 1e-6  # tiny angles too
    t = torch.from_numpy(aa)
    m = rot.axis_angle_to_matrix(t)
    assert m.dtype == torch.float32
    np.testing.assert_allclose(
        m.numpy(), Rotation.from_rotvec(aa.astype(np.float64)).as_matrix(), atol=2e-6
    )
    back = rot.matrix_to_axis_angle(m)
    assert back.dtype == torch.float32
    assert _same_rotation_aa(back.numpy(), aa, atol=5e-4)  # float32 near pi loses ~sqrt(eps)
    far = np.linalg.norm(aa, axis=1) < 3.0
    np.testing.assert_allclose(back.numpy()[far], aa[far], atol=1e-5)


def test_batch_shapes_and_numpy_io():
    aa = np.zeros((2, 5, 15, 3))
    m = rot.axis_angle_to_matrix(aa)
    assert isinstance(m, np.ndarray) and m.shape == (2, 5, 15, 3, 3)
    assert rot.matrix_to_rotation_6d(m).shape == (2, 5, 15, 6)
    assert rot.axis_angle_to_quaternion(torch.zeros(4, 3)).shape == (4, 4)
    with pytest.raises(ValueError, match="axis_angle"):
        rot.axis_angle_to_matrix(torch.zeros(4, 4))


# --- gradients ----------------------------------------------------------------------


@pytest.mark.parametrize("angle", [0.0, 1e-8, 1e-3, 1.0, math.pi - 1e-2])
def test_gradcheck_axis_angle_paths(angle):
    axis = torch.tensor([0.36, -0.48, 0.8], dtype=torch.float64)
    aa = (axis * angle).reshape(1, 3).requires_grad_(True)
    for fn in (
        rot.axis_angle_to_matrix,
        rot.axis_angle_to_quaternion,
        rot.axis_angle_to_rotation_6d,
        lambda a: rot.quaternion_to_axis_angle(rot.axis_angle_to_quaternion(a)),
        lambda a: rot.matrix_to_axis_angle(rot.axis_angle_to_matrix(a)),
    ):
        assert torch.autograd.gradcheck(fn, (aa,), eps=1e-7, atol=1e-5)


def test_gradcheck_matrix_and_6d_inputs():
    r = Rotation.random(3, random_state=8)
    m = _t(r.as_matrix()).requires_grad_(True)
    assert torch.autograd.gradcheck(rot.matrix_to_quaternion, (m,), eps=1e-7, atol=1e-5)
    assert torch.autograd.gradcheck(rot.matrix_to_axis_angle, (m,), eps=1e-7, atol=1e-5)
    d6 = _t(r.as_matrix()[:, :, :2].transpose(0, 2, 1).reshape(3, 6)).requires_grad_(True)
    assert torch.autograd.gradcheck(rot.rotation_6d_to_matrix, (d6,), eps=1e-7, atol=1e-5)
    q = _t(_wxyz(r.as_quat())).requires_grad_(True)
    assert torch.autograd.gradcheck(rot.quaternion_to_matrix, (q,), eps=1e-7, atol=1e-5)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_gradients_finite_at_identity_and_half_turn(dtype):
    aa = torch.tensor([[0.0, 0.0, 0.0], [math.pi, 0.0, 0.0], [0.0, 0.0, math.pi]], dtype=dtype)
    aa.requires_grad_(True)
    m = rot.axis_angle_to_matrix(aa)
    (rot.matrix_to_axis_angle(m).sum() + rot.axis_angle_to_quaternion(aa).sum()).backward()
    assert torch.isfinite(aa.grad).all()
    # the identity matrix itself as input
    eye = torch.eye(3, dtype=dtype).repeat(2, 1, 1).requires_grad_(True)
    rot.matrix_to_axis_angle(eye).sum().backward()
    assert torch.isfinite(eye.grad).all()
    # the derivative of R(a) at 0 is the skew generator: dR/da_z [1, 0] = 1
    a = torch.zeros(3, dtype=dtype, requires_grad=True)
    rot.axis_angle_to_matrix(a)[1, 0].backward()
    torch.testing.assert_close(a.grad, torch.tensor([0.0, 0.0, 1.0], dtype=dtype))


# --- properties -----------------------------------------------------------------------

_vec = st.tuples(*[st.floats(-10.0, 10.0, allow_nan=False, width=64)] * 3)


@settings(max_examples=200, deadline=None)
@given(_vec)
def test_property_matrix_is_a_rotation_and_matches_scipy(v):
    aa = _t(v)
    m = rot.axis_angle_to_matrix(aa)
    torch.testing.assert_close(m @ m.T, torch.eye(3, dtype=torch.float64), atol=1e-12, rtol=0)
    assert abs(torch.linalg.det(m).item() - 1.0) < 1e-12
    np.testing.assert_allclose(m.numpy(), Rotation.from_rotvec(np.array(v)).as_matrix(), atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(_vec)
def test_property_all_paths_agree(v):
    aa = _t(v)
    m = rot.axis_angle_to_matrix(aa)
    via_q = rot.quaternion_to_matrix(rot.axis_angle_to_quaternion(aa))
    via_6d = rot.rotation_6d_to_matrix(rot.axis_angle_to_rotation_6d(aa))
    via_back = rot.axis_angle_to_matrix(rot.matrix_to_axis_angle(m))
    for other in (via_q, via_6d, via_back):
        torch.testing.assert_close(other, m, atol=1e-9, rtol=0)
    assert rot.matrix_to_axis_angle(m).norm().item() <= math.pi + 1e-12


@settings(max_examples=100, deadline=None)
@given(
    st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 4).filter(
        lambda q: sum(x * x for x in q) > 1e-6
    )
)
def test_property_quaternion_round_trip(q):
    q = _t(q)
    back = rot.matrix_to_quaternion(rot.quaternion_to_matrix(q))
    expected = rot.standardize_quaternion(q / q.norm())
    if abs(expected[0].item()) < 1e-9:  # half turn: both signs are the same rotation
        assert torch.allclose(back, expected, atol=1e-9) or torch.allclose(
            back, -expected, atol=1e-9
        )
    else:
        torch.testing.assert_close(back, expected, atol=1e-9, rtol=0)
