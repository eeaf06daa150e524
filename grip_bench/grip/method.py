"""GRIP and its ablation variants as registered methods (one config switch each).

Every variant is :class:`GripMethod` with different options. Variants whose training
switches agree (``train_key``) train identical networks and may share a checkpoint:
``grip``, ``grip-no-rnet`` and ``grip-future10`` all train ``Variant()`` and differ only
at prediction time (``grip-no-rnet`` skips RNet).
``grip-blind`` is a probe of the data rather than an ablation: it sees the body's and the
object's rigid motion but no object geometry (``Variant(geometry=False)``).

``predict`` reads from :class:`~grip_bench.methods.api.PredictContext`:
``online`` (streaming), ``future_frames`` (must match the checkpoint), ``use_anet``
(False: use the input wrists), ``refine`` (Tab. 3: refine the given noisy hands with
ANet + RNet instead of generating hands; the runner sets it for perturbed sets) and
``precision`` ("fp32", the default, or "bf16": the networks' arithmetic).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import InputError
from ..methods.api import MethodSpec, PredictContext, TrainContext, register_method
from .pipeline import GripPipeline, Options, check_future
from .train import Variant, load_grip, train_grip

if TYPE_CHECKING:
    from ..data.sequence import Sequence


class GripMethod:
    """One GRIP variant: training switches (a :class:`Variant`) plus ``use_rnet``."""

    profile_sections = ("grip",)  # what training reads; a checkpoint keys only these

    def __init__(self, name: str = "grip", *, ambient: str = "distance", proximity: bool = True,
                 consistency: str = "latent", future_frames: int = 10, use_rnet: bool = True,
                 geometry: bool = True):
        self.name = name
        self.variant = Variant(ambient=ambient, proximity=proximity, consistency=consistency,
                               future_frames=future_frames, geometry=geometry)
        if use_rnet and not geometry:
            raise InputError("a variant without geometry cannot use RNet (it reads proximity)",
                             name)
        self.use_rnet = use_rnet
        self.nets: dict | None = None
        self.meta: dict = {}

    def train_key(self) -> str:
        """Methods with equal keys train identical checkpoints."""
        return "grip:" + self.variant.train_key()

    def train(self, data_dir: Path, out: Path, ctx: TrainContext) -> Path:
        return train_grip(data_dir, out, profile=ctx.profile, variant=self.variant, seed=ctx.seed,
                          device=ctx.device, progress=ctx.progress,
                          feature_cache=ctx.feature_cache)

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        if checkpoint is None:
            raise InputError(
                f"method {self.name!r} needs a checkpoint (grip-bench train {self.name})",
                "--checkpoint",
            )
        nets, meta = load_grip(checkpoint, device)
        key = meta.get("train_key")
        if key != self.variant.train_key():
            raise InputError(f"checkpoint was trained for {key!r}, but {self.name} needs "
                             f"{self.variant.train_key()!r}", checkpoint)
        self.nets, self.meta = nets, meta

    def options(self, ctx: PredictContext) -> Options:
        check_future(self.variant, ctx.future_frames)
        return Options(variant=self.variant, use_anet=ctx.use_anet, use_rnet=self.use_rnet,
                       online=bool(ctx.online), refine=ctx.refine, precision=ctx.precision)

    def predict(self, seq: Sequence, ctx: PredictContext) -> Sequence:
        if self.nets is None:
            raise InputError(
                f"method {self.name!r} is not loaded (call load(checkpoint) first)", self.name
            )
        return GripPipeline(self.nets, self.options(ctx)).run(seq, ctx.library)


NEEDS = ("object", "body")
VARIANTS = {
    "grip": ("GRIP: ANet + CNet (latent consistency) + RNet", {}),
    "grip-no-ambient": ("GRIP without the ambient sensor", {"ambient": "none"}),
    "grip-no-proximity": ("GRIP without the stage-one proximity sensor", {"proximity": False}),
    "grip-voxel-ambient": ("GRIP with a voxel-occupancy ambient sensor", {"ambient": "voxel"}),
    "grip-no-consist": ("GRIP without temporal consistency (one frame)",
                        {"consistency": "none"}),
    "grip-output-consist": ("GRIP with output-space instead of latent consistency",
                            {"consistency": "output"}),
    "grip-no-rnet": ("GRIP without the refinement network (CNet's hands)", {"use_rnet": False}),
    **{f"grip-future{n}": (f"GRIP with a {n}-frame future distance cue", {"future_frames": n})
       for n in (0, 3, 5)},
    # the default cue: identical to grip (Table 4-right's 10-frame row reads grip's results)
    "grip-future10": ("GRIP with a 10-frame future distance cue (= grip)", {"future_frames": 10}),
    # a probe of the data (a reference row of Table 2, never marked best there): body motion
    # and the object's rigid motion only; no Ambient, no Proximity, no future cue, no RNet
    "grip-blind": ("GRIP blind to object geometry: body and object-pose motion only (probe)",
                   {"geometry": False, "ambient": "none", "proximity": False,
                    "future_frames": 0, "use_rnet": False}),
}

for _name, (_desc, _opts) in VARIANTS.items():
    register_method(MethodSpec(name=_name, description=_desc, factory=GripMethod, needs=NEEDS,
                               trainable=True, options=_opts, supports_online=True,
                               variant_of=None if _name == "grip" else "grip"))
