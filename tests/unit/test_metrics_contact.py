"""Contact metrics: loop references, hand-worked values, NaN conventions."""

import numpy as np
import pytest

from grip_bench.core import constants as C
from grip_bench.metrics import (
    contact_consistency,
    contact_deviation,
    contact_drift,
    contact_frequency,
    contact_ratio,
    grasp_mask,
    held_mask,
    object_lift,
)
from grip_bench.metrics.contact import strict_contact


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


def naive_drift(pred, gt, gt_sd, mask, thr=C.CC_THRESHOLD):
    """Loop reference of ARCTIC-style drift on the GT's contact vertices."""
    out = [np.nan]
    for t in range(1, len(pred)):
        sel = [i for i in range(pred.shape[1]) if gt_sd[t, i] <= thr and gt_sd[t - 1, i] <= thr]
        if not (mask[t] and mask[t - 1]) or not sel:
            out.append(np.nan)
            continue
        out.append(np.mean([np.linalg.norm((pred[t, i] - pred[t - 1, i])
                                           - (gt[t, i] - gt[t - 1, i])) for i in sel]))
    return np.array(out)


def test_drift_is_zero_for_gt_and_rigid_offsets_and_measures_sliding():
    T, V = 5, 4
    gt_sd = np.full((T, V), 0.001)
    gt = np.tile(np.random.default_rng(5).normal(size=(1, V, 3)), (T, 1, 1))
    mask = np.ones(T, bool)
    assert np.isnan(contact_drift(gt, gt, gt_sd, mask)[0])
    np.testing.assert_allclose(contact_drift(gt, gt, gt_sd, mask)[1:], 0.0)
    np.testing.assert_allclose(contact_drift(gt + [0.01, 0, 0], gt, gt_sd, mask)[1:], 0.0)
    pred = gt.copy()
    pred[:, :, 0] += 0.002 * np.arange(T)[:, None]  # the whole hand slides 2 mm per frame
    np.testing.assert_allclose(contact_drift(pred, gt, gt_sd, mask)[1:], 0.002)


def test_drift_uses_the_ground_truths_vertices_so_not_touching_is_not_zero():
    gt_sd = np.array([[0.001, 0.05], [0.001, 0.05], [0.001, 0.05]])
    gt = np.zeros((3, 2, 3))
    pred = np.zeros((3, 2, 3))
    pred[:, 0, 1] = [0.0, 0.01, 0.02]  # far from the object, moving: its own distances unused
    drift = contact_drift(pred, gt, gt_sd, np.array([True, True, False]))
    assert drift[1] == pytest.approx(0.01)
    assert np.isnan(drift[2])  # frame 2 is not held


def test_drift_matches_loop():
    rng = np.random.default_rng(8)
    pred, gt = rng.normal(size=(2, 12, 9, 3)) * 0.01
    gt_sd = rng.uniform(-0.001, 0.004, size=(12, 9))
    mask = rng.random(12) > 0.2
    np.testing.assert_allclose(contact_drift(pred, gt, gt_sd, mask),
                               naive_drift(pred, gt, gt_sd, mask), rtol=1e-12)


def test_cdev_hand_worked_and_loop():
    gt_sd = np.array([[0.001, 0.01, -0.001], [0.03, 0.03, 0.03]])
    pred_sd = np.array([[0.004, 0.0, -0.002], [0.0, 0.0, 0.0]])
    out = contact_deviation(pred_sd, gt_sd)
    assert out[0] == pytest.approx((0.004 + 0.002) / 2)  # inside deviates as much as outside
    assert np.isnan(out[1])
    rng = np.random.default_rng(2)
    g, p = rng.uniform(-0.002, 0.006, size=(2, 10, 7))
    ref = [np.mean([abs(p[t, i]) for i in range(7) if g[t, i] <= C.CC_THRESHOLD]) if
           (g[t] <= C.CC_THRESHOLD).any() else np.nan for t in range(10)]
    np.testing.assert_allclose(contact_deviation(p, g), ref, rtol=1e-12)


def test_object_lift_of_a_cube_raised_one_centimetre():
    c = (-0.02, 0.02)
    cube = np.array([[x, y, z] for x in c for y in c for z in c])
    R = np.tile(np.eye(3), (3, 1, 1))
    t = np.array([[0, 0.02, 0], [0, 0.025, 0], [0, 0.03, 0]])
    np.testing.assert_allclose(object_lift(cube, R, t, np.array([0, 1.0, 0])), [0, 0.005, 0.01])
    # turning the cube about its centre by 45 degrees lowers its lowest corner
    c, s_ = np.cos(np.pi / 4), np.sin(np.pi / 4)
    R[1] = [[c, s_, 0], [-s_, c, 0], [0, 0, 1]]
    lift = object_lift(cube, R, np.zeros((3, 3)), np.array([0, 1.0, 0]))
    assert lift[1] == pytest.approx(0.02 - 0.02 * np.sqrt(2))


