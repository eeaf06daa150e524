"""nearest-neighbour's training items: drawing the kept rows while the sequences are read
gives the arrays of keeping every frame and indexing afterwards (the old form, below)."""

from dataclasses import replace

import numpy as np
import pytest
from grip_baselines.nearest import NearestTrainConfig, _training_items, sensor_features

from grip_bench.core.frames import SIDES, mirror_pose
from grip_bench.data.grab_io import list_sequences, read_grab
from grip_bench.data.library import ObjectLibrary
from tests.baseline_fixtures import baseline_dataset


def _all_then_keep(seqs, library, cfg, seed):
    """Every frame's key and pose, then the seeded draw: the reference."""
    feats, poses = [], []
    for seq in seqs:
        f = sensor_features(library, seq)
        for k, side in enumerate(SIDES):
            pose = np.asarray(seq.hand_params(side)["hand_pose"], float)
            feats.append(f[k])
            poses.append(mirror_pose(pose) if side == "left" else pose)
    feats, poses = np.concatenate(feats), np.concatenate(poses)
    if cfg.max_frames and len(feats) > cfg.max_frames:
        keep = np.sort(np.random.default_rng(seed).choice(len(feats), cfg.max_frames,
                                                          replace=False))
        feats, poses = feats[keep], poses[keep]
    return feats, poses


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = baseline_dataset(tmp_path_factory.mktemp("nn"), T=12)
    return [read_grab(p) for p in list_sequences(root)], ObjectLibrary(root)


@pytest.mark.parametrize("max_frames", [0, 1, 7, 40, 10_000])
@pytest.mark.parametrize("seed", [0, 3])
def test_kept_rows_are_the_reference_bit_for_bit(data, max_frames, seed):
    seqs, library = data
    cfg = replace(NearestTrainConfig(), max_frames=max_frames)
    feats, poses = _training_items(seqs, library, cfg, seed)
    ref_f, ref_p = _all_then_keep(seqs, library, cfg, seed)
    total = sum(2 * s.n_frames for s in seqs)
    assert len(feats) == (min(max_frames, total) if max_frames else total)
    assert feats.tobytes() == ref_f.tobytes() and poses.tobytes() == ref_p.tobytes()
