"""Contact metrics on precomputed hand-to-object distances (docs/contract.md, "Definitions").

Distances are signed (negative inside the object) and computed by the caller with a
distance field; every function here is pure numpy. "In contact" means
``signed_dist <= threshold``, so a vertex inside the object counts as in contact.
"""

from __future__ import annotations

import numpy as np

from ..core import constants as C


def in_contact(signed_dist: np.ndarray, threshold: float = C.CONTACT_THRESHOLD) -> np.ndarray:
    """Per-vertex contact flags: within ``threshold`` of the surface or inside.

    signed_dist: (T, V) metres -> (T, V) bool.
    """
    return np.asarray(signed_dist) <= threshold


def grasp_mask(gt_signed_dist: np.ndarray, threshold: float = C.CONTACT_THRESHOLD) -> np.ndarray:
    """Grasp frames: the ground-truth hand is within ``threshold`` of the object (or inside).

    gt_signed_dist: (T, V) metres -> (T,) bool.
    """
    return in_contact(gt_signed_dist, threshold).any(axis=-1)


def contact_ratio(
    pred_signed_dist: np.ndarray, mask: np.ndarray, threshold: float = C.CONTACT_THRESHOLD
) -> float:
    """Share of masked (grasp) frames where the predicted hand touches or enters the object.

    pred_signed_dist: (T, V) metres; mask: (T,) bool -> fraction in [0, 1], NaN without grasp
    frames.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return float("nan")
    return float(grasp_mask(pred_signed_dist, threshold)[mask].mean())


def contact_consistency(
    pred_vertices: np.ndarray,
    gt_vertices: np.ndarray,
    gt_signed_dist: np.ndarray,
    threshold: float = C.CC_THRESHOLD,
) -> np.ndarray:
    """Per-frame vertex error on the vertices the ground truth has in contact (GRIP's CC).

    pred_vertices, gt_vertices: (T, V, 3) m; gt_signed_dist: (T, V) m -> (T,) m.
    Frames with no ground-truth contact vertex are NaN (not 0: nothing was measured there).
    """
    err = np.linalg.norm(np.asarray(pred_vertices) - np.asarray(gt_vertices), axis=-1)
    sel = in_contact(gt_signed_dist, threshold)
    n = sel.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(sel, err, 0.0).sum(axis=-1) / n
    return np.where(n > 0, out, np.nan)


def contact_drift(
    pred_signed_dist: np.ndarray,
    closest_obj_points_local: np.ndarray,
    mask: np.ndarray,
    threshold: float = C.CONTACT_THRESHOLD,
) -> np.ndarray:
    """Per-frame sliding of the predicted contacts over the object surface.

    For frames t-1, t that are both grasp frames, take the hand vertices the *prediction* has
    in contact in both (the metric measures the method's own sliding, so its own distances
    decide contact) and average how far their closest object points moved, expressed in the
    object's own frame. A rigidly held grasp scores 0 whatever the object does in the world.

    pred_signed_dist: (T, V) m; closest_obj_points_local: (T, V, 3) m in the object frame;
    mask: (T,) bool -> (T,) m; frame 0 and frames without such vertices are NaN.
    """
    d = np.asarray(pred_signed_dist)
    c = np.asarray(closest_obj_points_local, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    out = np.full(d.shape[0], np.nan)
    if d.shape[0] < 2:
        return out
    touch = in_contact(d, threshold)
    sel = touch[1:] & touch[:-1] & (mask[1:] & mask[:-1])[:, None]  # (T-1, V)
    move = np.linalg.norm(c[1:] - c[:-1], axis=-1)
    n = sel.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        per = np.where(sel, move, 0.0).sum(axis=-1) / n
    out[1:] = np.where(n > 0, per, np.nan)
    return out


def contact_frequency(
    signed_dist: np.ndarray, mask: np.ndarray, threshold: float = C.CONTACT_THRESHOLD
) -> np.ndarray:
    """Per-vertex share of grasp frames in contact, for contact heatmaps.

    signed_dist: (T, V) m; mask: (T,) bool -> (V,) in [0, 1]; all NaN without grasp frames.
    """
    mask = np.asarray(mask, dtype=bool)
    d = np.asarray(signed_dist)
    if not mask.any():
        return np.full(d.shape[-1], np.nan)
    return in_contact(d[mask], threshold).mean(axis=0)
