"""``wrist-follow``: the input wrists, with finger poses learned from the training split.

Training reads every sequence of the train split and averages each hand's finger pose
(axis-angle, (45,)) over two kinds of frames: *near* (the wrist within ``NEAR`` of the
object's surface: reaching and grasping) and *far* (the wrist beyond ``FAR``: the free
hand). Prediction keeps the input hands' wrist trajectory (``global_orient``, ``transl``:
the wrist position, docs/contract.md) and blends the two means by the wrist's distance to
the object, linearly between ``NEAR`` and ``FAR``. It trains in well under a second on a
small dataset and needs only the object and the wrists.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from grip_bench.core.checkpoint import load_checkpoint, save_checkpoint
from grip_bench.core.errors import InputError
from grip_bench.core.frames import SIDES
from grip_bench.methods.api import MethodSpec, PredictContext, TrainContext, register_method

if TYPE_CHECKING:
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.data.sequence import Sequence

NEAR = 0.05  # m: wrist-to-surface distance at and below which the grasping mean applies
FAR = 0.15  # m: distance at and beyond which the free-hand mean applies


def wrist_distance(seq: Sequence, side: str, library: ObjectLibrary) -> np.ndarray:
    """Distance (T,) m of ``side``'s wrist (its ``transl``) to the object's surface."""
    wrist = np.asarray(seq.hand_params(side)["transl"], dtype=np.float64)[:, None]  # (T, 1, 3)
    local = library.world_to_object(seq, wrist)[:, 0]  # (T, 3), the object's frame
    field = library.field(seq.obj_name)
    return np.abs(np.asarray(field.signed_distance(local, far="exact"), dtype=np.float64))


def near_weight(distance: np.ndarray) -> np.ndarray:
    """Weight (T,) in [0, 1] of the grasping mean: 1 at <= NEAR, 0 at >= FAR, linear between."""
    return np.clip((FAR - distance) / (FAR - NEAR), 0.0, 1.0)


def fit_means(poses: list[np.ndarray], weights: list[np.ndarray]) -> dict[str, list[float]]:
    """Weighted means (45,) of finger poses (T, 45): ``near`` weighted by ``w``, ``far`` by
    ``1 - w``; an empty side of the split falls back to the plain mean."""
    pose = np.concatenate(poses).reshape(-1, 45)
    w = np.concatenate(weights)[:, None]
    plain = pose.mean(axis=0)
    near = (w * pose).sum(0) / w.sum() if w.sum() > 0 else plain
    far = ((1 - w) * pose).sum(0) / (1 - w).sum() if (1 - w).sum() > 0 else plain
    return {"near": near.tolist(), "far": far.tolist()}


class WristFollow:
    """The method object (``grip_bench.methods.api.Method``)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.means: dict[str, dict[str, np.ndarray]] | None = None

    def train(self, data_dir: Path, out: Path, ctx: TrainContext) -> Path:
        """Average the train split's finger poses near and far from the object."""
        from grip_bench.data.grab_io import read_grab
        from grip_bench.data.library import ObjectLibrary
        from grip_bench.data.splits import sequences_in_split

        if ctx.device != "cpu":
            raise InputError("wrist-follow runs on the CPU only", "--device")
        paths = sequences_in_split(data_dir, "train")
        if not paths:
            raise InputError("the train split has no sequences", data_dir)
        library = ObjectLibrary(data_dir)
        poses: dict[str, list[np.ndarray]] = {s: [] for s in SIDES}
        weights: dict[str, list[np.ndarray]] = {s: [] for s in SIDES}
        for path in paths:
            seq = read_grab(path)
            for side in SIDES:
                poses[side].append(np.asarray(seq.hand_params(side)["hand_pose"]).reshape(-1, 45))
                weights[side].append(near_weight(wrist_distance(seq, side, library)))
        means = {side: fit_means(poses[side], weights[side]) for side in SIDES}
        meta = {"method": self.name, "means": means, "n_sequences": len(paths)}
        return save_checkpoint(out, model_state={}, configs={}, meta=meta)

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        if checkpoint is None:
            raise InputError("wrist-follow needs a checkpoint (grip-bench train)", "--checkpoint")
        meta = load_checkpoint(checkpoint, {}).meta
        if meta.get("method") != self.name:
            raise InputError(f"checkpoint of {meta.get('method')!r}, not {self.name!r}",
                             checkpoint)
        self.means = {side: {k: np.asarray(v, dtype=np.float64) for k, v in m.items()}
                      for side, m in meta["means"].items()}

    def predict(self, seq: Sequence, ctx: PredictContext) -> Sequence:
        """The input's wrists; fingers blended between the learned near and far means."""
        if self.means is None:
            raise InputError("load a checkpoint before predicting", self.name)
        hands = {}
        for side in SIDES:
            w = near_weight(wrist_distance(seq, side, ctx.library))[:, None]  # (T, 1)
            m = self.means[side]
            hands[side] = {"hand_pose": w * m["near"] + (1 - w) * m["far"]}  # (T, 45) rad
        return seq.with_hands(**hands)


register_method(MethodSpec(
    name="wrist-follow",
    description="input wrists, finger pose blended between learned near/far means (plug-in)",
    factory=WristFollow, needs=("object", "wrists"), trainable=True, predict_cost=0.1,
))
