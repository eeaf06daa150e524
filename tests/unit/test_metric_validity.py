"""Metric validity (grip_bench.metrics.validity): each degradation does what it says,
measured, and on smoke-sized data every metric keeps its claim (docs/contract.md,
"Metric validity")."""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.data.grab_io import read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.data.posing import hand_poser
from grip_bench.metrics import validity as V
from grip_bench.metrics.evaluate import EvalOptions
from tests.eval_fixtures import grasp_dataset


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("validity")
    files = grasp_dataset(root, T=40)  # a one-handed mug lift, a two-handed cylinder pass
    return root, ObjectLibrary(root), [read_grab(f) for f in files]


def _verts(seq, side):
    return hand_poser(seq, None).pose(side, seq.hand_params(side))


def test_wrist_shift_moves_every_vertex_by_the_level(data):
    _, lib, seqs = data
    gt = seqs[0]
    out = V.wrist_shift(gt, 0.01, lib, seed=0)
    for side in ("right", "left"):
        d = np.linalg.norm(_verts(out, side)[0] - _verts(gt, side)[0], axis=-1)
        np.testing.assert_allclose(d, 0.01, atol=1e-6)  # float32 posing
    same = V.wrist_shift(gt, 0.0, lib, seed=0)
    np.testing.assert_array_equal(same.rhand["transl"], gt.rhand["transl"])


def test_push_and_pull_move_the_contact_region_along_the_normal(data):
    _, lib, seqs = data
    gt = seqs[1]  # the solid cylinder (the mug's wall is thinner than a push)
    field = lib.field(gt.obj_name)

    def sd(seq):
        local = lib.world_to_object(seq, _verts(seq, "right")[0])
        return np.asarray(field.exact_signed_distance(local))

    base = sd(gt)
    near = base.min(axis=1) < 0.005  # frames where the hand touches
    contact = base <= 0.005
    pushed, pulled = sd(V.push_in(gt, 0.005, lib, 0)), sd(V.pull_off(gt, 0.005, lib, 0))
    # the deepest vertex goes about 5 mm deeper (4.8 mm measured: the mean normal of a
    # wrapping contact region is not every vertex's normal)
    assert np.all(pushed.min(axis=1)[near] < base.min(axis=1)[near] - 0.004)

    def mean_contact(d):
        return np.array([d[t][contact[t]].mean() for t in np.flatnonzero(near)])

    assert np.all(mean_contact(pulled) > mean_contact(base) + 0.001)
    assert np.all(mean_contact(pushed) < mean_contact(base) - 0.001)


def test_closing_brings_fingertips_to_the_palm_and_opening_away(data):
    _, lib, seqs = data
    gt = seqs[0]

    def spread(seq):
        j = _verts(seq, "right")[1]  # (T, 21, 3): 16 joints, then 5 tips
        palm = j[:, [0, 1, 4, 7, 10]].mean(axis=1, keepdims=True)
        return np.linalg.norm(j[:, 16:] - palm, axis=-1).mean()

    assert spread(V.finger_close(gt, 0.3, lib, 0)) < spread(gt) < spread(V.finger_open(gt, 0.3,
                                                                                        lib, 0))


def test_noise_is_seeded_and_scales_one_draw(data):
    _, lib, seqs = data
    gt = seqs[1]
    a, b = V.finger_noise(gt, 0.1, lib, 0), V.finger_noise(gt, 0.1, lib, 0)
    np.testing.assert_array_equal(a.rhand["hand_pose"], b.rhand["hand_pose"])
    c = V.finger_noise(gt, 0.2, lib, 0)
    np.testing.assert_allclose(c.rhand["hand_pose"] - gt.rhand["hand_pose"],
                               2 * (a.rhand["hand_pose"] - gt.rhand["hand_pose"]), atol=1e-12)
    d = V.temporal_jitter(gt, 0.001, lib, 1)
    assert not np.array_equal(d.rhand["transl"], V.temporal_jitter(gt, 0.001, lib, 0)
                              .rhand["transl"])


def test_every_metric_keeps_its_claim_on_smoke_data(data):
    root, _, _ = data
    df = V.metric_validity(str(root), "test", sequences=2, seed=0,
                           options=EvalOptions(physics=False, max_iv_frames=2))
    assert set(df["degradation"]) == set(V.DEGRADATIONS)
    claimed = df[df["expected"] != ""]
    assert len(claimed) >= 4 * sum(len(v) for v in V.EXPECTED.values()) * 0.9
    assert V.check_validity(df) == []


def test_check_validity_catches_broken_claims():
    import pandas as pd

    rows = [("wrist", lv, "mpjpe", "mm", v, "up") for lv, v in ((0, 0.0), (5, 4.0), (10, 3.0),
                                                                  (20, 9.0))]
    rows += [("wrist", lv, "jitter", "m/s2", v, "flat") for lv, v in ((0, 1.0), (5, 1.0),
                                                                        (10, 1.5), (20, 1.0))]
    df = pd.DataFrame(rows, columns=["degradation", "level", "metric", "unit", "value",
                                     "expected"])
    bad = V.check_validity(df)
    assert any(b.startswith("mpjpe under wrist: not up") for b in bad)
    assert any(b.startswith("jitter under wrist: not flat") for b in bad)
