"""Pose metrics: per-frame MPJPE and MPVPE, global (no alignment), per hand.

Definitions: docs/contract.md, "Definitions".
"""

from __future__ import annotations

import numpy as np

from ..core.vec import norm3

# 21 MANO keypoints: 0 wrist, 1..15 finger joints, 16..20 fingertips. MPJPE uses 1..15 only.
FINGER_JOINTS = slice(1, 16)


def _check_pair(pred: np.ndarray, gt: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    from ..core.errors import InputError

    pred, gt = np.asarray(pred, dtype=np.float64), np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape or pred.ndim != 3 or pred.shape[-1] != 3:
        raise InputError(
            f"expected matching (T, N, 3) arrays, got {pred.shape} and {gt.shape}", name
        )
    return pred, gt


def mean_point_error(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-frame mean Euclidean distance between corresponding points.

    pred, gt: (T, N, 3) metres -> (T,) metres.
    """
    pred, gt = _check_pair(pred, gt, "points")
    return norm3(pred - gt).mean(axis=-1)


def mpjpe(pred_joints: np.ndarray, gt_joints: np.ndarray) -> np.ndarray:
    """Per-frame MPJPE over the 15 finger joints (wrist and fingertips excluded, as GRIP).

    pred_joints, gt_joints: (T, 21, 3) metres -> (T,) metres.
    """
    from ..core.errors import InputError

    pred, gt = _check_pair(pred_joints, gt_joints, "joints")
    if pred.shape[1] != 21:
        raise InputError(f"expected 21 keypoints, got {pred.shape[1]}", "joints")
    return mean_point_error(pred[:, FINGER_JOINTS], gt[:, FINGER_JOINTS])


def mpvpe(pred_vertices: np.ndarray, gt_vertices: np.ndarray) -> np.ndarray:
    """Per-frame MPVPE over all hand vertices.

    pred_vertices, gt_vertices: (T, V, 3) metres -> (T,) metres.
    """
    return mean_point_error(pred_vertices, gt_vertices)
