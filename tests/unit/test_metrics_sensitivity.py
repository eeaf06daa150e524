"""Geometry sensitivity (metrics/sensitivity.py, report/sensitivity.py): analytic cases, loop
references, the reference predictors' exact scores and the sanity gate."""

import math

import numpy as np
import pandas as pd
import pytest

from grip_bench.core.errors import InputError
from grip_bench.metrics.sensitivity import (
    aperture,
    aperture_change_error,
    change_reproduced,
    pair_scores,
)
from grip_bench.report.sensitivity import render_markdown, sanity_gate, summarize


def _tips(gap_index: float, gap_middle: float) -> np.ndarray:
    """Fingertips (5, 3): thumb at the origin, index and middle at the given distances."""
    t = np.zeros((5, 3))
    t[1] = [gap_index, 0.0, 0.0]
    t[2] = [0.0, gap_middle, 0.0]
    t[3] = [9.0, 9.0, 9.0]  # ring and pinky must not count
    t[4] = [-9.0, 9.0, 9.0]
    return t


def test_aperture_analytic_and_rigid_invariant():
    assert aperture(_tips(0.03, 0.05)) == pytest.approx(0.04)
    rng = np.random.default_rng(0)
    tips = rng.normal(size=(6, 5, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    moved = tips @ q.T + rng.normal(size=3)
    np.testing.assert_allclose(aperture(moved), aperture(tips), rtol=1e-12)
    ref = [0.5 * (math.dist(t[0], t[1]) + math.dist(t[0], t[2])) for t in tips]
    np.testing.assert_allclose(aperture(tips), ref, rtol=1e-12)
    with pytest.raises(InputError):
        aperture(np.zeros((4, 3)))


def test_change_reproduced_analytic_cases():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(7, 50, 3)) * 0.05
    b = a + rng.normal(size=a.shape) * 0.01
    d = b - a
    assert change_reproduced(a, b, a, b) == 1.0  # ground truth
    assert change_reproduced(a, b, a, a) == 0.0  # the same hands twice
    assert change_reproduced(a, b, b, b) == 0.0
    assert change_reproduced(a, b, a, a + 0.5 * d) == pytest.approx(0.5)
    assert change_reproduced(a, b, a, a + 0.75 * d) == pytest.approx(0.75)
    assert change_reproduced(a, b, a, a - d) == 0.0  # the opposite change: clipped
    assert change_reproduced(a, b, a, a + 2 * d) == 0.0  # twice the change: no better than none
    # a method's own offset shared by both members does not matter, only its change
    off = rng.normal(size=a.shape) * 0.02
    assert change_reproduced(a, b, a + off, b + off) == pytest.approx(1.0)


def test_change_reproduced_matches_loop_reference():
    rng = np.random.default_rng(2)
    ga, gb, noise_a, noise_b = rng.normal(size=(4, 3, 8, 3))
    pa, pb = ga + 0.2 * noise_a, gb + 0.2 * noise_b  # a method near the truth: inside (0, 1)
    num = den = 0.0
    for t in range(3):
        for v in range(8):
            for k in range(3):
                dg = gb[t, v, k] - ga[t, v, k]
                dm = pb[t, v, k] - pa[t, v, k]
                num += (dm - dg) ** 2
                den += dg ** 2
    ref = min(max(1.0 - math.sqrt(num) / math.sqrt(den), 0.0), 1.0)
    assert 0.0 < ref < 1.0
    assert change_reproduced(ga, gb, pa, pb) == pytest.approx(ref, rel=1e-12)


def test_change_reproduced_nan_without_change_or_frames():
    a = np.ones((4, 10, 3))
    assert math.isnan(change_reproduced(a, a, a, a + 0.01))
    assert math.isnan(change_reproduced(a, a + 1e-6, a, a))  # below CF_MIN_GT_RMS
    e = np.zeros((0, 10, 3))
    assert math.isnan(change_reproduced(e, e, e, e))
    with pytest.raises(InputError):
        change_reproduced(a, a, a, np.ones((4, 11, 3)))


def test_aperture_change_error_analytic_and_reference():
    ga = np.stack([_tips(0.03, 0.03)] * 2)
    gb = np.stack([_tips(0.05, 0.05)] * 2)  # GT opens by 20 mm
    np.testing.assert_allclose(aperture_change_error(ga, gb, ga, gb), 0.0, atol=1e-15)
    np.testing.assert_allclose(aperture_change_error(ga, gb, ga, ga), 0.02, rtol=1e-12)
    pb = np.stack([_tips(0.035, 0.035)] * 2)  # the method opens by 5 mm
    np.testing.assert_allclose(aperture_change_error(ga, gb, ga, pb), 0.015, rtol=1e-12)
    rng = np.random.default_rng(3)
    t = rng.normal(size=(4, 5, 5, 3))
    ap = lambda x: 0.5 * (math.dist(x[0], x[1]) + math.dist(x[0], x[2]))  # noqa: E731
    ref = [abs((ap(t[3, f]) - ap(t[2, f])) - (ap(t[1, f]) - ap(t[0, f]))) for f in range(5)]
    np.testing.assert_allclose(aperture_change_error(*t), ref, rtol=1e-12)


def _pair(T=6, V=20, seed=4):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(T, V, 3)) * 0.05
    b = a + rng.normal(size=a.shape) * 0.01
    tips_a, tips_b = a[:, :5], b[:, :5]
    return a, b, tips_a, tips_b


