"""The pure computation behind the ``tip_dist`` metric (no registration here)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

# The 21 keypoints of a posed hand (grip_bench.metrics.pose): 0 wrist, 1..15 finger
# joints, 16..20 the fingertips (thumb, index, middle, ring, pinky).
TIP_IDS = np.arange(16, 21)


def fingertip_surface_distance(tips: np.ndarray,
                               signed_distance: Callable[[np.ndarray], np.ndarray]
                               ) -> np.ndarray:
    """Mean unsigned distance (T,) m of the fingertips to the object's surface.

    tips: (T, 5, 3) fingertip positions in the object's frame, metres;
    signed_distance: object-frame points (N, 3) -> signed distances (N,) m (negative
    inside; a tip inside the object counts by its depth).
    """
    tips = np.asarray(tips, dtype=np.float64)
    if tips.ndim != 3 or tips.shape[2] != 3:
        raise ValueError(f"tips should be (T, K, 3), got {tips.shape}")
    d = np.asarray(signed_distance(tips.reshape(-1, 3)), dtype=np.float64)
    return np.abs(d).reshape(tips.shape[:2]).mean(axis=1)
