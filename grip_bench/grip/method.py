"""GRIP and its ablation variants as registered methods (one config switch each).

Every variant is :class:`GripMethod` with different options. Variants whose training
switches agree (``train_key``) train identical networks and may share a checkpoint:
``grip``, ``grip-no-rnet`` and ``grip-future10`` all train ``Variant()`` and differ only
at prediction time (``grip-no-rnet`` skips RNet).

``predict`` reads from :class:`~grip_bench.bench.methods.PredictContext`:
``online`` (streaming), ``future_frames`` (must match the checkpoint), and in ``extra``:
``no_anet`` (use the input wrists), ``refine`` (Tab. 3: refine the given noisy hands
with ANet + RNet instead of generating hands; the runner sets it for perturbed sets) and
``precision`` ("fp32", the default, or "bf16": the networks' arithmetic).
"""

from __future__ import annotations

from pathlib import Path

from ..bench.methods import MethodSpec, register_method
from ..errors import InputError
from .pipeline import GripPipeline, Options, check_future
from .train import Variant, load_grip, train_grip


class GripMethod:
    """One GRIP variant: training switches (a :class:`Variant`) plus ``use_rnet``."""

    supports_online = True  # predict honours ctx.online (causal streaming pipeline)

    def __init__(self, name: str = "grip", *, ambient: str = "distance", proximity: bool = True,
                 consistency: str = "latent", future_frames: int = 10, use_rnet: bool = True):
        self.name = name
        self.variant = Variant(ambient=ambient, proximity=proximity, consistency=consistency,
                               future_frames=future_frames)
        self.use_rnet = use_rnet
        self.nets: dict | None = None
        self.meta: dict = {}

    def train_key(self) -> str:
        """Methods with equal keys train identical checkpoints."""
        return "grip:" + self.variant.train_key()

    def train(self, data_dir, out, *, profile: dict, seed: int | None = None, device: str = "cpu",
              progress: bool = True) -> Path:
        return train_grip(data_dir, out, profile=profile, variant=self.variant, seed=seed,
                          device=device, progress=progress)

    def load(self, checkpoint, device: str = "cpu") -> None:
        if checkpoint is None:
            raise InputError(f"method {self.name!r} needs a checkpoint (grip-bench train {self.name})",
                             "--checkpoint")
        nets, meta = load_grip(checkpoint, device)
        key = meta.get("train_key")
        if key != self.variant.train_key():
            raise InputError(f"checkpoint was trained for {key!r}, but {self.name} needs "
                             f"{self.variant.train_key()!r}", checkpoint)
        self.nets, self.meta = nets, meta

    def options(self, ctx) -> Options:
        extra = ctx.extra or {}
        check_future(self.variant, ctx.future_frames)
        return Options(variant=self.variant, use_anet=not extra.get("no_anet", False),
                       use_rnet=self.use_rnet, online=bool(ctx.online),
                       refine=bool(extra.get("refine", False)),
                       precision=extra.get("precision", "fp32"))

    def predict(self, seq, ctx):
        if self.nets is None:
            raise InputError(f"method {self.name!r} is not loaded (call load(checkpoint) first)", self.name)
        return GripPipeline(self.nets, self.options(ctx)).run(seq, ctx.library)


ALL_TABLES = ("table2_ablation", "table3_perturbation", "table4_grasp", "table4_future", "physics", "runtime")
NEEDS = ("object", "body")
VARIANTS = {
    "grip": ("GRIP: ANet + CNet (latent consistency) + RNet", {}, ALL_TABLES),
    "grip-no-ambient": ("GRIP without the ambient sensor", {"ambient": "none"}, ("table2_ablation",)),
    "grip-no-proximity": ("GRIP without the stage-one proximity sensor", {"proximity": False},
                          ("table2_ablation",)),
    "grip-voxel-ambient": ("GRIP with a voxel-occupancy ambient sensor", {"ambient": "voxel"},
                           ("table2_ablation",)),
    "grip-no-consist": ("GRIP without temporal consistency (one frame)", {"consistency": "none"},
                        ("table2_ablation",)),
    "grip-output-consist": ("GRIP with output-space instead of latent consistency",
                            {"consistency": "output"}, ("table2_ablation",)),
    "grip-no-rnet": ("GRIP without the refinement network (CNet's hands)", {"use_rnet": False},
                     ("table2_ablation", "table4_grasp", "physics", "runtime")),
    **{f"grip-future{n}": (f"GRIP with a {n}-frame future distance cue", {"future_frames": n},
                           ("table4_future",)) for n in (0, 3, 5)},
    # the default cue: identical to grip (Table 4-right's 10-frame row reads grip's results)
    "grip-future10": ("GRIP with a 10-frame future distance cue (= grip)", {"future_frames": 10},
                      ()),
}

for _name, (_desc, _opts, _tables) in VARIANTS.items():
    register_method(MethodSpec(name=_name, description=_desc, factory=GripMethod, needs=NEEDS,
                               tables=_tables, trainable=True, options=_opts,
                               variant_of=None if _name == "grip" else "grip"))
