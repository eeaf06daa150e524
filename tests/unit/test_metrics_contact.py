"""Contact metrics: loop references, hand-worked values, NaN conventions."""

import numpy as np
import pytest

from grip_bench.core import constants as C
from grip_bench.metrics import (
    contact_consistency,
    contact_drift,
    contact_frequency,
    contact_ratio,
    grasp_mask,
)


def test_grasp_mask_and_ratio_match_loops():
    rng = np.random.default_rng(3)
    gt = rng.uniform(-0.002, 0.03, size=(50, 30))
    pred = rng.uniform(-0.002, 0.03, size=(50, 30))
    mask_ref = np.array([min(row) <= C.CONTACT_THRESHOLD for row in gt])
    np.testing.assert_array_equal(grasp_mask(gt), mask_ref)
    hits = [min(pred[t]) <= C.CONTACT_THRESHOLD for t in range(50) if mask_ref[t]]
    assert contact_ratio(pred, mask_ref) == pytest.approx(sum(hits) / len(hits))


def test_inside_counts_as_contact_and_no_grasp_is_nan():
    d = np.array([[0.02, -0.01], [0.02, 0.02]])  # frame 0: one vertex 1 cm inside
    np.testing.assert_array_equal(grasp_mask(d), [True, False])
    assert contact_ratio(d, np.array([True, True])) == 0.5
    assert np.isnan(contact_ratio(d, np.array([False, False])))


def test_cc_hand_worked_and_nan_without_contact():
    gt_v = np.zeros((2, 3, 3))
    pred_v = gt_v.copy()
    pred_v[:, 0, 0] = 0.004  # 4 mm error on vertex 0
    pred_v[:, 1, 0] = 0.010  # 10 mm error on vertex 1 (not in contact)
    gt_d = np.array([[0.001, 0.01, -0.001], [0.01, 0.01, 0.01]])  # vertices 0, 2 in contact at t=0
    cc = contact_consistency(pred_v, gt_v, gt_d)
    assert cc[0] == pytest.approx(0.002)  # (4 + 0) / 2 mm
    assert np.isnan(cc[1])


def test_cc_matches_loop():
    rng = np.random.default_rng(4)
    pred, gt = rng.normal(size=(2, 6, 25, 3)) * 0.01
    d = rng.uniform(-0.001, 0.01, size=(6, 25))
    for t in range(6):
        sel = [i for i in range(25) if d[t, i] <= C.CC_THRESHOLD]
        ref = np.mean([np.linalg.norm(pred[t, i] - gt[t, i]) for i in sel]) if sel else np.nan
        np.testing.assert_allclose(contact_consistency(pred, gt, d)[t], ref, rtol=1e-12)


def test_rigid_grasp_has_zero_drift_and_sliding_is_measured():
    T, V = 5, 4
    d = np.full((T, V), 0.001)
    local = np.tile(np.random.default_rng(5).normal(size=(1, V, 3)), (T, 1, 1))
    mask = np.ones(T, bool)
    drift = contact_drift(d, local, mask)
    assert np.isnan(drift[0]) and np.allclose(drift[1:], 0.0)
    local[:, 0, 0] += 0.002 * np.arange(T)  # vertex 0 slides 2 mm per frame, others hold
    np.testing.assert_allclose(contact_drift(d, local, mask)[1:], 0.0005)


def test_drift_uses_prediction_contacts_and_grasp_frames():
    d = np.array([[0.001, 0.02], [0.001, 0.001], [0.001, 0.001]])
    local = np.zeros((3, 2, 3))
    local[:, :, 1] = [[0.0, 0.0], [0.003, 0.05], [0.006, 0.08]]
    drift = contact_drift(d, local, np.array([True, True, False]))
    assert drift[1] == pytest.approx(0.003)  # vertex 1 was not in contact at frame 0
    assert np.isnan(drift[2])  # frame 2 is not a grasp frame


def test_contact_frequency_matches_loop():
    rng = np.random.default_rng(6)
    d = rng.uniform(-0.001, 0.01, size=(20, 8))
    mask = rng.random(20) > 0.3
    ref = [
        np.mean([d[t, i] <= C.CONTACT_THRESHOLD for t in range(20) if mask[t]]) for i in range(8)
    ]
    np.testing.assert_allclose(contact_frequency(d, mask), ref)
    assert np.isnan(contact_frequency(d, np.zeros(20, bool))).all()
