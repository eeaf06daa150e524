"""``grip-bench train``: train a registered method and write its checkpoint."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

DESCRIPTION = """\
Train METHOD on DATA's train split (early stopping on its val split) and write one
checkpoint file to --out. Hyper-parameters come from --profile (smoke: seconds, for
tests; default: the benchmark's; paper: GRIP's network sizes). An interrupted GRIP
training resumes from <out>.partial when re-run with the same arguments. --device cuda
trains on the GPU (every method; deterministic per machine, not bit-equal to the CPU;
checkpoints hold CPU tensors). --nproc N trains with PyTorch DDP on N local processes
(gloo on the CPU, nccl with one GPU per process under --device cuda; batch_size stays the
global batch; see docs/distributed_training.md); under torchrun each process is one rank."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train a method and write its checkpoint",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example:\n  grip-bench train grip --data synth/ --out ckpt/grip.pt --profile smoke",
    )
    p.add_argument("method", help="method name (see `grip-bench ls methods`)")
    p.add_argument(
        "--data", type=Path, required=True, metavar="DIR", help="GRAB-layout data folder"
    )
    p.add_argument(
        "--out", type=Path, required=True, metavar="CKPT", help="checkpoint file to write"
    )
    p.add_argument("--profile", default="default", help="smoke, default, paper or a .toml file")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda"), help="device (default cpu)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--nproc", type=int, default=1, metavar="N",
                   help="train with PyTorch DDP on N local processes (default 1; "
                   "docs/distributed_training.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bench.stages.train import train_checkpoint
    from ..core.errors import InputError
    from ..methods.api import TrainContext, load_all
    from ..profiles import load_profile

    load_all().get(args.method)  # InputError listing the known methods
    profile = load_profile(args.profile)
    if not (args.data / "grab").is_dir():
        raise InputError("not a GRAB-layout data folder (no grab/ inside)", args.data)
    if args.out.is_dir():
        raise InputError("is a folder; --out names the checkpoint file to write", args.out)
    t0 = time.perf_counter()
    # the runner's training stage calls the same function: same seed, same bytes
    ctx = TrainContext(profile=profile, seed=args.seed, device=args.device,
                       progress=not args.no_progress)
    out = train_checkpoint(args.method, args.data, args.out, ctx, args.nproc)
    if int(os.environ.get("RANK", "0") or 0) == 0:  # one line from a torchrun job
        print(f"wrote {out} ({time.perf_counter() - t0:.1f} s)")
    return 0
