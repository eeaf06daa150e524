"""How much of the finger pose do the wrist motion and the object's identity give away?

A leak indicator of a SynthGRAB dataset that needs no training (issue #16): every
right-hand contact frame of the scored split copies the finger pose of the training
frame whose wrist pose *relative to the object* is nearest, among training frames of the
same object family when the family was seen in training (its identity), else among all.
The key of a frame is the wrist position in the object's frame (divided by
``POSITION_SCALE``, 5 cm ~ 1) and the first two columns of the wrist rotation in the object
frame (6D, unitless); it is what a method sees without any object geometry (body motion
and the object's rigid motion).

Scores: MPJPE (mm) of the 20 finger keypoints (15 joints + 5 tips) in the wrist frame of a
unit-scale procedural right hand, for the copied pose (``nn``) and for the mean training
contact pose (``mean``, no information). ``ratio = nn / mean``: near 0, the wrist motion
nearly identifies the fingers (the data cannot test whether a method looks at the object);
near 1, the wrist tells little about the fingers. NaN when a split has no contact frames.

    python tools/synth_leak.py DATA [--split test] [--json]
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections import defaultdict
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

POSITION_SCALE = 0.05  # m; a wrist 5 cm away counts like a 1-unit rotation column change
FINGER_KEYPOINTS = slice(1, 21)  # the 15 finger joints and the 5 tips (wrist excluded)


def family_of(obj_name: str) -> str:
    """``mug_2`` -> ``mug`` (SynthGRAB instance names)."""
    return re.sub(r"_\d+$", "", obj_name)


def frame_keys(seq, side: str = "right") -> tuple[np.ndarray, np.ndarray]:
    """Keys (K, 9) and finger poses (K, 45) of the frames where ``side`` touches the object.

    Key: wrist position in the object frame / POSITION_SCALE (3) and the wrist rotation's
    first two columns in the object frame (6).
    """
    import torch

    from grip_bench.core.frames import object_pose
    from grip_bench.geometry.rotations import axis_angle_to_matrix

    hp = seq.hand_params(side)
    held = seq.contact_frames(side)
    if not held.any():
        return np.zeros((0, 9)), np.zeros((0, 45))
    R_o, t_o = object_pose(seq)  # world = R_o @ local + t_o
    R_w = axis_angle_to_matrix(torch.as_tensor(np.asarray(hp["global_orient"], float))).numpy()
    p = np.einsum("tji,tj->ti", R_o, np.asarray(hp["transl"], float) - t_o)  # R_o^T (w - t)
    R = np.einsum("tji,tjk->tik", R_o, R_w)  # R_o^T R_w
    keys = np.concatenate([p / POSITION_SCALE, R[:, :, 0], R[:, :, 1]], axis=1)
    return keys[held], np.asarray(hp["hand_pose"], float).reshape(-1, 45)[held]


def copy_nearest(train_keys: np.ndarray, train_poses: np.ndarray,
                 query_keys: np.ndarray) -> np.ndarray:
    """The pose (Q, 45) of each query's nearest training key (Euclidean; ties: lowest index)."""
    from scipy.spatial import cKDTree

    _, idx = cKDTree(train_keys).query(query_keys, k=1)
    return train_poses[idx]


def finger_mpjpe(pred: np.ndarray, true: np.ndarray, hand=None) -> np.ndarray:
    """Per-frame MPJPE (F,) in metres of the finger keypoints of two pose sets (F, 45),
    posed in the wrist frame of ``hand`` (default: the unit right procedural hand)."""
    import torch

    from grip_bench.bodies.hand import ProceduralHand

    hand = hand or ProceduralHand("right", 1.0).double()
    with torch.no_grad():
        _, jp = hand(None, torch.tensor(np.asarray(pred, float).reshape(-1, 45)), None)
        _, jt = hand(None, torch.tensor(np.asarray(true, float).reshape(-1, 45)), None)
    d = (jp - jt)[:, FINGER_KEYPOINTS].norm(dim=-1).mean(-1)
    return d.numpy()


def leak(data_dir: str | Path, split: str = "test") -> dict:
    """The leak indicator of ``data_dir``'s ``split`` against its ``train`` split (see the
    module docstring). Returns frames, MPJPEs (mm) and their ratio."""
    from grip_bench.data.grab_io import read_grab
    from grip_bench.data.splits import sequences_in_split

    train = defaultdict(lambda: ([], []))
    for path in sequences_in_split(data_dir, "train"):
        seq = read_grab(path)
        k, q = frame_keys(seq)
        train[family_of(seq.obj_name)][0].append(k)
        train[family_of(seq.obj_name)][1].append(q)
    fam_keys = {f: (np.concatenate(k), np.concatenate(q)) for f, (k, q) in train.items()}
    all_keys = np.concatenate([k for k, _ in fam_keys.values()])
    all_poses = np.concatenate([q for _, q in fam_keys.values()])
    mean_pose = all_poses.mean(0)
    nn_err, mean_err, seen = [], [], []
    for path in sequences_in_split(data_dir, split):
        seq = read_grab(path)
        k, q = frame_keys(seq)
        if not len(k):
            continue
        fam = family_of(seq.obj_name)
        keys, poses = fam_keys.get(fam, (all_keys, all_poses))
        seen.append(np.full(len(k), fam in fam_keys))
        nn_err.append(finger_mpjpe(copy_nearest(keys, poses, k), q))
        mean_err.append(finger_mpjpe(np.broadcast_to(mean_pose, q.shape), q))
    if not nn_err:
        return {"split": split, "frames": 0, "nn_mpjpe_mm": float("nan"),
                "mean_mpjpe_mm": float("nan"), "ratio": float("nan"), "seen_family_share": 0.0}
    nn_e, mean_e, seen_m = (np.concatenate(x) for x in (nn_err, mean_err, seen))
    out = {"split": split, "frames": int(len(nn_e)), "train_frames": int(len(all_keys)),
           "seen_family_share": round(float(seen_m.mean()), 3)}
    for tag, m in (("", np.ones_like(seen_m)), ("seen_", seen_m), ("unseen_", ~seen_m)):
        nn = 1000 * float(nn_e[m].mean()) if m.any() else float("nan")
        mean = 1000 * float(mean_e[m].mean()) if m.any() else float("nan")
        out |= {f"{tag}nn_mpjpe_mm": round(nn, 3), f"{tag}mean_mpjpe_mm": round(mean, 3),
                f"{tag}ratio": round(nn / mean, 4) if m.any() else float("nan")}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="a SynthGRAB (or GRAB-layout) folder with splits.json")
    ap.add_argument("--split", default="test", choices=("test", "val"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    from grip_bench.core.errors import GripBenchError

    try:
        res = leak(args.data, args.split)
    except GripBenchError as e:  # bad data: one line naming the file, as the CLI does
        print(f"error: {e.message}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        print(f"{args.data} ({args.split}, {res['frames']} right-hand contact frames, "
              f"{100 * res['seen_family_share']:.0f}% of a family seen in training): "
              f"nearest-wrist copy {res['nn_mpjpe_mm']} mm, mean pose "
              f"{res['mean_mpjpe_mm']} mm, ratio {res['ratio']} (seen families: ratio "
              f"{res.get('seen_ratio')}, unseen: {res.get('unseen_ratio')})")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
