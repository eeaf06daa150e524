"""Contact metrics on precomputed hand-to-object distances (docs/contract.md, "Definitions").

Distances are signed (negative inside the object) and computed by the caller with a
distance field; every function here is pure numpy. "In contact" means
``signed_dist <= threshold``, so a vertex inside the object counts as in contact.
"""

from __future__ import annotations

import numpy as np

from ..core import constants as C
from ..core.vec import norm3


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


# Finger of each skinning bone (MANO joint order: wrist, index 1-3, middle 4-6, pinky 7-9,
# ring 10-12, thumb 13-15): -1 palm, 0 thumb, 1 index, 2 middle, 3 ring, 4 pinky.
BONE_FINGER = np.array([-1, 1, 1, 1, 2, 2, 2, 4, 4, 4, 3, 3, 3, 0, 0, 0])


def finger_ids(bone_ids: np.ndarray) -> np.ndarray:
    """Finger code of each vertex (V,) from its skinning bone (V,) (see ``BONE_FINGER``)."""
    return BONE_FINGER[np.asarray(bone_ids, dtype=np.int64)]


def object_lift(local_vertices: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                up: np.ndarray) -> np.ndarray:
    """Height of the object's lowest point above its height at frame 0, per frame (T,) m.

    local_vertices (N, 3) in the object's frame (its hull's vertices suffice); rotations
    (T, 3, 3) and translations (T, 3) with world = local @ R_t + t_t (GRAB's convention);
    up (3,). GRAB sequences start with the object resting on the table, so frame 0 is the
    resting height.
    """
    u = np.asarray(up, dtype=np.float64)
    heights = np.einsum("nj,tjk,k->tn", np.asarray(local_vertices, np.float64),
                        np.asarray(rotations, np.float64), u)
    low = heights.min(axis=1) + np.asarray(translations, np.float64) @ u
    return low - low[0] if len(low) else low


def trim_runs(mask: np.ndarray, trim: int) -> np.ndarray:
    """``mask`` (T,) bool with ``trim`` frames removed at each end of every run of True."""
    m = np.asarray(mask, dtype=bool)
    out = np.zeros_like(m)
    edges = np.flatnonzero(np.diff(np.r_[0, m.astype(np.int8), 0]))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if stop - start > 2 * trim:
            out[start + trim:stop - trim] = True
    return out


def held_mask(gt_signed_dist: np.ndarray, finger: np.ndarray, lift: np.ndarray,
              touch: float = C.HELD_TOUCH, min_lift: float = C.HELD_MIN_LIFT,
              trim: int = C.HELD_TRIM) -> np.ndarray:
    """Held frames (T,) bool: the object is lifted and the ground truth grips it.

    A frame is held when the object's lowest point is at least ``min_lift`` above its
    resting height (``lift`` (T,) m, from :func:`object_lift`) and the ground-truth thumb and
    at least one other finger have a vertex within ``touch`` (inside counts); each run of
    such frames then loses ``trim`` frames at each end (a grasp being formed or released).
    gt_signed_dist (T, V) m; finger (V,) codes from :func:`finger_ids`.
    """
    near = in_contact(gt_signed_dist, touch)
    finger = np.asarray(finger)
    grip = near[:, finger == 0].any(axis=-1) & near[:, finger > 0].any(axis=-1)
    return trim_runs(grip & (np.asarray(lift) >= min_lift), trim)


def strict_contact(pred_signed_dist: np.ndarray, finger: np.ndarray,
                   touch: float = C.HELD_TOUCH) -> np.ndarray:
    """Frames (T,) bool where the thumb and at least one other finger are within ``touch``
    (inside counts): the strict contact ratio's per-frame test. pred_signed_dist (T, V) m."""
    near = in_contact(pred_signed_dist, touch)
    finger = np.asarray(finger)
    return near[:, finger == 0].any(axis=-1) & near[:, finger > 0].any(axis=-1)


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
    err = norm3(np.asarray(pred_vertices) - np.asarray(gt_vertices))
    return contact_consistency_from_error(err, gt_signed_dist, threshold)


def contact_consistency_from_error(
    err: np.ndarray, gt_signed_dist: np.ndarray, threshold: float = C.CC_THRESHOLD
) -> np.ndarray:
    """:func:`contact_consistency` from the per-vertex errors ``|p - g|`` (T, V) m (the
    evaluation computes them once for MPVPE and CC) -> (T,) m."""
    sel = in_contact(gt_signed_dist, threshold)
    n = sel.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(sel, err, 0.0).sum(axis=-1) / n
    return np.where(n > 0, out, np.nan)


def contact_drift(
    pred_local: np.ndarray,
    gt_local: np.ndarray,
    gt_signed_dist: np.ndarray,
    mask: np.ndarray,
    threshold: float = C.CC_THRESHOLD,
) -> np.ndarray:
    """Per-frame drift of the ground truth's contact vertices relative to the object
    (ARCTIC's motion deviation, MDev, on contact vertices).

    For frames t-1, t that are both masked, take the vertices the *ground truth* has within
    ``threshold`` in both frames (the same vertices for every method, so a method that never
    touches is measured too) and average ``|(p_t - p_{t-1}) - (g_t - g_{t-1})|``, with p, g
    the predicted and ground-truth vertex positions in the object's own frame: how much
    more (or differently) the method's contact region moves over the object than the ground
    truth's does. Ground truth against itself is exactly 0, a rigid offset of the hand in the
    object frame is 0, a hand sliding by s per frame over a still ground truth scores s.

    pred_local, gt_local: (T, V, 3) m in the object frame; gt_signed_dist: (T, V) m;
    mask: (T,) bool -> (T,) m; frame 0 and frames without such vertices are NaN.
    """
    p = np.asarray(pred_local, dtype=np.float64)
    g = np.asarray(gt_local, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    out = np.full(p.shape[0], np.nan)
    if p.shape[0] < 2:
        return out
    touch = in_contact(gt_signed_dist, threshold)
    sel = touch[1:] & touch[:-1] & (mask[1:] & mask[:-1])[:, None]  # (T-1, V)
    # Deviations of the selected (frame, vertex) entries only (a few % of them); the rows are
    # then summed over all V with zeros elsewhere, as np.where(sel, dev, 0).sum(-1) does, so
    # the summation order and the values stay those of the dense form bit for bit.
    t, v = np.nonzero(sel)
    dev = np.zeros(sel.shape)
    dev[t, v] = norm3((p[t + 1, v] - p[t, v]) - (g[t + 1, v] - g[t, v]))
    n = sel.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        per = dev.sum(axis=-1) / n
    out[1:] = np.where(n > 0, per, np.nan)
    return out


def contact_deviation(
    pred_signed_dist: np.ndarray, gt_signed_dist: np.ndarray,
    threshold: float = C.CC_THRESHOLD,
) -> np.ndarray:
    """Per-frame contact deviation (ARCTIC's CDev): the mean distance to the object's surface
    of the predicted vertices whose ground-truth counterparts are within ``threshold``.

    pred_signed_dist, gt_signed_dist: (T, V) m -> (T,) m (absolute distances: a vertex
    inside the object deviates as much as one outside); NaN where the ground truth has no
    such vertex.
    """
    sel = in_contact(gt_signed_dist, threshold)
    n = sel.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(sel, np.abs(pred_signed_dist), 0.0).sum(axis=-1) / n
    return np.where(n > 0, out, np.nan)


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
