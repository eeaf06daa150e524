"""Evaluation metrics: pure functions on batched arrays and meshes.

Definitions: docs/contract.md, "Definitions".

Units in, units out: metres, m^3, fractions, m/s^2; ``registry.METRICS`` holds the report
unit and scale of each metric id. Heavy dependencies (mujoco, coacd, manifold3d, libigl)
are imported inside the functions that need them.
"""

from .contact import (
    contact_consistency,
    contact_deviation,
    contact_drift,
    contact_frequency,
    contact_ratio,
    grasp_mask,
    held_mask,
    in_contact,
    object_lift,
)
from .intersection import (
    FailureCounter,
    cap_boundary_loops,
    intersection_volume,
    intersection_volume_batch,
    is_closed_manifold,
)
from .jitter import acceleration_error, jitter, jitter_error
from .penetration import exact_signed_distance, penetration_depth, penetration_depth_from_sdf
from .physics import (
    StabilityResult,
    convex_decomposition,
    hand_convex_pieces,
    stability,
    stability_sequence,
)
from .pose import mpjpe, mpvpe
from .registry import METRICS, MetricSpec

__all__ = [
    "METRICS",
    "FailureCounter",
    "MetricSpec",
    "StabilityResult",
    "acceleration_error",
    "cap_boundary_loops",
    "contact_consistency",
    "contact_deviation",
    "contact_drift",
    "contact_frequency",
    "contact_ratio",
    "convex_decomposition",
    "exact_signed_distance",
    "grasp_mask",
    "hand_convex_pieces",
    "held_mask",
    "in_contact",
    "intersection_volume",
    "intersection_volume_batch",
    "is_closed_manifold",
    "jitter",
    "jitter_error",
    "mpjpe",
    "mpvpe",
    "object_lift",
    "penetration_depth",
    "penetration_depth_from_sdf",
    "stability",
    "stability_sequence",
]
