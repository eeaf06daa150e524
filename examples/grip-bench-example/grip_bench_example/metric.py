"""``tip_dist``: how far the predicted fingertips are from the object while it is held.

Registered with grip-bench's own decorator (``grip_bench.metrics.registry.metric``) when the
registry imports this module through the ``grip_bench.metrics`` entry point. Per held
frame of the ground truth (``frame_mask = "held"``), the mean over the five predicted
fingertips of their exact unsigned distance to the object's surface, in the object's
frame; reported in mm, lower is better. Ground truth scores near 0 where its fingertips
touch; a hand that hovers or sinks in scores more.
"""

from __future__ import annotations

import numpy as np

from grip_bench.core.frames import world_to_object
from grip_bench.metrics.evaluate import Measured, SequencePair
from grip_bench.metrics.registry import metric

from .tips import TIP_IDS, fingertip_surface_distance


@metric("tip_dist", "Fingertip-surface distance", "mm", 1e3, False, "held", 1,
        "mean |distance| of the five predicted fingertips to the object's surface on held "
        "frames (example plug-in)")
def m_tip_dist(pair: SequencePair, side: str) -> Measured:
    """Per held frame (K,) the fingertips' mean distance to the surface, metres."""
    idx = np.flatnonzero(pair.held(side))
    joints = pair.track("pred", side).joints[idx]  # (K, 21, 3) world, m
    rot = pair.pred.object_rotations()[idx]  # the prediction's own object trajectory
    tips = world_to_object(joints[:, TIP_IDS], rot, pair.pred.object["transl"][idx])  # (K,5,3)
    values = fingertip_surface_distance(tips, pair.field.exact_signed_distance)
    return Measured(idx, values)
