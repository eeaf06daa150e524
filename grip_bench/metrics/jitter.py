"""Jitter: mean acceleration magnitude of hand vertices by second finite differences."""

from __future__ import annotations

import numpy as np

from ..core import constants as C
from ..core.vec import norm3


def acceleration(vertices: np.ndarray, fps: float = C.FPS) -> np.ndarray:
    """Central second differences of positions.

    vertices: (T, V, 3) metres -> (T-2, V, 3) m/s^2.
    """
    v = np.asarray(vertices, dtype=np.float64)
    return (v[2:] - 2.0 * v[1:-1] + v[:-2]) * fps**2


def acceleration_magnitudes(vertices: np.ndarray, fps: float = C.FPS) -> np.ndarray:
    """Acceleration magnitude of every vertex: (T, V, 3) m -> (T-2, V) m/s^2 (frames 1..T-2;
    empty when T < 3). Computed once per hand by the jitter metric, which reads both its
    per-frame means and its overall mean from it."""
    if np.shape(vertices)[0] < 3:
        return np.zeros((0, *np.shape(vertices)[1:-1]))
    return norm3(acceleration(vertices, fps))


def jitter(vertices: np.ndarray, fps: float = C.FPS) -> float:
    """Mean acceleration magnitude over frames and vertices of one sequence.

    vertices: (T, V, 3) metres -> m/s^2; NaN when T < 3 (no second difference exists).
    """
    if np.shape(vertices)[0] < 3:
        return float("nan")
    return float(acceleration_magnitudes(vertices, fps).mean())


def jitter_error(pred_vertices: np.ndarray, gt_vertices: np.ndarray, fps: float = C.FPS) -> float:
    """Absolute difference between the prediction's jitter and the ground truth's, m/s^2."""
    return abs(jitter(pred_vertices, fps) - jitter(gt_vertices, fps))


def acceleration_error(pred_vertices: np.ndarray, gt_vertices: np.ndarray,
                       fps: float = C.FPS) -> np.ndarray:
    """Per-frame acceleration error as ARCTIC defines it: the mean over vertices of
    ``|a_pred - a_gt|`` (not the difference of mean magnitudes, which is 0 for a wrong motion
    of the same energy).

    pred_vertices, gt_vertices: (T, V, 3) m in one frame (the world: a hand's absolute
    motion is what jitters) -> (T-2,) m/s^2 for frames 1..T-2; empty when T < 3.
    """
    if np.shape(pred_vertices)[0] < 3:
        return np.zeros(0)
    return acceleration_error_of(acceleration(pred_vertices, fps), acceleration(gt_vertices, fps))


def acceleration_error_of(pred_accel: np.ndarray, gt_accel: np.ndarray) -> np.ndarray:
    """:func:`acceleration_error` from the two accelerations (T-2, V, 3) m/s^2 (the
    evaluation computes the prediction's once for jitter and this) -> (T-2,) m/s^2."""
    return norm3(pred_accel - gt_accel).mean(axis=-1)
