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
    if v.ndim < 2 or len(v) < 3:
        return (v[2:] - 2.0 * v[1:-1] + v[:-2]) * fps**2
    # ((v[t+1] - 2 v[t]) + v[t-1]) * fps^2, the operations of the one-line form above in its
    # order (bit for bit the same values), a block of frames at a time into the output: the
    # one-line form passes four fresh (T-2, V, 3) temporaries through memory.
    out = np.empty((len(v) - 2, *v.shape[1:]))
    step = _block_frames(v)
    for s in range(0, len(out), step):
        e = min(len(out), s + step)
        _accel_block(v, s, e, fps, out[s:e])
    return out


def _block_frames(v: np.ndarray) -> int:
    """Frames per block of the blocked loops here (``_BLOCK_VALUES`` values of a frame)."""
    return max(1, _BLOCK_VALUES // max(1, v[0].size))


def _accel_block(v: np.ndarray, s: int, e: int, fps: float, out: np.ndarray) -> np.ndarray:
    """``acceleration(v)[s:e]`` written into ``out`` (e - s, ...): the one-line form's
    operations in its order, per element."""
    o = np.multiply(v[s + 1 : e + 1], 2.0, out=out)
    np.subtract(v[s + 2 : e + 2], o, out=o)
    o += v[s:e]
    o *= fps**2
    return o


# Values per block of ``acceleration`` (512 KB of float64): a block's operands stay in cache.
_BLOCK_VALUES = 1 << 16


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
    return acceleration_error_against(acceleration(pred_vertices, fps), gt_vertices, fps)


def acceleration_error_of(pred_accel: np.ndarray, gt_accel: np.ndarray) -> np.ndarray:
    """:func:`acceleration_error` from the two accelerations (T-2, V, 3) m/s^2 (the
    evaluation computes the prediction's once for jitter and this) -> (T-2,) m/s^2."""
    return norm3(pred_accel - gt_accel).mean(axis=-1)


def acceleration_error_against(pred_accel: np.ndarray, gt_vertices: np.ndarray,
                               fps: float = C.FPS) -> np.ndarray:
    """``acceleration_error_of(pred_accel, acceleration(gt_vertices, fps))`` (T-2,) m/s^2, bit
    for bit, a block of frames at a time: the ground truth's acceleration and the difference
    are block-sized temporaries (each value and each frame's mean over vertices, a
    reduction within one frame's row, are computed exactly as in the whole-array form).

    pred_accel: (T-2, V, 3) m/s^2; gt_vertices: (T, V, 3) m.
    """
    g = np.asarray(gt_vertices, dtype=np.float64)
    a = np.asarray(pred_accel)
    if g.ndim != 3 or len(g) < 3 or a.shape != (len(g) - 2, *g.shape[1:]) or a.dtype != g.dtype:
        return acceleration_error_of(a, acceleration(g, fps))
    out = np.empty(len(a))
    step = _block_frames(g)
    buf = np.empty((min(step, len(a)), *g.shape[1:]))
    for s in range(0, len(a), step):
        e = min(len(a), s + step)
        d = _accel_block(g, s, e, fps, buf[: e - s])
        np.subtract(a[s:e], d, out=d)
        out[s:e] = norm3(d).mean(axis=-1)
    return out
