"""GRIP's training throughput per network at a profile's widths, on a CPU or a GPU.

    python tools/train_throughput.py --data DATA --profile paper --device cuda --out t.json

For each network (ANet, CNet, RNet) it builds the training problem exactly as
``grip-bench train grip`` does (the same features, batches, losses, Adam, deterministic
algorithms), then times ``--steps`` training batches after ``--warmup`` untimed ones:
the batch's build on the CPU and its move to the device (``fetch``), and the forward,
backward and optimiser step (``step``, synchronised on a GPU). It reports frames per
second, the parameters and the peak GPU memory, and what one epoch over ``--epoch-frames``
frames would take at that rate (GRIP's paper trains on GRAB's train split: give its frame
count there). The training itself is not changed or run to the end: this measures the
loop, not the model's quality. Batches repeat when a split is smaller than the steps.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np
import torch

from grip_bench.data.grab_io import dataset_hash
from grip_bench.data.library import ObjectLibrary
from grip_bench.grip import train as T
from grip_bench.nn import ddp
from grip_bench.profiles import load_profile


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def time_stage(stage: T.Stage, bs: int, steps: int, warmup: int, lr: float) -> dict:
    """Seconds spent fetching and stepping ``steps`` batches of ``bs`` (after ``warmup``)."""
    dev = stage.device
    opt = torch.optim.Adam(stage.model.parameters(), lr=lr, foreach=True)
    stage.model.train()
    order = np.random.default_rng(0).permutation(stage.n_train)
    starts = [s for s in range(0, stage.n_train, bs) if stage.n_train - s >= bs] or [0]
    fetch_s = step_s = 0.0
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(dev)
    for k in range(warmup + steps):
        s = starts[k % len(starts)]
        t0 = time.perf_counter()
        batch = stage.fetch("train", order[s:s + bs])
        _sync(dev)
        t1 = time.perf_counter()
        loss, _ = stage.loss(stage.model, batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        _sync(dev)
        t2 = time.perf_counter()
        if k >= warmup:
            fetch_s, step_s = fetch_s + t1 - t0, step_s + t2 - t1
    frames = steps * min(bs, stage.n_train)
    out = {"batch": min(bs, stage.n_train), "steps": steps, "fetch_ms": 1e3 * fetch_s / steps,
           "step_ms": 1e3 * step_s / steps, "frames_per_s": frames / (fetch_s + step_s),
           "step_frames_per_s": frames / step_s,
           "params": sum(p.numel() for p in stage.model.parameters()),
           "train_frames": stage.n_train}
    if dev.type == "cuda":
        out["peak_gpu_mib"] = torch.cuda.max_memory_allocated(dev) / 2**20
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="a SynthGRAB or GRAB data folder")
    p.add_argument("--profile", default="paper", help="smoke, default, paper or a .toml file")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    p.add_argument("--steps", type=int, default=50, help="timed batches per network")
    p.add_argument("--warmup", type=int, default=5, help="untimed batches first")
    p.add_argument("--stages", default="anet,cnet,rnet", help="networks to time")
    p.add_argument("--epoch-frames", type=int, default=0,
                   help="frames of one epoch for the time estimate (0: the data's train split)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--cache", type=Path, default=None, help="feature cache (default: temporary)")
    p.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    dev = ddp.resolve_device(a.device)
    T._cuda_determinism(dev)
    profile = load_profile(a.profile)
    hp = dict(profile["grip"])
    variant = T.Variant()
    result = {"profile": profile["name"], "device": str(dev), "torch": torch.__version__,
              "python": platform.python_version(), "threads": torch.get_num_threads(),
              "cpu": platform.processor() or platform.machine(), "stages": {}}
    if dev.type == "cuda":
        result["gpu"] = torch.cuda.get_device_name(dev)
    with tempfile.TemporaryDirectory() as tmp, T.deterministic():
        cache = a.cache or Path(tmp)
        t0 = time.perf_counter()
        data = T._features(a.data, cache, variant, hp["seed"], dataset_hash(a.data), False)
        result["features_s"] = time.perf_counter() - t0
        nets = T._build_nets(T.build_configs(hp, variant), hp["seed"], {}, dev)
        library = ObjectLibrary(a.data)
        for name in a.stages.split(","):
            t0 = time.perf_counter()
            stage = T._make_stage(name, nets, data, hp, variant, library, dev)
            built = time.perf_counter() - t0
            r = time_stage(stage, hp["batch_size"], a.steps, a.warmup, hp["lr"])
            r["build_s"] = built
            n = a.epoch_frames or r["train_frames"]
            r["epoch_s_estimate"] = n / r["frames_per_s"]
            r["epochs_in_profile"] = hp[f"epochs_{name}"]
            result["stages"][name] = r
            print(f"{name}: {r['frames_per_s']:,.0f} frames/s (step {r['step_ms']:.2f} ms, "
                  f"fetch {r['fetch_ms']:.2f} ms per batch of {r['batch']}), "
                  f"{r['params'] / 1e6:.1f} M parameters"
                  + (f", peak {r['peak_gpu_mib']:.0f} MiB" if "peak_gpu_mib" in r else ""),
                  flush=True)
    if a.out:
        a.out.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