def test_pair_scores_references_masks_and_mpvpe():
    a, b, ta, tb = _pair()
    held_a = np.array([0, 1, 1, 1, 1, 0], bool)
    held_b = np.array([0, 0, 1, 1, 1, 1], bool)
    gt = pair_scores(a, b, a, b, (ta, tb, ta, tb), held_a, held_b)
    assert gt["reproduced"] == 1.0 and gt["aperture_error"] == 0.0
    assert gt["mpvpe_a"] == 0.0 and gt["mpvpe_b"] == 0.0 and gt["n_frames"] == 3
    same = pair_scores(a, b, a, a, (ta, tb, ta, ta), held_a, held_b)
    assert same["reproduced"] == 0.0
    both = held_a & held_b
    ap = lambda x: 0.5 * (np.linalg.norm(x[:, 1] - x[:, 0], axis=-1)  # noqa: E731
                          + np.linalg.norm(x[:, 2] - x[:, 0], axis=-1))
    assert same["aperture_error"] == pytest.approx(np.abs(ap(tb) - ap(ta))[both].mean())
    assert same["gt_aperture_change"] == pytest.approx((ap(tb) - ap(ta))[both].mean())
    # MPVPE B: on B's own held frames, loop reference
    ref = np.mean([np.mean([math.dist(a[t, v], b[t, v]) for v in range(a.shape[1])])
                   for t in np.flatnonzero(held_b)])
    assert same["mpvpe_b"] == pytest.approx(ref, rel=1e-12)
    assert same["mpvpe"] == pytest.approx(0.5 * ref)


def test_pair_scores_nan_without_held_frames_and_shape_errors():
    a, b, ta, tb = _pair()
    none = np.zeros(len(a), bool)
    s = pair_scores(a, b, a, b, (ta, tb, ta, tb), none, none)
    assert s["n_frames"] == 0
    for k in ("reproduced", "aperture_error", "mpvpe_a", "mpvpe_b", "mpvpe"):
        assert math.isnan(s[k]), k
    with pytest.raises(InputError):
        pair_scores(a, b, a, b[:-1], (ta, tb, ta, tb), none, none)
    with pytest.raises(InputError):
        pair_scores(a, b, a, b, (ta, tb, ta, tb), none[:-1], none)
    with pytest.raises(InputError):
        pair_scores(a, b, a, b, (ta[:, :4], tb[:, :4], ta[:, :4], tb[:, :4]), none, none)


def _rows(gt_value=1.0):
    rows = []
    for k, fam in enumerate(["mug", "mug", "cube", "apple"]):
        base = {"pair": f"cf{k}", "family": fam, "variant": "larger", "side": "right",
                "grasp_kind": "power", "gt_aperture_change": 0.01, "n_frames": 10}
        rows += [
            {**base, "method": "gt", "reproduced": gt_value, "aperture_error": 0.0,
             "mpvpe_a": 0.0, "mpvpe_b": 0.0, "mpvpe": 0.0},
            {**base, "method": "same-hands", "reproduced": 0.0, "aperture_error": 0.01,
             "mpvpe_a": 0.0, "mpvpe_b": 0.004, "mpvpe": 0.002},
            {**base, "method": "weak", "reproduced": 0.2 + 0.01 * k, "aperture_error": 0.008,
             "mpvpe_a": 0.003, "mpvpe_b": 0.005, "mpvpe": 0.004},
            {**base, "method": "strong", "reproduced": 0.7, "aperture_error": 0.003,
             "mpvpe_a": 0.002, "mpvpe_b": 0.002, "mpvpe": 0.002},
        ]
    return pd.DataFrame(rows)


def test_summary_ranks_methods_and_keeps_references_last():
    s = summarize(_rows(), n_boot=200)
    assert list(s["method"]) == ["strong", "weak", "gt", "same-hands"]
    weak = s.set_index("method").loc["weak"]
    assert weak["reproduced"] == pytest.approx(100 * (0.2 + 0.015))
    assert weak["reproduced_lo"] <= weak["reproduced"] <= weak["reproduced_hi"]
    assert weak["aperture_error"] == pytest.approx(8.0)
    assert s.set_index("method").loc["gt", "reproduced"] == 100.0


def test_sanity_gate_passes_on_exact_references_and_fails_otherwise():
    gate = sanity_gate(_rows())
    assert all(ok for _, ok, _ in gate)
    bad = sanity_gate(_rows(gt_value=0.97))
    assert not bad[0][1] and bad[1][1]
    text = render_markdown(summarize(_rows(), n_boot=50), gate, 4)
    assert "PASS: gt" in text and "PASS: same-hands" in text and "| strong |" in text
