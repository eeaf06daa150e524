"""Does ANet converge within its epoch budget? ANet alone, trained with a longer budget.

The default profile trains ANet (GRIP's arm-to-wrist network) for ``epochs_anet`` = 15
epochs, keeping the epoch of lowest validation loss and stopping after ``patience``
epochs without improvement (``grip.train.fit``). This probe trains ANet alone on a
dataset's train split (validation on its val split), with the profile's settings except
the epoch budget, and prints each epoch's losses and one JSON line: the epochs run, the
best epoch and loss, and the validation curve (x 1e-4). Its features go to ``--cache``
(built once a seed, ~5 minutes for the default data). A diagnostic for
docs/seeds_and_noise.md ("ANet at its epoch budget"): nothing here changes the suite.

    python tools/anet_convergence.py DATA --seed 0 [--epochs 60] [--profile default]
        [--cache DIR] [--out anet.pt]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np
import torch


def train_anet(data: Path, seed: int, epochs: int, profile: str, cache: Path) -> dict:
    """ANet of ``profile``'s settings, ``epochs`` at most; returns the curve and the net."""
    from grip_bench.data.grab_io import dataset_hash
    from grip_bench.grip import train as T
    from grip_bench.profiles import load_profile

    hp = dict(load_profile(profile)["grip"])
    hp["seed"] = seed
    variant = T.Variant()
    start = time.time()
    with T.deterministic():
        frames = T._features(data, cache, variant, seed, dataset_hash(data), False)
        nets = T._build_nets(T.build_configs(hp, variant), seed, {}, torch.device("cpu"))
        stage = T._anet_stage(nets["anet"], frames, hp, torch.device("cpu"))
        st = T.fit(stage, hp, T.StageState(), seed, epochs, lambda s: None, True)
    v = np.asarray(st.val_curve)
    return {"seed": seed, "profile_epochs": hp["epochs_anet"], "epochs_run": st.epoch,
            "best_epoch": int(v.argmin()) + 1, "best": float(v.min()),
            "val_x1e4": [round(float(x) * 1e4, 3) for x in v],
            "seconds": round(time.time() - start), "net": nets["anet"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="a GRAB-layout folder with splits.json")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--epochs", type=int, default=60, help="the epoch budget (default 60)")
    ap.add_argument("--profile", default="default", help="a built-in profile's name or a TOML path")
    ap.add_argument("--cache", type=Path, default=Path(".grip-cache"),
                    help="feature cache folder (default ./.grip-cache)")
    ap.add_argument("--out", type=Path, default=None, help="write ANet's weights here")
    args = ap.parse_args(argv)
    res = train_anet(args.data, args.seed, args.epochs, args.profile, args.cache)
    net = res.pop("net")
    if args.out is not None:
        torch.save(net.state_dict(), args.out)
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
