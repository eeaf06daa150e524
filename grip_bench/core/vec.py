"""Small vector helpers on numpy arrays that must give numpy's own values bit for bit."""

from __future__ import annotations

import numpy as np


def norm3(x: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis of 3-vectors: ``(..., 3) -> (...)``.

    Bit for bit ``np.linalg.norm(x, axis=-1)`` (same dtype: float32 stays float32, integers
    become float64): numpy sums the three squares in order, ``(x0^2 + x1^2) + x2^2``, and so
    does this, column by column, about 3-4x faster on hand-sized arrays (T, 778, 3) because
    it avoids the strided reduction over an axis of length 3 (tests/unit/test_vec.py).
    """
    x = np.asarray(x)
    if x.dtype.kind != "f":
        x = x.astype(np.float64)
    if x.shape[-1:] != (3,):
        raise ValueError(f"norm3 needs (..., 3) vectors, got shape {x.shape}")
    total = x[..., 0] * x[..., 0]
    total += x[..., 1] * x[..., 1]
    total += x[..., 2] * x[..., 2]
    return np.sqrt(total)
