"""The blocked jitter helpers give the one-line forms' values bit for bit."""

import importlib

import numpy as np
import pytest

from grip_bench.core.vec import norm3
from grip_bench.metrics import evaluate as E

J = importlib.import_module("grip_bench.metrics.jitter")  # the package exports a function jitter


def _accel_reference(v, fps):
    v = np.asarray(v, dtype=np.float64)
    return (v[2:] - 2.0 * v[1:-1] + v[:-2]) * fps**2


@pytest.mark.parametrize("block", [1, 10, 1 << 16])
@pytest.mark.parametrize("shape", [(60, 778, 3), (3, 5, 3), (2, 4, 3), (0, 4, 3), (17, 1, 3),
                                   (40, 3), (9,)])
def test_acceleration_is_the_second_difference_bit_for_bit(monkeypatch, block, shape):
    monkeypatch.setattr(J, "_BLOCK_VALUES", block)
    v = np.random.default_rng(len(shape) + block).normal(size=shape) * 0.3
    for fps in (30.0, 30, 120.0, np.float64(29.97)):
        for x in (v, v.astype(np.float32)):
            ref, out = _accel_reference(x, fps), J.acceleration(x, fps)
            assert out.dtype == ref.dtype and out.shape == ref.shape
            assert out.tobytes() == ref.tobytes()


def test_constant_acceleration_is_recovered():
    t = np.arange(10)[:, None, None] / 30.0
    v = 0.5 * 2.0 * t**2 * np.ones((1, 4, 3))  # a = 2 m/s^2 on every axis
    np.testing.assert_allclose(J.acceleration(v), 2.0, rtol=1e-9)


@pytest.mark.parametrize("block", [1, 10, 1 << 16])
def test_acceleration_error_against_matches_the_whole_array_form(monkeypatch, block):
    monkeypatch.setattr(J, "_BLOCK_VALUES", block)
    rng = np.random.default_rng(block)
    for T, V in ((50, 778), (3, 2), (7, 1)):
        p = rng.normal(size=(T, V, 3))
        g = p + rng.normal(size=(T, V, 3)) * 1e-3
        ref = norm3(_accel_reference(p, 30.0) - _accel_reference(g, 30.0)).mean(axis=-1)
        out = J.acceleration_error_against(J.acceleration(p), g, 30.0)
        assert out.tobytes() == ref.tobytes()
        assert J.acceleration_error(p, g).tobytes() == ref.tobytes()
    assert J.acceleration_error(np.zeros((2, 3, 3)), np.zeros((2, 3, 3))).shape == (0,)


def test_blocked_vertex_error_is_norm3_of_the_difference(monkeypatch):
    monkeypatch.setattr(E, "_BLOCK_VALUES", 7)
    rng = np.random.default_rng(5)
    for T, V in ((30, 100), (1, 1), (0, 4)):
        p, g = rng.normal(size=(T, V, 3)), rng.normal(size=(T, V, 3))
        assert E._blocked_norm3_diff(p, g).tobytes() == norm3(p - g).tobytes()
