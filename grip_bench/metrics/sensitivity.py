"""Geometry sensitivity: does a method's hand change between the two members of a
counterfactual pair (docs/counterfactual.md) the way the ground truth's does?

A pair (A, B) shares body, wrists and object motion; only the object's shape differs, so the
ground truth's change ``d_gt = hands_B - hands_A`` is the fingers' answer to the shape. A
method's change ``d_m = pred_B - pred_A`` is compared with it, per hand, on frames held in
both members (``contact.held_mask`` of each member's ground truth):

- :func:`change_reproduced`: ``1 - ||d_m - d_gt|| / ||d_gt||`` over all those frames and
  vertices (Frobenius norms), clipped to [0, 1]: the ground truth scores 1, a method that
  outputs the same hands for A and B scores 0 (``d_m = 0``), and so does one whose change is
  as wrong as no change at all (twice the change, or the opposite one);
- :func:`aperture_change_error`: mean over frames of ``|dap_m - dap_gt|``, ``dap = ap_B -
  ap_A``, the aperture (:func:`aperture`) being the mean distance from the thumb tip to the
  index and middle tips;
- :func:`pair_scores`: both, plus MPVPE on each member's own held frames.

Pure functions of arrays, metres; NaN (never 0) where a score cannot be computed.
"""

from __future__ import annotations

import numpy as np

from ..core.constants import CF_MIN_GT_RMS
from ..core.errors import InputError
from .pose import mpvpe

TIP_THUMB, TIP_INDEX, TIP_MIDDLE = 0, 1, 2  # rows of fingertips (layouts.TIP_NAMES order)


def aperture(tips: np.ndarray) -> np.ndarray:
    """Hand aperture (...) m from fingertips (..., 5, 3) in ``layouts.TIP_NAMES`` order
    (thumb, index, middle, ring, pinky): the mean of the thumb-index and thumb-middle tip
    distances."""
    tips = np.asarray(tips, dtype=np.float64)
    if tips.ndim < 2 or tips.shape[-2:] != (5, 3):
        raise InputError(f"fingertips should be (..., 5, 3), got {tips.shape}", "aperture")
    thumb = tips[..., TIP_THUMB, :]
    d_index = np.linalg.norm(tips[..., TIP_INDEX, :] - thumb, axis=-1)
    d_middle = np.linalg.norm(tips[..., TIP_MIDDLE, :] - thumb, axis=-1)
    return 0.5 * (d_index + d_middle)


def _same_shape(where: str, *arrays: np.ndarray) -> list[np.ndarray]:
    out = [np.asarray(a, dtype=np.float64) for a in arrays]
    if len({a.shape for a in out}) != 1:
        raise InputError(f"shapes differ: {[a.shape for a in out]}", where)
    return out


def change_reproduced(gt_a: np.ndarray, gt_b: np.ndarray, pred_a: np.ndarray,
                      pred_b: np.ndarray, min_rms: float = CF_MIN_GT_RMS) -> float:
    """Share of the ground truth's A -> B change a method reproduces, in [0, 1].

    All four (T, V, 3) m on the same frames (held in both members). ``1 - ||d_m - d_gt||_F /
    ||d_gt||_F``, clipped to [0, 1]. NaN with no frame or when the ground truth's change is
    below ``min_rms`` (RMS over frames and vertices): there is nothing to reproduce.
    """
    gt_a, gt_b, pred_a, pred_b = _same_shape("change_reproduced", gt_a, gt_b, pred_a, pred_b)
    if gt_a.size == 0:
        return float("nan")
    d_gt = (gt_b - gt_a).reshape(-1)
    d_m = (pred_b - pred_a).reshape(-1)
    norm = float(np.linalg.norm(d_gt))
    if not np.isfinite(norm) or norm <= min_rms * np.sqrt(d_gt.size / 3):
        return float("nan")
    return float(np.clip(1.0 - np.linalg.norm(d_m - d_gt) / norm, 0.0, 1.0))


def aperture_change_error(gt_tips_a: np.ndarray, gt_tips_b: np.ndarray,
                          pred_tips_a: np.ndarray, pred_tips_b: np.ndarray) -> np.ndarray:
    """Per-frame aperture-change error (T,) m: ``|(ap(pred_B) - ap(pred_A)) - (ap(gt_B) -
    ap(gt_A))|``; fingertips (T, 5, 3) m each, on the same frames."""
    arrays = _same_shape("aperture_change_error", gt_tips_a, gt_tips_b, pred_tips_a, pred_tips_b)
    ga, gb, pa, pb = (aperture(a) for a in arrays)
    return np.abs((pb - pa) - (gb - ga))


def pair_scores(gt_a: np.ndarray, gt_b: np.ndarray, pred_a: np.ndarray, pred_b: np.ndarray,
                tips: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                held_a: np.ndarray, held_b: np.ndarray) -> dict[str, float]:
    """Scores of one hand of one pair.

    gt_a, gt_b, pred_a, pred_b: vertices (T, V, 3) m (the two members have the same frames);
    tips: fingertips (T, 5, 3) m of (gt_a, gt_b, pred_a, pred_b); held_a, held_b (T,) bool:
    each member's held frames. Returns (m, or a share):

    - ``reproduced``: :func:`change_reproduced` on frames held in both;
    - ``aperture_error``: mean :func:`aperture_change_error` on those frames;
    - ``gt_aperture_change``: mean ``ap(gt_B) - ap(gt_A)`` there (signed);
    - ``mpvpe_a`` / ``mpvpe_b``: MPVPE on each member's own held frames; ``mpvpe``: their mean;
    - ``n_frames``: frames held in both.

    NaN for each value that has no frame.
    """
    gt_a, gt_b, pred_a, pred_b = _same_shape("pair_scores", gt_a, gt_b, pred_a, pred_b)
    if gt_a.ndim != 3 or gt_a.shape[-1] != 3:
        raise InputError(f"vertices should be (T, V, 3), got {gt_a.shape}", "pair_scores")
    T = len(gt_a)
    ha, hb = (np.asarray(h, dtype=bool).reshape(-1) for h in (held_a, held_b))
    if ha.shape != (T,) or hb.shape != (T,):
        raise InputError(f"held masks should be ({T},), got {ha.shape}, {hb.shape}",
                         "pair_scores")
    tips = _same_shape("pair_scores: tips", *tips)
    if tips[0].shape != (T, 5, 3):
        raise InputError(f"fingertips should be ({T}, 5, 3), got {tips[0].shape}",
                         "pair_scores")
    both = ha & hb
    nan = float("nan")
    out = {"n_frames": float(both.sum())}
    out["reproduced"] = change_reproduced(gt_a[both], gt_b[both], pred_a[both], pred_b[both])
    if both.any():
        err = aperture_change_error(*(t[both] for t in tips))
        out["aperture_error"] = float(err.mean())
        gt_change = aperture(tips[1][both]) - aperture(tips[0][both])
        out["gt_aperture_change"] = float(gt_change.mean())
    else:
        out["aperture_error"] = out["gt_aperture_change"] = nan
    out["mpvpe_a"] = float(mpvpe(pred_a[ha], gt_a[ha]).mean()) if ha.any() else nan
    out["mpvpe_b"] = float(mpvpe(pred_b[hb], gt_b[hb]).mean()) if hb.any() else nan
    out["mpvpe"] = float(np.mean([out["mpvpe_a"], out["mpvpe_b"]]))
    return out
