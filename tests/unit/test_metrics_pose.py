"""MPJPE / MPVPE: analytic offset, loop reference, hand-worked values."""

import numpy as np
import pytest

from grip_bench.core.errors import InputError
from grip_bench.metrics import mpjpe, mpvpe


def test_mpjpe_known_offset_ignores_wrist_and_tips():
    rng = np.random.default_rng(0)
    gt = rng.normal(size=(4, 21, 3))
    pred = gt + np.array([0.003, 0.004, 0.0])  # 5 mm everywhere
    pred[:, 0] += 1.0  # wrist and fingertips are excluded, so these must not count
    pred[:, 16:] -= 1.0
    np.testing.assert_allclose(mpjpe(pred, gt), 0.005, rtol=1e-12)


def test_mpvpe_matches_python_loop():
    rng = np.random.default_rng(1)
    pred, gt = rng.normal(size=(2, 5, 40, 3))
    ref = [
        sum(np.sqrt(sum((p[i] - g[i]) ** 2)) for i in range(len(p))) / len(p)
        for p, g in zip(pred, gt, strict=True)
    ]
    np.testing.assert_allclose(mpvpe(pred, gt), ref, rtol=1e-12)


def test_mpvpe_tiny_hand_worked():
    gt = np.zeros((1, 2, 3))
    pred = np.array([[[0.0, 0.0, 0.002], [0.0, 0.006, 0.008]]])  # errors 2 mm and 10 mm
    assert mpvpe(pred, gt)[0] == pytest.approx(0.006)


def test_shape_mismatch_is_input_error():
    with pytest.raises(InputError):
        mpvpe(np.zeros((2, 5, 3)), np.zeros((2, 6, 3)))
    with pytest.raises(InputError):
        mpjpe(np.zeros((2, 16, 3)), np.zeros((2, 16, 3)))
