"""Reference rows: ground truth, the perturbed input, flat hands and the relaxed mean hand.

They bracket every table: ``gt`` is the metric sanity row (its pose errors are 0 by
construction), ``perturbed-input`` is the "before" of Table 3, ``flat-input`` is what
GRIP upgrades (the body motion with unarticulated hands) and ``mean-pose`` puts GRIP's
relaxed mean hand at the input wrists. None of them learns anything; ``train`` writes a
small checkpoint so that ``train``/``predict`` work the same for every method.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from grip_bench.core.checkpoint import load_checkpoint, save_checkpoint
from grip_bench.core.frames import SIDES
from grip_bench.methods.api import MethodSpec, PredictContext, TrainContext, register_method

from .common import resolve_device

if TYPE_CHECKING:
    from grip_bench.data.sequence import Sequence


class FixedMethod:
    """A method without weights whose hands are a function of the input sequence."""

    def __init__(self, name: str, finger_pose: str | None = None) -> None:
        self.name = name
        self.finger_pose = finger_pose  # None keeps the input's fingers; "flat" / "relaxed"

    def train(self, data_dir: Path, out: Path, ctx: TrainContext) -> Path:
        """Nothing to learn: record what the method is so ``load`` can check it."""
        resolve_device(ctx.device)  # an unavailable device fails here as for every method
        meta = {"method": self.name, "trained": False, "seed": ctx.seed}
        return save_checkpoint(out, model_state={}, configs={}, meta=meta)

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        resolve_device(device)
        if checkpoint is not None:
            load_checkpoint(checkpoint, {})

    def predict(self, seq: Sequence, ctx: PredictContext | None) -> Sequence:
        """The input sequence, with the finger poses replaced where the method says so."""
        if self.finger_pose is None:
            return seq.copy()
        return seq.with_hands(**{side: {"hand_pose": self._pose(seq, side)} for side in SIDES})

    def _pose(self, seq: Sequence, side: str) -> np.ndarray:
        """Finger pose (T, 45) of ``side`` for every frame."""
        from grip_bench.bodies.hand import ProceduralHand

        T = seq.n_frames
        if self.finger_pose == "flat":
            return np.zeros((T, 45))
        relaxed = ProceduralHand(side).named_pose("relaxed").double().numpy().reshape(45)
        return np.broadcast_to(relaxed, (T, 45)).copy()


# reference: a row that bounds the scale (ground truth, the unchanged input) is never marked
# best; flat-input and mean-pose are trivial controls: ranked like any method, never marked
# best, and a leaderboard column where one scores as well as the best method marks no best
for _name, _pose, _desc, _needs, _clean, _reference in (
    ("gt", None, "ground truth hands (metric sanity row)", (), True, True),
    ("perturbed-input", None, "the perturbed input hands unchanged (Table 3 'before')",
     ("noisy_hands",), False, True),  # on clean data it is gt again
    ("flat-input", "flat", "input wrists with flat fingers (what GRIP upgrades)", ("wrists",),
     True, False),
    ("mean-pose", "relaxed", "input wrists with GRIP's relaxed mean hand", ("wrists",), True,
     False),
):
    register_method(MethodSpec(
        name=_name, description=_desc, factory=FixedMethod, needs=_needs, trainable=False,
        options={"finger_pose": _pose}, clean=_clean, predict_cost=0.1, reference=_reference,
        control=_pose is not None,
    ))
