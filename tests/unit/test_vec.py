"""core.vec.norm3 against numpy's own norm (the reference it must equal bit for bit)."""

import numpy as np
import pytest

from grip_bench.core.vec import norm3


@pytest.mark.parametrize("shape", [(300, 778, 3), (5, 3), (3,), (0, 3), (4, 5, 6, 3)])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_norm3_equals_numpy_bit_for_bit(shape: tuple, dtype: type) -> None:
    rng = np.random.default_rng(len(shape))
    for scale in (1e-6, 1.0, 1e6):
        x = (rng.normal(size=shape) * scale).astype(dtype)
        ref = np.linalg.norm(x, axis=-1)
        got = norm3(x)
        assert got.dtype == ref.dtype and got.shape == ref.shape
        np.testing.assert_array_equal(got, ref)


def test_norm3_on_strided_and_integer_input() -> None:
    x = np.random.default_rng(1).normal(size=(40, 30, 3)).transpose(1, 0, 2)  # not contiguous
    np.testing.assert_array_equal(norm3(x), np.linalg.norm(x, axis=-1))
    ints = np.array([[3, 4, 12], [0, 0, 0]])
    np.testing.assert_array_equal(norm3(ints), [13.0, 0.0])
    assert norm3(ints).dtype == np.float64


def test_norm3_analytic_and_shape_check() -> None:
    assert norm3(np.array([1.0, 2.0, 2.0])) == 3.0
    with pytest.raises(ValueError, match="3"):
        norm3(np.zeros((4, 2)))
