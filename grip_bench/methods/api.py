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
from typing import TYPE_CHECKING, Any, Protocol

from ..core.plugins import METHODS_GROUP, load_group
from ..core.plugins import plugin_modules as core_plugin_modules
from ..core.registry import Registry

if TYPE_CHECKING:
    from ..data.sequence import Sequence

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
    """What ``predict`` may use besides the input sequence (one typed field per fact)."""

    library: Any  # grip_bench.data.library.ObjectLibrary of the input's dataset
    device: str = "cpu"
    seed: int = 0
    future_frames: int | None = None  # override of the method's default, if it has one
    online: bool = False  # frame-by-frame streaming using only past frames
    refine: bool = False  # refine the given (perturbed) hands instead of generating (Table 3)
    use_anet: bool = True  # GRIP: denoise the arm motion (False: keep the input wrists)
    precision: str = "fp32"  # arithmetic of the networks where a method offers a choice
    data_dir: Path | None = None  # the clean dataset (retrieval methods read its train split)
    split: str = "test"  # the split being predicted
    perturbation: str = "none"  # the test set's perturbation label ("none": clean)
    # GrabNet-style: grasp frames to place grasps at, per side ((T,) bool); None: its own
    grasp_frames: dict[str, Any] | None = None


@dataclass
class TrainContext:
    """What ``train`` may use besides the data folder and the output path."""

    profile: dict  # the loaded profile (grip_bench.profiles.load_profile)
    seed: int = 0
    device: str = "cpu"
    progress: bool = True
    # a folder shared by the runs of one code version where a method may cache what does
    # not depend on its variant (GRIP's sensor features and ANet); None: beside ``out``
    feature_cache: Path | None = None


class Method(Protocol):
    """What every registered method object provides.

    Optional: ``train_key()`` (methods with equal keys train one shared checkpoint) and
    ``profile_sections`` (the profile sections ``train`` reads; ``grip-bench run`` keys
    the checkpoint by these alone and hands ``train`` only these, docs/architecture.md,
    "Cache keys"; absent: every section but ``[run]``).
    """

    name: str

    def train(self, data_dir: Path, out: Path, ctx: TrainContext) -> Path:
        """Train on ``data_dir``'s train split (validate on val); write a checkpoint to ``out``."""
        ...

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        """Load a checkpoint written by :meth:`train` (``None`` for methods without weights)
        and move the method's networks to ``device``."""
        ...

    def predict(self, seq: Sequence, ctx: PredictContext) -> Sequence:
        """The input :class:`~grip_bench.data.sequence.Sequence` with this method's hands."""
        ...


@dataclass(frozen=True)
class MethodSpec:
    """Every fact about a registered method, and how to build it.

    Which tables show a method is not stored here: the table files
    (``grip_bench/report/tables/*.toml``) are the one home of that fact.
    """

    name: str
    description: str
    factory: Any  # callable(name=..., **options) -> Method
    needs: tuple[str, ...] = ("object",)
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
    # whether ``predict`` honours ``ctx.online`` (causal frame-by-frame streaming)
    supports_online: bool = False
    # a reference row (ground truth, the perturbed input, flat hand, mean pose): shown for
    # comparison, never ranked as a method
    reference: bool = False
    # a trivial control (flat hand, mean pose at the input wrists): ranked like a method but
    # never marked best, and a leaderboard column where it scores as well as the best method
    # marks no best: that column cannot tell a method from a hand that does nothing
    control: bool = False
    # bump when the method's outputs change for the same code digest (part of cache keys)
    version: str = "1"

    def build(self) -> Method:
        return self.factory(name=self.name, **self.options)

    def describe(self, tables: tuple[str, ...] = ()) -> str:
        kind = "train" if self.trainable else "fixed"
        shown = ",".join(tables) or "-"
        needs = ",".join(self.needs)
        return f"{self.name:20s} {kind:5s} needs={needs:28s} tables={shown:30s} {self.description}"


METHODS: Registry[MethodSpec] = Registry("method")

# Modules whose import registers methods (added as the methods are implemented).
METHOD_MODULES: list[str] = [
    "grip_baselines.reference", "grip_bench.grip.method", "grip_baselines.grabnet_method",
    "grip_baselines.toch_method", "grip_baselines.manipnet_method", "grip_baselines.nearest",
    "grip_baselines.nearest_arm",
]


def register_method(spec: MethodSpec) -> MethodSpec:
    """Add ``spec`` to :data:`METHODS` (called at import by method modules)."""
    return METHODS.register(spec.name, spec)


# Third-party methods register through this entry-point group: in the plug-in's
# pyproject.toml, ``[project.entry-points."grip_bench.methods"] my-method = "my_pkg.my_module"``
# names a module whose import registers the method (docs/architecture.md, "How to add a
# method"; ``core.plugins`` finds the entry points of every group).
PLUGIN_GROUP = METHODS_GROUP


def plugin_modules() -> list[str]:
    """Modules named by installed ``grip_bench.methods`` entry points, sorted."""
    return core_plugin_modules(PLUGIN_GROUP)


def load_all() -> Registry[MethodSpec]:
    """Import every method module (ours, then installed plug-ins) so that :data:`METHODS`
    is complete. A plug-in that fails to import is an :class:`InputError` naming it."""
    for module in METHOD_MODULES:
        importlib.import_module(module)
    load_group(PLUGIN_GROUP)
    return METHODS


def variants() -> set[str]:
    """Names of the registered methods that are ablation variants of another."""
    return {name for name in load_all().names() if METHODS.get(name).variant_of}


def predicted_hands() -> dict[str, tuple[str, ...]]:
    """{method: hands it predicts} for every registered method (imports the method modules)."""
    return {name: METHODS.get(name).hands for name in load_all().names()}


def reference_rows() -> tuple[str, ...]:
    """Registered reference rows (``MethodSpec.reference``), in registration order."""
    return tuple(name for name in load_all().names() if METHODS.get(name).reference)


def control_rows() -> tuple[str, ...]:
    """Registered trivial controls (``MethodSpec.control``), in registration order."""
    return tuple(name for name in load_all().names() if METHODS.get(name).control)
