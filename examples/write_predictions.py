"""Write predictions made by another codebase so that ``grip-bench evaluate`` scores them.

docs/predictions.md explains every rule; in short: one ``.npz`` per ground-truth sequence,
at the same relative path, holding the ground-truth file's header, body, object and table
with this method's hands (``global_orient (T,3)``, ``hand_pose (T,45)`` full axis-angle,
``transl (T,3)`` = the wrist's world position, metres, 30 fps), plus a ``manifest.json``.

Usage as a script (demonstration: the ground truth's own hands, i.e. the ``gt`` row)::

    python examples/write_predictions.py GT_DIR OUT_DIR [--method NAME] [--split test]
    grip-bench evaluate --pred OUT_DIR --gt GT_DIR --out EVAL
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from grip_bench.core.io import atomic_write_text
from grip_bench.data.grab_io import read_grab, write_grab
from grip_bench.data.splits import sequences_in_split

HAND_KEYS = ("global_orient", "hand_pose", "transl")


def write_prediction(gt_file: Path, gt_dir: Path, out_dir: Path,
                     hands: Mapping[str, Mapping[str, np.ndarray]]) -> Path:
    """Write one prediction: ``gt_file``'s sequence with ``hands`` replaced.

    hands: ``{"right": {...}, "left": {...}}`` (either side may be omitted: it is then
    the ground truth's, and a method predicting one hand should leave the other out of the
    tables); each side any of ``global_orient (T,3)`` rad axis-angle, ``hand_pose
    (T,45)`` rad full axis-angle (no PCA), ``transl (T,3)`` m, the wrist's world position.
    Returns the written path, ``out_dir / <gt_file relative to gt_dir>``.
    """
    gt = read_grab(gt_file)
    sides = {}
    for side, params in hands.items():
        unknown = set(params) - set(HAND_KEYS)
        if unknown:
            raise ValueError(f"{side}: unknown hand keys {sorted(unknown)}")
        sides[side] = {k: np.asarray(v, dtype=np.float64) for k, v in params.items()}
    pred = gt.with_hands(**sides)  # checks shapes; keeps body, object, table, header
    return write_grab(pred, out_dir / gt_file.relative_to(gt_dir))


def write_manifest(out_dir: Path, method: str, perturbation: str = "none") -> Path:
    """``OUT/manifest.json``: what made the predictions (``perturbation``: the input's label,
    "none" for clean inputs)."""
    manifest = {"generator": "examples/write_predictions.py", "method": method,
                "perturbation": perturbation}
    path = Path(out_dir) / "manifest.json"
    atomic_write_text(path, json.dumps(manifest, indent=2) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("gt", type=Path, help="ground-truth data folder (GRAB layout)")
    p.add_argument("out", type=Path, help="prediction folder to write")
    p.add_argument("--method", default="my-method")
    p.add_argument("--split", default="test")
    args = p.parse_args(argv)
    for gt_file in sequences_in_split(args.gt, args.split):
        seq = read_grab(gt_file)
        # your model here: arrays (T, 3), (T, 45), (T, 3) per hand
        hands = {side: {k: seq.hand_params(side)[k] for k in HAND_KEYS}
                 for side in ("right", "left")}
        write_prediction(gt_file, args.gt, args.out, hands)
    write_manifest(args.out, args.method)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