def naive_held(sd, finger, lift, touch=C.HELD_TOUCH, min_lift=C.HELD_MIN_LIFT, trim=C.HELD_TRIM):
    raw = []
    for t in range(len(sd)):
        thumb = any(sd[t, i] <= touch for i in range(sd.shape[1]) if finger[i] == 0)
        other = any(sd[t, i] <= touch for i in range(sd.shape[1]) if finger[i] > 0)
        raw.append(thumb and other and lift[t] >= min_lift)
    out = [False] * len(raw)
    t = 0
    while t < len(raw):
        if raw[t]:
            e = t
            while e < len(raw) and raw[e]:
                e += 1
            for k in range(t + trim, e - trim):
                out[k] = True
            t = e
        else:
            t += 1
    return np.array(out)


def test_held_mask_cases_and_loop():
    finger = np.array([0, 1, 2, -1])
    T = 30
    sd = np.full((T, 4), 0.01)
    sd[:, [0, 1]] = 0.001
    lift = np.full(T, 0.01)
    held = held_mask(sd, finger, lift)
    assert not held[:5].any() and not held[-5:].any() and held[5:-5].all()
    lift[12] = 0.004  # one frame resting: two runs, each trimmed
    held = held_mask(sd, finger, lift)
    assert held[5:7].all() and not held[7:18].any() and held[18:25].all()
    sd2 = sd.copy()
    sd2[:, 1] = 0.01  # the thumb alone grips nothing (the palm does not count)
    sd2[:, 3] = 0.0
    assert not held_mask(sd2, finger, np.full(T, 0.01)).any()
    short = np.full(10, 0.01)  # a 10-frame hold vanishes under the 5 + 5 trim
    assert not held_mask(sd[:10], finger, short).any()
    rng = np.random.default_rng(4)
    sd3 = rng.uniform(0, 0.004, size=(80, 6))
    f3 = np.array([0, 1, 2, 3, 4, -1])
    lift3 = np.where(rng.random(80) > 0.1, 0.01, 0.0)
    np.testing.assert_array_equal(held_mask(sd3, f3, lift3), naive_held(sd3, f3, lift3))


def test_strict_contact_needs_thumb_and_a_finger():
    finger = np.array([0, 1, -1])
    sd = np.array([[0.001, 0.001, 0.05], [0.001, 0.003, 0.0], [-0.001, -0.002, 0.05]])
    np.testing.assert_array_equal(strict_contact(sd, finger), [True, False, True])


def test_contact_frequency_matches_loop():
    rng = np.random.default_rng(6)
    d = rng.uniform(-0.001, 0.01, size=(20, 8))
    mask = rng.random(20) > 0.3
    ref = [
        np.mean([d[t, i] <= C.CONTACT_THRESHOLD for t in range(20) if mask[t]]) for i in range(8)
    ]
    np.testing.assert_allclose(contact_frequency(d, mask), ref)
    assert np.isnan(contact_frequency(d, np.zeros(20, bool))).all()


def _dense_drift(p, g, sd, mask, threshold):
    """The dense form contact_drift had: every (frame, vertex) deviation, masked by np.where."""
    from grip_bench.core.vec import norm3

    touch = sd <= threshold
    sel = touch[1:] & touch[:-1] & (mask[1:] & mask[:-1])[:, None]
    dev = norm3((p[1:] - p[:-1]) - (g[1:] - g[:-1]))
    n = sel.sum(axis=-1)
    out = np.full(p.shape[0], np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        out[1:] = np.where(n > 0, np.where(sel, dev, 0.0).sum(axis=-1) / n, np.nan)
    return out


def test_drift_on_selected_entries_equals_the_dense_form_bit_for_bit():
    """contact_drift computes deviations only where the GT touches in both frames; the sums
    run over all vertices with zeros elsewhere, so the values are the dense ones exactly
    (NaN where no vertex is selected, large random V so pairwise summation matters)."""
    from grip_bench.metrics.contact import contact_drift

    rng = np.random.default_rng(3)
    T, V = 30, 2500
    p, g = rng.normal(0, 0.05, (T, V, 3)), rng.normal(0, 0.05, (T, V, 3))
    sd = rng.uniform(-0.002, 0.02, (T, V))  # ~20 % of the vertices within 2 mm
    mask = np.ones(T, bool)
    mask[[4, 10, 11, 12, 20]] = False  # frames 0, 4-5, 10-13, 20-21 NaN
    got = contact_drift(p, g, sd, mask, C.CC_THRESHOLD)
    ref = _dense_drift(p, g, sd, mask, C.CC_THRESHOLD)
    assert np.isnan(got).sum() == 9 and np.isfinite(got).sum() == T - 9
    np.testing.assert_array_equal(got, ref)  # NaN where NaN
    assert got.tobytes() == ref.tobytes()
    none = contact_drift(p, g, np.full((T, V), 1.0), mask, C.CC_THRESHOLD)
    assert np.isnan(none).all()


def test_cc_from_shared_errors_equals_cc_bit_for_bit():
    from grip_bench.core.vec import norm3
    from grip_bench.metrics.contact import contact_consistency_from_error

    rng = np.random.default_rng(4)
    p, g = rng.normal(0, 0.05, (12, 778, 3)), rng.normal(0, 0.05, (12, 778, 3))
    sd = rng.uniform(-0.002, 0.01, (12, 778))
    sd[3] = 1.0  # a frame without contact: NaN
    a = contact_consistency(p, g, sd, C.CC_THRESHOLD)
    b = contact_consistency_from_error(norm3(p - g), sd, C.CC_THRESHOLD)
    assert np.isnan(a[3]) and a.tobytes() == b.tobytes()
