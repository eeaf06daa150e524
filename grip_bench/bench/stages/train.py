"""Stage unit ``checkpoint``: one method trained on the dataset's train split.

``grip-bench train`` calls :func:`train_checkpoint` too, so both entry points run the same
code on the same floating-point path (one torch thread) and write the same bytes.

``nproc > 1`` (``--nproc``, the profile's ``[run] train_nproc``) trains with PyTorch DDP on
that many local processes (:func:`grip_bench.nn.ddp.spawn`, a free localhost port; gloo
on the CPU, nccl with one GPU per rank for ``--device cuda``;
docs/distributed_training.md); under an external ``torchrun`` the process joins its job.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from ...core.threads import single_thread
from ...methods.api import METHODS, TrainContext
from ...nn import ddp

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit


def train_checkpoint(
    name: str, data_dir: Path, out: Path, ctx: TrainContext, nproc: int = 1
) -> Path:
    """Train registered method ``name`` on ``data_dir`` and write its checkpoint ``out``.

    One torch thread: the same floating-point path in a worker process, in-process and in
    ``grip-bench train``, so the same seed gives the same bytes. ``nproc > 1``: a DDP job of
    that many processes (rank 0 writes ``out``); inside a torchrun job (``WORLD_SIZE`` set)
    this process is one of its ranks and ``nproc`` is not used.
    """
    ddp.check_nproc(nproc)
    if nproc > 1 and ddp.env_world() <= 1:
        METHODS.get(name)  # an unknown name fails here, not in N processes
        ddp.check_gpus(nproc, ctx.device)  # so do a missing CUDA and too few GPUs
        ddp.spawn(_rank_main, nproc, (name, str(data_dir), str(out), ctx))
        return Path(out)
    method = METHODS.get(name).build()
    with single_thread(), ddp.process_group(ctx.device):
        return Path(method.train(Path(data_dir), Path(out), ctx))


def _rank_main(name: str, data_dir: str, out: str, ctx: TrainContext) -> None:
    """One rank of :func:`train_checkpoint`'s DDP job (a fresh spawned process)."""
    from ...methods.api import load_all

    load_all()  # the registry of the parent, rebuilt in this process
    train_checkpoint(name, Path(data_dir), Path(out), ctx)


def train_method(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Train one method on the dataset's train split; the checkpoint is the unit.

    Training writes into ``cache/work/<key>/`` (outside the atomic temp folder) so that a
    method that checkpoints its progress (GRIP's ``<out>.partial``) resumes after a kill;
    the finished file is then moved into the unit. GRIP's variants share the sensor
    features of the data through ``cache/features/<code>/`` (keyed inside by data hash):
    one folder per version of the code that trains them, so edited code never reads
    features an older version wrote.
    """
    work = st.cache.root / "work" / unit.key
    work.mkdir(parents=True, exist_ok=True)
    features = st.cache.root / "features" / unit.params["inputs"]["code"][:16]
    # the method trains on the profile sections its unit's key holds, no more (plan.py,
    # ``_train_profile``): a section it read without declaring would be missing, not stale
    profile = {**unit.params["inputs"]["profile"], "name": st.cfg.profile.get("name")}
    ctx = TrainContext(profile=profile, seed=st.cfg.seed, device=st.cfg.device,
                       progress=st.cfg.progress, feature_cache=features)
    nproc = int((st.cfg.profile.get("run") or {}).get("train_nproc", 1))
    path = train_checkpoint(unit.params["method"], st.data_dir(unit.deps[0]),
                            work / "model.ckpt", ctx, nproc)
    shutil.move(path, tmp / path.name)
    shutil.rmtree(work, ignore_errors=True)
    return {"file": path.name}
