"""``nearest-arm``: retrieval of finger poses by arm and wrist motion alone (issue #16's
probe). Its key is in the body's frame, reads no object, and a training frame finds
itself."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from grip_bench.core import constants as C
from grip_bench.core.frames import SIDES
from grip_bench.data.grab_io import list_sequences, read_grab
from grip_bench.data.splits import sequences_in_split
from grip_bench.methods.api import METHOD_MODULES, METHODS, PredictContext, TrainContext, load_all
from tests.grip_fixtures import tiny_profile, write_grip_dataset


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return write_grip_dataset(tmp_path_factory.mktemp("data"), T=16)


def _train(root: Path, out: Path, n_components: int = 500) -> Path:
    profile = tiny_profile()
    profile["nearest"] = {**profile["nearest"], "n_components": n_components}
    return METHODS.get("nearest-arm").build().train(
        root, out, TrainContext(profile=profile, progress=False))


@pytest.fixture(scope="module")
def trained(root, tmp_path_factory) -> Path:
    return _train(root, tmp_path_factory.mktemp("ckpt") / "na.pt")


def _turned(seq, rot: Rotation, shift: np.ndarray):
    """The whole scene turned by ``rot`` about the origin and moved by ``shift``: body root,
    hand wrists and object (positions of a row of points ``p -> R p + shift``)."""
    R = rot.as_matrix()

    def orient(aa):
        return (rot * Rotation.from_rotvec(np.asarray(aa, float))).as_rotvec().astype(aa.dtype)

    def move(p):
        return (np.asarray(p, float) @ R.T + shift).astype(p.dtype)

    body = {**seq.body, "global_orient": orient(seq.body["global_orient"]),
            "transl": move(seq.body["transl"])}
    hands = {k: {**getattr(seq, k), "global_orient": orient(getattr(seq, k)["global_orient"]),
                 "transl": move(getattr(seq, k)["transl"])} for k in ("rhand", "lhand")}
    return replace(seq, body=body, **hands)


def test_registered_as_a_probe():
    load_all()
    spec = METHODS.get("nearest-arm")
    # a reference row of Table 2 (the table file says so); on the leaderboard it competes
    assert not spec.reference and spec.trainable and spec.variant_of is None and spec.clean
    assert "object" not in spec.needs
    assert "grip_baselines.nearest_arm" in METHOD_MODULES


def test_arm_features_layout_window_and_body_frame(root):
    from grip_baselines.nearest_arm import ARM_JOINTS, BLOCKS, FEAT_DIM, arm_features

    from grip_bench.bodies.layouts import SMPLX_INDEX
    from grip_bench.geometry.rotations import axis_angle_to_rotation_6d

    seq = read_grab(list_sequences(root)[0])
    T, W = seq.n_frames, len(C.NEAREST_ARM_OFFSETS)
    f = arm_features(seq)
    assert f.shape == (T, FEAT_DIM) == (T, sum(n for _, n in BLOCKS))
    arms = f[:, :W * 24].reshape(T, W, 4, 6)
    bp = np.asarray(seq.body["body_pose"], float).reshape(T, 21, 3)
    want = axis_angle_to_rotation_6d(bp[:, [SMPLX_INDEX[j] - 1 for j in ARM_JOINTS]])
    mid = C.NEAREST_ARM_OFFSETS.index(0)
    np.testing.assert_allclose(arms[:, mid], want, atol=1e-12)
    np.testing.assert_allclose(arms[0, 0], want[0], atol=1e-12)  # clamped at the start
    np.testing.assert_allclose(arms[-1, -1], want[-1], atol=1e-12)  # and at the end
    # wrist positions: R_root^T (wrist - transl) at the window's centre
    pos = f[:, W * 24:W * 30].reshape(T, W, 2, 3)[:, mid]
    R = Rotation.from_rotvec(np.asarray(seq.body["global_orient"], float)).as_matrix()
    for k, side in enumerate(SIDES):
        d = np.asarray(seq.hand_params(side)["transl"], float) - seq.body["transl"]
        np.testing.assert_allclose(pos[:, k], np.einsum("tji,tj->ti", R, d), atol=1e-9)
    # the body frame: turning and moving the whole scene changes no key
    turned = _turned(seq, Rotation.from_euler("xyz", [0.3, -1.1, 0.7]), np.array([1.0, 0.2, -3]))
    np.testing.assert_allclose(arm_features(turned), f, atol=1e-5)  # float32 storage


def test_block_scale_equalises_blocks_and_index_finds_its_items():
    from grip_baselines.nearest_arm import BLOCKS, FEAT_DIM, block_scale, build_index
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    feats = rng.normal(size=(60, FEAT_DIM)) * np.repeat([0.1, 3.0, 0.5], [n for _, n in BLOCKS])
    scaled = feats * block_scale(feats)
    at = 0
    for _, n in BLOCKS:
        assert scaled[:, at:at + n].var(0).sum() == pytest.approx(1.0)
        at += n
    poses = rng.normal(size=(60, 2, 45))
    index = build_index(feats, poses, 60)  # full rank: distances are preserved
    _, nn = cKDTree(index.keys.numpy()).query(index.reduce(feats[[4, 33]]))
    assert nn.tolist() == [4, 33]


def test_train_predict_copies_training_frames_and_ignores_the_object(root, trained, tmp_path):
    m = METHODS.get("nearest-arm").build()
    m.load(trained)
    ctx = PredictContext(library=None)  # no object library: nothing reads the object
    train_seq = read_grab(sequences_in_split(root, "train")[0])
    pred = m.predict(train_seq, ctx)
    for side in SIDES:  # each training frame retrieves itself (full-rank PCA here)
        np.testing.assert_allclose(pred.hand_params(side)["hand_pose"],
                                   train_seq.hand_params(side)["hand_pose"], atol=1e-6)
        np.testing.assert_array_equal(pred.hand_params(side)["transl"],
                                      train_seq.hand_params(side)["transl"])
    test_seq = read_grab(sequences_in_split(root, "test")[0])
    got = m.predict(test_seq, ctx)
    assert got.rhand["hand_pose"].shape == test_seq.rhand["hand_pose"].shape
    assert np.isfinite(got.rhand["hand_pose"]).all() and np.isfinite(got.lhand["hand_pose"]).all()
    moved = replace(test_seq, obj_name="apple",
                    object={**test_seq.object, "transl": test_seq.object["transl"] + 0.3})
    again = m.predict(moved, ctx)
    for side in SIDES:
        np.testing.assert_array_equal(again.hand_params(side)["hand_pose"],
                                      got.hand_params(side)["hand_pose"])
    # deterministic: a second training writes the same index
    from grip_baselines.nearest_arm import ArmIndexConfig

    from grip_bench.core.checkpoint import load_checkpoint

    second = _train(root, tmp_path / "again.pt")
    a = load_checkpoint(trained, {"index": ArmIndexConfig}).state["index"]
    b = load_checkpoint(second, {"index": ArmIndexConfig}).state["index"]
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
