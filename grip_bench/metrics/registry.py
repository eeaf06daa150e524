"""Metric registry: what each metric id means, its report unit and direction (DESIGN 5)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..registry import Registry


@dataclass(frozen=True)
class MetricSpec:
    """Static description of one metric; values are computed in SI and multiplied by ``scale``.

    ``frame_mask`` is ``"all"`` (every frame) or ``"grasp"`` (frames where the ground-truth hand
    is within ``constants.CONTACT_THRESHOLD`` of the object).
    """

    id: str
    name: str
    unit: str
    scale: float
    higher_is_better: bool
    frame_mask: Literal["all", "grasp"]
    version: int
    description: str

    def describe(self) -> str:
        """One line for ``grip-bench ls metrics``."""
        arrow = "higher" if self.higher_is_better else "lower"
        return (
            f"{self.id:<14} {self.unit:<5} {arrow:<6} frames={self.frame_mask:<5} "
            f"v{self.version}  {self.name}: {self.description}"
        )

    def to_report(self, value_si: float) -> float:
        """Convert an SI value (m, m^3, fraction, m/s^2) to the report unit."""
        return value_si * self.scale


METRICS: Registry[MetricSpec] = Registry("metric")

_SPECS = [
    MetricSpec("mpjpe", "MPJPE", "mm", 1e3, False, "all", 1,
               "mean error of the 15 finger joints (wrist and tips excluded), no alignment"),
    MetricSpec("mpvpe", "MPVPE", "mm", 1e3, False, "all", 1,
               "mean error of all hand mesh vertices, no alignment"),
    MetricSpec("cc", "Contact consistency", "mm", 1e3, False, "grasp", 1,
               "vertex error on hand vertices within 2 mm of the object in ground truth"),
    MetricSpec("contact_drift", "Contact drift", "mm", 1e3, False, "grasp", 1,
               "per-frame sliding of the method's contact points in the object's frame, "
               "beyond the ground truth's (GT vs itself = 0)"),
    MetricSpec("iv", "Intersection volume", "cm3", 1e6, False, "grasp", 1,
               "exact vol(hand & object) with manifold3d; NaN plus a count on failure"),
    MetricSpec("pen_depth", "Penetration depth", "mm", 1e3, False, "grasp", 1,
               "largest depth of a hand vertex inside the object (exact signed distance)"),
    MetricSpec("contact_ratio", "Contact ratio", "%", 1e2, True, "grasp", 1,
               "share of grasp frames where the hand is within 4.5 mm of the object or inside"),
    MetricSpec("sim_stable", "Physics stability", "%", 1e2, True, "grasp", 1,
               "MuJoCo, hand fixed, object free: share moving < 1 mm in 5 steps of 1/240 s "
               "(<= 12 evenly spaced grasp frames per sequence and hand)"),
    MetricSpec("sim_disp", "Simulated displacement", "mm", 1e3, False, "grasp", 1,
               "object displacement after the paper protocol (5 steps of 1/240 s; "
               "<= 12 grasp frames)"),
    MetricSpec("sim_disp_hold", "Simulated displacement (1 s hold)", "mm", 1e3, False, "grasp", 1,
               "object displacement after 1 s of simulated time (<= 12 grasp frames)"),
    MetricSpec("jitter", "Jitter", "m/s2", 1.0, False, "all", 1,
               "mean acceleration magnitude of hand vertices (second differences at 30 fps)"),
    MetricSpec("jitter_err", "Jitter error", "m/s2", 1.0, False, "all", 1,
               "absolute difference between the method's jitter and ground truth"),
]
for _spec in _SPECS:
    METRICS.register(_spec.id, _spec)
