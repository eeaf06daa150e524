"""Metric registry: each metric id with its meaning, report unit, direction, frame mask,
version and the function that computes it (docs/contract.md, "Definitions").

Metrics register where they are computed (``metrics.evaluate``, with :func:`metric`), as
torchmetrics and lm-evaluation-harness do: a spec and its code cannot drift apart. This
module imports ``evaluate`` at its end, then the modules of installed plug-ins (entry-point
group ``grip_bench.metrics``, ``core.plugins``), which register theirs with the same
decorator, so ``METRICS`` is complete once it is imported, in every process (a worker
imports this module too). A plug-in that fails is an ``InputError`` naming it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from ..core.registry import Registry


@dataclass(frozen=True)
class MetricSpec:
    """Static description of one metric; values are computed in SI and multiplied by ``scale``.

    ``frame_mask`` is ``"all"`` (every frame) or ``"held"`` (the ground truth holds the object
    lifted: ``metrics.contact.held_mask``).
    """

    id: str
    name: str
    unit: str
    scale: float
    higher_is_better: bool
    frame_mask: Literal["all", "held"]
    version: int
    description: str
    # (pair: metrics.evaluate.SequencePair, side) -> metrics.evaluate.Measured, SI units
    compute: Callable[[Any, str], Any] | None = None
    # False: a table's sensitivity column (e.g. the hold check at other frictions), kept off
    # the leaderboard, which shows each quantity once
    leaderboard: bool = True

    def describe(self) -> str:
        """One line for ``grip-bench ls metrics``."""
        arrow = "higher" if self.higher_is_better else "lower"
        return (
            f"{self.id:<20} {self.unit:<5} {arrow:<6} frames={self.frame_mask:<4} "
            f"v{self.version}  {self.name}: {self.description}"
        )

    def to_report(self, value_si: float) -> float:
        """Convert an SI value (m, m^3, fraction, m/s^2) to the report unit."""
        return value_si * self.scale


METRICS: Registry[MetricSpec] = Registry("metric")


def metric(id: str, name: str, unit: str, scale: float, higher_is_better: bool,
           frame_mask: Literal["all", "held"], version: int, description: str,
           leaderboard: bool = True
           ) -> Callable[[Callable[[Any, str], Any]], Callable[[Any, str], Any]]:
    """Decorator registering the per-hand compute function of metric ``id`` (in definition
    order, which is the order of tables and leaderboards; ``leaderboard`` False: tables
    only)."""

    def register(fn: Callable[[Any, str], Any]) -> Callable[[Any, str], Any]:
        METRICS.register(id, MetricSpec(id, name, unit, scale, higher_is_better, frame_mask,
                                        version, description, compute=fn,
                                        leaderboard=leaderboard))
        return fn

    return register


from . import evaluate as _evaluate  # noqa: E402, F401  (registers every metric)


def plugin_modules() -> list[str]:
    """Modules named by installed ``grip_bench.metrics`` entry points, sorted (their code is
    in the metric units' keys: ``bench.plan.stage_code``)."""
    from ..core.plugins import METRICS_GROUP
    from ..core.plugins import plugin_modules as modules

    return modules(METRICS_GROUP)


def _load_plugins() -> None:
    from ..core.plugins import METRICS_GROUP, load_group

    load_group(METRICS_GROUP)


_load_plugins()  # after the suite's own metrics: plug-ins come last in tables and results
