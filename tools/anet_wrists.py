"""How far off does GRIP's ANet put the wrists? Mean wrist-translation error per hand on a split.

ANet (GRIP's arm network) corrects the input body's arms, and GRIP's hands ride on the
corrected wrists (``grip.pipeline.GripPipeline.arms_and_wrists_many``: ANet's recursion,
then each wrist moved by its arm's rigid change). Every GRIP variant of a seed shares that
seed's ANet, so its wrist error moves every variant's hand errors together (docs/
seeds_and_noise.md, "ANet at its epoch budget"). This probe runs ANet alone on the
ground-truth sequences of a split and prints, per network, each hand's wrist-translation
error: ``|t_out - t_gt|`` per frame (m, the hand parameters' ``transl``), averaged over
frames, then over sequences, in mm. A network is a GRIP checkpoint (``model.ckpt`` of a
run's checkpoint unit, or ``grip-bench train``'s output) or, with ``--weights W@CKPT``,
ANet weights saved by ``tools/anet_convergence.py --out`` loaded into CKPT's ANet.
A diagnostic: nothing here changes the suite.

    python tools/anet_wrists.py DATA CKPT [CKPT ...] [--weights W.pt@CKPT ...] [--split test]
        [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np
import torch

SIDES = ("left", "right")


def wrist_errors(anet: torch.nn.Module, seqs: list) -> dict[str, float]:
    """Mean wrist-translation error (mm) per hand of ``anet``'s output on ``seqs``
    (ground-truth ``Sequence`` objects): per frame, then per sequence, then the mean."""
    from grip_bench.grip.pipeline import GripPipeline, Options
    from grip_bench.grip.train import Variant
    from grip_bench.sensors import wrist_frames

    # a fresh pipeline freezes ``anet`` as it is now (grip.frozen caches per network object)
    pipe = GripPipeline({"anet": anet}, Options(variant=Variant(), use_rnet=False))
    out = pipe.arms_and_wrists_many(seqs)
    res = {}
    for side in SIDES:
        per = [np.linalg.norm(w[side][1] - wrist_frames(seq, side)[1], axis=1).mean()
               for seq, (_, w) in zip(seqs, out, strict=True)]
        res[side] = float(np.mean(per)) * 1e3
    return res


def load_anet(checkpoint: Path, weights: Path | None = None) -> torch.nn.Module:
    """The ANet of a GRIP ``checkpoint``, with ``weights`` (a state dict) loaded when given:
    a new network object each call, so no frozen copy of another is reused."""
    from grip_bench.grip.train import load_grip

    anet = load_grip(checkpoint)[0]["anet"]
    if weights is not None:
        anet.load_state_dict(torch.load(weights, weights_only=True))
    return anet.eval()


def probe(data: Path, checkpoints: list[Path], weights: list[tuple[Path, Path]],
          split: str = "test") -> dict[str, dict[str, float]]:
    """``{label: {side: mm}}`` for each checkpoint's ANet and each (weights, checkpoint)."""
    from grip_bench.data.grab_io import read_grab
    from grip_bench.data.splits import sequences_in_split

    seqs = [read_grab(p) for p in sequences_in_split(data, split)]
    nets = [(str(c), load_anet(c)) for c in checkpoints]
    nets += [(f"{w}@{c}", load_anet(c, w)) for w, c in weights]
    return {label: wrist_errors(net, seqs) for label, net in nets}


def _weights(text: str) -> tuple[Path, Path]:
    w, sep, c = text.partition("@")
    if not sep or not w or not c:
        raise argparse.ArgumentTypeError(f"expected WEIGHTS@CHECKPOINT, got {text!r}")
    return Path(w), Path(c)


def main(argv: list[str] | None = None) -> int:
    from tools.probe_cli import run

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="a GRAB-layout folder with splits.json")
    ap.add_argument("checkpoints", type=Path, nargs="*", help="GRIP checkpoints")
    ap.add_argument("--weights", type=_weights, action="append", default=[],
                    metavar="W.pt@CKPT", help="ANet weights to load into CKPT's ANet")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if not args.checkpoints and not args.weights:
        ap.error("give at least one checkpoint or --weights")
    res = run(lambda: probe(args.data, args.checkpoints, args.weights, args.split))
    if res is None:
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    for label, r in res.items():
        print(f"{label}: left {r['left']:.2f} mm, right {r['right']:.2f} mm")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
