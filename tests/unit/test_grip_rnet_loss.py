"""RNet's geometric loss terms: the differentiable grid distance, hand placement and depth."""

import numpy as np
import pytest
import torch
import trimesh

from grip_bench.data.library import ObjectLibrary
from grip_bench.geometry.distance import DistanceField
from grip_bench.grip import train as TR
from grip_bench.grip.data import build_split, hand_model
from grip_bench.nn.terms import penetration_depth
from tests.grip_fixtures import write_grip_dataset


@pytest.fixture(scope="module")
def sphere():
    return DistanceField(trimesh.creation.icosphere(subdivisions=4, radius=0.05))


def test_grid_distance_matches_the_field_and_points_outward(sphere):
    rng = np.random.default_rng(0)
    p = rng.normal(size=(500, 3))
    p = p / np.linalg.norm(p, axis=1, keepdims=True) * rng.uniform(0.03, 0.075, (500, 1))
    x = torch.tensor(p, requires_grad=True)
    d = sphere.grid_signed_distance(x)
    assert d.shape == (500,) and d.dtype == torch.float32
    np.testing.assert_allclose(d.detach().numpy(), sphere.signed_distance(p), atol=5e-4)
    d.sum().backward()
    normal = p / np.linalg.norm(p, axis=1, keepdims=True)
    cos = (x.grad.numpy() * normal).sum(1) / np.linalg.norm(x.grad.numpy(), axis=1)
    assert np.quantile(cos, 0.05) > 0.95  # the gradient is the outward normal
    far = sphere.grid_signed_distance(torch.tensor([[1.0, 0.0, 0.0]]))
    assert torch.isfinite(far).all() and far.item() > 0.02  # beyond the grid: the border value


def test_penetration_depth_sums_inside_vertices_per_hand():
    sd = torch.tensor([[[0.01, -0.002, -0.003], [0.0, 0.02, -0.001]]])  # (1, 2 hands, 3 vertices)
    assert penetration_depth(sd).item() == pytest.approx((0.005 + 0.001) / 2)
    mask = torch.tensor([[True, False]])
    assert penetration_depth(sd, mask).item() == pytest.approx(0.005)
    assert penetration_depth(sd, torch.zeros(1, 2, dtype=bool)).item() == 0.0


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    root = write_grip_dataset(tmp_path_factory.mktemp("rnetloss"), T=16)
    fs = build_split(root, "train", cache_dir=tmp_path_factory.mktemp("feat"), seed=0)
    return root, fs


def _batch(fs, idx, objects):
    b = TR.placement(fs, idx, objects)
    return {k: torch.as_tensor(v) if k == "object" else torch.as_tensor(v, dtype=torch.float32)
            for k, v in b.items()}


def test_hand_object_distance_matches_a_numpy_reference(frames):
    root, fs = frames
    lib = ObjectLibrary(root)
    objects = sorted({str(o) for o in fs.objects})
    dist = TR.HandObjectDistance(lib, objects, n_vertices=64)
    idx = np.arange(0, len(fs), 3)
    got = dist(torch.as_tensor(fs.gt_poses[idx]), _batch(fs, idx, objects)).numpy()  # (N, 2, K)
    for n, f in enumerate(idx):  # naive: one frame, one hand at a time, exact distances
        name = str(fs.objects[fs.seq_id[f]])
        rot = torch.as_tensor(TR.rotation_6d_to_matrix(torch.as_tensor(fs.gt_poses[f][None])))
        local = (
            hand_model(float(fs.hand_scale[f])).vertices(rot.float(), dist.ids)[0].double().numpy()
        )
        for h in range(2):
            world = local[h] @ fs.wrist_rot[f, h].T.astype(float) + fs.wrist_transl[f, h]
            obj = (world - fs.obj_transl[f]) @ fs.obj_rot[f].T.astype(float)
            want = lib.field(name).signed_distance(obj)
            near = np.abs(want) < 0.02  # the grid's exact band; beyond, border values
            np.testing.assert_allclose(got[n, h][near], want[near], atol=1e-3)
    assert (np.abs(got) < 0.02).any()


def test_a_gradient_step_on_the_penetration_term_lifts_the_fingers_out(frames):
    root, fs = frames
    lib = ObjectLibrary(root)
    objects = sorted({str(o) for o in fs.objects})
    dist = TR.HandObjectDistance(lib, objects)
    idx = np.flatnonzero(fs.gt_min_dist.min(1) < 0.01)
    aa = TR.rotation_6d_to_axis_angle(torch.as_tensor(fs.gt_poses[idx], dtype=torch.float64))
    aa[..., 2] += 0.8  # curl every finger joint into the object
    from grip_bench.geometry.rotations import axis_angle_to_rotation_6d

    poses = axis_angle_to_rotation_6d(aa).float().requires_grad_(True)
    b = _batch(fs, idx, objects)
    before = penetration_depth(dist(poses, b))
    assert before.item() > 0
    before.backward()
    with torch.no_grad():
        after = penetration_depth(dist(poses - 0.5 * poses.grad / poses.grad.abs().max(), b))
    assert after.item() < before.item()
