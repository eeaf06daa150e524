"""GRIP's split features: the voxel split reuses the plain one, and neither depends on how it
was reached (cache or not, torch threads)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest
import torch

from grip_bench.data.grab_io import read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.data.perturb import sequence_rng
from grip_bench.grip.data import FrameSet, build_split, sequence_features, split_files
from grip_bench.sensors import ambient_sensor, stage_one
from tests.grip_fixtures import write_grip_dataset


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return write_grip_dataset(tmp_path_factory.mktemp("gripfeat"), T=10)


def _direct(root, split: str, voxel: bool, seed: int = 0) -> dict:
    """The split's arrays from ``sequence_features`` of each sequence, concatenated."""
    library = ObjectLibrary(root)
    per_seq = []
    for f in split_files(root, split):
        seq = read_grab(f)
        per_seq.append(
            sequence_features(library, seq, voxel=voxel, rng=sequence_rng(seed, seq.name))
        )
    return {k: np.concatenate([s[k] for s in per_seq]) for k in per_seq[0]}


def _assert_same(fs: FrameSet, ref: dict) -> None:
    for f in fields(fs):
        if f.name in ref:
            a = getattr(fs, f.name)
            assert a.dtype == ref[f.name].dtype and np.array_equal(a, ref[f.name]), f.name
    assert (fs.voxel is None) == ("voxel" not in ref)


def test_voxel_split_equals_per_sequence_features(root, tmp_path):
    ref = _direct(root, "train", voxel=True)
    _assert_same(build_split(root, "train", voxel=True), ref)  # no cache
    cached = build_split(root, "train", voxel=True, cache_dir=tmp_path)
    _assert_same(cached, ref)
    assert len(list(tmp_path.glob("grip-train-*.npz"))) == 2  # the plain split is cached on the way
    plain = build_split(root, "train", voxel=False, cache_dir=tmp_path)
    _assert_same(plain, {k: v for k, v in ref.items() if k != "voxel"})
    _assert_same(build_split(root, "train", voxel=True, cache_dir=tmp_path), ref)  # from the cache


def test_features_do_not_depend_on_torch_threads(root):
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        fs = build_split(root, "val", seed=3)
        assert torch.get_num_threads() == 2  # restored after the one-thread build
    finally:
        torch.set_num_threads(before)
    _assert_same(fs, _direct(root, "val", voxel=False, seed=3))


def test_ambient_sensor_is_stage_ones_ambient(root):
    library = ObjectLibrary(root)
    seq = read_grab(split_files(root, "train")[0])
    for kind in ("distance", "voxel", "none"):
        np.testing.assert_array_equal(ambient_sensor(library, seq, None, kind),
                                      stage_one(library, seq, None, kind).ambient)
