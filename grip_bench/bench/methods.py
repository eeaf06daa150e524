"""One interface for GRIP, its variants, the baselines and the reference rows.

A method is registered by name with a :class:`MethodSpec` (what it is, what it needs,
which tables it appears in) and a factory building a :class:`Method` object. Every
method trains the same way (``train(data_dir, out, ...)`` writes one checkpoint file)
and predicts the same way (``predict(seq, ctx)`` returns the sequence with the
method's hands), so ``grip-bench train/predict/run`` treat them alike.

Method modules register themselves at import; :data:`METHOD_MODULES` lists them so the
registry can be filled lazily (``grip-bench ls methods`` imports nothing optional).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from ..registry import Registry

# What a method may need at prediction time (documented in ``ls methods``).
NEEDS = {
    "object": "the object mesh and its pose per frame",
    "body": "the body motion (arms, wrists)",
    "wrists": "ground-truth wrist poses",
    "noisy_hands": "perturbed input hands to refine",
    "train_data": "the training split (retrieval)",
}


@dataclass
class PredictContext:
    """What ``predict`` may use besides the input sequence."""

    library: Any  # grip_bench.data.library.ObjectLibrary of the input's dataset
    device: str = "cpu"
    seed: int = 0
    future_frames: int | None = None  # override of the method's default, if it has one
    online: bool = False  # frame-by-frame streaming using only past frames
    extra: dict = field(default_factory=dict)


class Method(Protocol):
    """What every registered method object provides."""

    name: str

    def train(self, data_dir: Path, out: Path, *, profile: dict, seed: int = 0,
              device: str = "cpu", progress: bool = True) -> Path:
        """Train on ``data_dir``'s train split (validate on val) and write a checkpoint to ``out``."""
        ...

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        """Load a checkpoint written by :meth:`train` (``None`` for methods without weights)."""
        ...

    def predict(self, seq, ctx: PredictContext):
        """The input :class:`~grip_bench.data.sequence.Sequence` with this method's hands."""
        ...


@dataclass(frozen=True)
class MethodSpec:
    """A registered method: name, one-line description, needs, tables, and how to build it."""

    name: str
    description: str
    factory: Any  # callable(**options) -> Method
    needs: tuple[str, ...] = ("object",)
    tables: tuple[str, ...] = ()
    trainable: bool = True
    options: dict = field(default_factory=dict)  # passed to the factory (variant switches)
    # hands the method predicts; any other hand is returned as given (the input), so the
    # leaderboard leaves its columns empty rather than credit the method with the input
    hands: tuple[str, ...] = ("right", "left")
    # whether it runs on the clean test split (the leaderboard); perturbed-input does not:
    # on clean data it is the ground truth again
    clean: bool = True
    # the method this one is an ablation of ("grip" for GRIP's variants): a variant is
    # compared in its tables (on their metrics), not on the leaderboard
    variant_of: str | None = None
    # rough prediction time per sequence relative to GRIP (1.0); `run` starts the slowest
    # prediction units first so that no long unit is left alone at the end of the stage
    predict_cost: float = 1.0

    def build(self) -> Method:
        return self.factory(name=self.name, **self.options)

    def describe(self) -> str:
        kind = "train" if self.trainable else "fixed"
        tables = ",".join(self.tables) or "-"
        needs = ",".join(self.needs)
        return f"{self.name:20s} {kind:5s} needs={needs:28s} tables={tables:30s} {self.description}"


METHODS: Registry[MethodSpec] = Registry("method")

# Modules whose import registers methods (added as the methods are implemented).
METHOD_MODULES: list[str] = [
    "grip_baselines.reference", "grip_bench.grip.method", "grip_baselines.grabnet_method",
    "grip_baselines.toch_method", "grip_baselines.manipnet_method", "grip_baselines.nearest",
]


def register_method(spec: MethodSpec) -> MethodSpec:
    """Add ``spec`` to :data:`METHODS` (called at import by method modules)."""
    return METHODS.register(spec.name, spec)


def load_all() -> Registry[MethodSpec]:
    """Import every method module so that :data:`METHODS` is complete."""
    for module in METHOD_MODULES:
        importlib.import_module(module)
    return METHODS


def variants() -> set[str]:
    """Names of the registered methods that are ablation variants of another."""
    return {name for name in load_all().names() if METHODS.get(name).variant_of}


def predicted_hands() -> dict[str, tuple[str, ...]]:
    """{method: hands it predicts} for every registered method (imports the method modules)."""
    return {name: METHODS.get(name).hands for name in load_all().names()}
