"""Data-parallel training with PyTorch DDP: process groups, the global batch, BatchNorm.

The training loops (GRIP's ``grip_bench/grip/train.py``, the learned baselines) use this
module so that a run on N processes computes what one process computes on the same global
batches, up to floating-point summation order (docs/distributed_training.md):

- the profile's ``batch_size`` is the GLOBAL batch; every rank draws the same permutation
  from the seed and takes its contiguous share of each global batch (:func:`rank_share`);
- each rank's loss is the mean over its share, weighted by ``n_rank * N / n_global``
  (:func:`share_weight`; exactly 1 for an even split) so that DDP's gradient average is
  the mean over the global batch;
- BatchNorm in training mode normalises with the statistics of the GLOBAL batch
  (:class:`GlobalBatchNorm1d`, all-reduced through autograd; torch's ``SyncBatchNorm``
  refuses CPU tensors), so running statistics and gradients match one process;
- scalars that drive decisions (validation loss) are reduced in float64 and rank 0's value
  is broadcast (:func:`global_mean`), so every rank takes the same branch.

A single process (``world == 1``) never touches ``torch.distributed``: its path is the
plain one and writes the same bytes as before DDP existed.
"""

from __future__ import annotations

import contextlib
import inspect
import os
import socket
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from grip_bench.core.errors import InputError

ENV_KEYS = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")


@dataclass(frozen=True)
class Dist:
    """This process's place in the training job (``world == 1``: no job)."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        """Rank 0: the only one that prints progress and writes files."""
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world > 1


SINGLE = Dist()  # one process, no job
_BN_GROUP: Any = None  # a second process group for BatchNorm statistics (see below)


def current() -> Dist:
    """The running job (an initialised default process group), or a single process."""
    if not (dist.is_available() and dist.is_initialized()):
        return SINGLE
    return Dist(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", 0)))


def env_world() -> int:
    """``WORLD_SIZE`` set by torchrun (or :func:`spawn`) for this process; 1 when unset."""
    return int(os.environ.get("WORLD_SIZE", "1") or 1)


def backend_for(device: str | torch.device) -> str:
    """nccl for CUDA training, gloo for the CPU."""
    return "nccl" if torch.device(device).type == "cuda" else "gloo"


def resolve_device(device: str | torch.device) -> torch.device:
    """``--device`` as a ``torch.device``: ``cpu``, ``cuda`` or ``cuda:N`` (or ``mps``).

    An unknown device, or one this machine does not have, is an :class:`InputError` naming
    ``--device``: a run asked for the GPU must not silently train on the CPU. GRIP and the
    baselines share it (both sit above this layer).
    """
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError, ValueError):
        raise InputError(f"unknown device {device!r} (cpu or cuda)", "--device") from None
    if dev.type == "cpu":
        return dev
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise InputError("CUDA is not available on this machine (use --device cpu)",
                             "--device")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise InputError(f"no CUDA device {dev.index} on this machine "
                             f"({torch.cuda.device_count()} found)", "--device")
        return dev
    if dev.type == "mps":
        if not torch.backends.mps.is_available():
            raise InputError("MPS is not available on this machine (use --device cpu)",
                             "--device")
        return dev
    raise InputError(f"unsupported device {device!r} (cpu or cuda)", "--device")


def train_device(device: str | torch.device, d: Dist) -> torch.device:
    """The device this rank trains on: :func:`resolve_device` of ``--device``, and under a
    DDP job with ``cuda`` the rank's own GPU ``cuda:LOCAL_RANK`` (nccl's one-GPU-per-rank
    layout; :func:`process_group` made it the current device)."""
    dev = resolve_device(device)
    if d.active and dev.type == "cuda":
        dev = resolve_device(f"cuda:{d.local_rank}")
    return dev


@contextlib.contextmanager
def process_group(device: str | torch.device = "cpu") -> Iterator[Dist]:
    """Join the job described by torchrun's environment (``WORLD_SIZE > 1``) for the block.

    Nothing happens for a single process or when a group is already initialised (the
    caller owns it then). Yields :func:`current`.
    """
    global _BN_GROUP
    if env_world() <= 1 or dist.is_initialized():
        yield current()
        return
    backend = backend_for(device)
    if backend == "nccl":
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", 0)))
    dist.init_process_group(backend)
    # BatchNorm's all-reduces run inside the backward pass, while DDP all-reduces gradient
    # buckets asynchronously on the default group: a group of their own keeps the two
    # streams of collectives from interleaving differently on different ranks.
    _BN_GROUP = dist.new_group(backend=backend)
    try:
        yield current()
    finally:
        _BN_GROUP = None
        dist.destroy_process_group()


def free_port() -> int:
    """A TCP port on localhost that is free now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _rank_entry(rank: int, world: int, port: int, fn: Callable, args: tuple, errors: Any) -> None:
    from ..core.procs import exit_with_parent

    exit_with_parent()  # a rank ends with a killed launcher rather than wait on its peers
    os.environ.update(RANK=str(rank), WORLD_SIZE=str(world), LOCAL_RANK=str(rank),
                      MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    try:
        fn(*args)
    except InputError as e:  # passed back as itself: the CLI prints it as one line
        errors.put((rank, e.what, str(e.where)))
        raise


def spawn(fn: Callable, nproc: int, args: tuple) -> None:
    """Run ``fn(*args)`` in ``nproc`` fresh processes on localhost (ranks 0..nproc-1).

    Each process sees torchrun's environment variables (``RANK``, ``WORLD_SIZE``, ...) with
    a free port, so ``fn`` joins the job through :func:`process_group`. ``fn`` must be
    importable (a module-level function). An :class:`InputError` in a rank is raised here.
    """
    import torch.multiprocessing as mp

    ctx = mp.get_context("spawn")
    errors = ctx.SimpleQueue()
    try:
        mp.spawn(_rank_entry, args=(nproc, free_port(), fn, args, errors), nprocs=nproc,
                 join=True, start_method="spawn")
    except mp.ProcessRaisedException:
        if not errors.empty():
            _, what, where = errors.get()
            raise InputError(what, where) from None
        raise
    finally:
        errors.close()


def check_nproc(nproc: int, where: str = "--nproc") -> int:
    if not isinstance(nproc, int) or isinstance(nproc, bool) or nproc < 1:
        raise InputError(f"the process count must be an int >= 1, got {nproc!r}", where)
    return nproc


def check_gpus(nproc: int, device: str | torch.device) -> None:
    """A local CUDA job of ``nproc`` processes needs one GPU per process (rank r trains on
    ``cuda:r``): an :class:`InputError` before any process starts, else nothing."""
    if nproc > 1 and resolve_device(device).type == "cuda":
        found = torch.cuda.device_count()
        if nproc > found:
            raise InputError(f"{nproc} processes on cuda need one GPU each, {found} found",
                             "--nproc")


def check_batch(batch_size: int, d: Dist, where: str) -> None:
    """The global batch must split evenly over the ranks (an :class:`InputError` otherwise)."""
    if batch_size % d.world:
        raise InputError(f"batch_size {batch_size} is the global batch and must split evenly "
                         f"over {d.world} processes", where)


def rank_share(global_idx: np.ndarray, d: Dist) -> np.ndarray:
    """This rank's contiguous share of one global batch ``(B,) -> (~B / N,)``.

    Shares differ by at most one sample (a last, shorter batch); concatenated in rank
    order they are the global batch.
    """
    return np.array_split(global_idx, d.world)[d.rank]


def share_weight(n_share: int, n_global: int, d: Dist) -> float:
    """Loss weight of a rank's share: DDP averages over ranks, this makes it the mean over
    the global batch (``n_share * N / n_global``; 1.0 for an even split)."""
    return n_share * d.world / n_global


def wrap(model: nn.Module, d: Dist, device: torch.device | None = None) -> nn.Module:
    """``model`` with global-batch BatchNorm, inside ``DistributedDataParallel`` (as it is
    for a single process). The wrapped module shares the parameters: optimise
    ``model.parameters()``, save ``model.state_dict()``."""
    if not d.active:
        return model
    convert_batchnorm(model)
    ids = [device] if device is not None and device.type == "cuda" else None
    # buffers (BatchNorm's running statistics) are the same on every rank by construction:
    # no broadcast before each forward (the keyword's name changed in torch 2.13)
    params = inspect.signature(nn.parallel.DistributedDataParallel).parameters
    quiet = ({"forward_sync_buffers": False} if "forward_sync_buffers" in params
             else {"broadcast_buffers": False})
    return nn.parallel.DistributedDataParallel(model, device_ids=ids, **quiet)


def global_sum(values: list[float], d: Dist, device: str | torch.device = "cpu") -> list[float]:
    """Element-wise sum over the ranks (float64), rank 0's result broadcast to all."""
    if not d.active:
        return list(values)
    t = torch.tensor(values, dtype=torch.float64, device=device)
    dist.all_reduce(t)
    dist.broadcast(t, 0)  # the same bits everywhere, whatever the reduction order
    return [float(v) for v in t.cpu()]


def global_mean(total: float, count: float, d: Dist, device: str | torch.device = "cpu") -> float:
    """``sum(total) / sum(count)`` over the ranks (0-safe)."""
    total, count = global_sum([total, count], d, device)
    return total / max(count, 1)


def agree(value: Any, d: Dist) -> Any:
    """Rank 0's ``value`` on every rank (for decisions read from files that could change
    between the ranks' reads)."""
    if not d.active:
        return value
    box = [value]
    dist.broadcast_object_list(box, 0)
    return box[0]


def barrier(d: Dist) -> None:
    if d.active:
        dist.barrier()


@contextlib.contextmanager
def main_first(d: Dist) -> Iterator[None]:
    """Rank 0 runs the block, then the others (for work that fills a shared cache)."""
    if not d.main:
        barrier(d)
    yield
    if d.main:
        barrier(d)


def broadcast_module(model: nn.Module, d: Dist) -> None:
    """Rank 0's parameters and buffers on every rank (in place)."""
    if not d.active:
        return
    with torch.no_grad():
        for t in [*model.parameters(), *model.buffers()]:
            dist.broadcast(t.data, 0)


# --- BatchNorm over the global batch -------------------------------------------------------
class GlobalBatchNorm1d(nn.BatchNorm1d):
    """``BatchNorm1d`` whose training statistics are those of the global batch.

    ``(N, C)`` or ``(N, C, L)``. The per-channel count, sum and sum of squares (float64) are
    summed over the ranks with the differentiable all-reduce, so the backward pass carries
    each sample's share of the statistics' gradient back to the rank that holds it, as
    torch's ``SyncBatchNorm`` does on GPUs. Running statistics are updated as one process
    would (unbiased variance of the global batch). Eval mode, or no job: plain BatchNorm.
    Same parameters and buffers as ``BatchNorm1d``: state dicts are interchangeable.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (self.training and dist.is_initialized() and dist.get_world_size() > 1):
            return super().forward(x)
        dims = [0, *range(2, x.ndim)]
        x64 = x.double()
        n_local = x64.numel() / x64.shape[1]
        stats = torch.cat([x64.sum(dims), (x64 * x64).sum(dims),
                           x64.new_full((1,), n_local)])
        stats = _AllReduce.apply(stats, _BN_GROUP or dist.group.WORLD)
        c = x.shape[1]
        n = stats[-1]
        mean = stats[:c] / n
        var = (stats[c:2 * c] / n - mean * mean).clamp_min(0.0)  # biased, as BN normalises
        if self.track_running_stats:
            self._update_running(mean.detach(), var.detach(), float(n.detach()))
        shape = [1, c] + [1] * (x.ndim - 2)
        y = (x64 - mean.view(shape)) / torch.sqrt(var.view(shape) + self.eps)
        y = y.to(x.dtype)
        if self.affine:
            y = y * self.weight.view(shape) + self.bias.view(shape)
        return y

    @torch.no_grad()
    def _update_running(self, mean: torch.Tensor, var: torch.Tensor, n: float) -> None:
        self.num_batches_tracked.add_(1)
        m = self.momentum if self.momentum is not None else 1.0 / float(self.num_batches_tracked)
        unbiased = var * (n / max(n - 1.0, 1.0))
        self.running_mean.mul_(1 - m).add_(mean.to(self.running_mean.dtype), alpha=m)
        self.running_var.mul_(1 - m).add_(unbiased.to(self.running_var.dtype), alpha=m)


class _AllReduce(torch.autograd.Function):
    """Differentiable sum over the ranks: ``y = sum_r x_r`` on every rank, so the gradient
    of ``x_r`` is the sum over the ranks of ``dL_r / dy``."""

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor, group: Any) -> torch.Tensor:
        ctx.group = group
        y = x.clone()
        dist.all_reduce(y, group=group)
        return y

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, None]:
        g = grad.contiguous().clone()
        dist.all_reduce(g, group=ctx.group)
        return g, None


def convert_batchnorm(module: nn.Module) -> nn.Module:
    """Every ``BatchNorm1d`` below ``module`` becomes a :class:`GlobalBatchNorm1d` sharing
    its parameters and buffers (in place; returns the root, replaced if it is one)."""
    if isinstance(module, nn.BatchNorm1d) and not isinstance(module, GlobalBatchNorm1d):
        new = GlobalBatchNorm1d(module.num_features, module.eps, module.momentum,
                                module.affine, module.track_running_stats)
        new.weight, new.bias = module.weight, module.bias
        new.running_mean, new.running_var = module.running_mean, module.running_var
        new.num_batches_tracked = module.num_batches_tracked
        new.train(module.training)
        return new
    for name, child in module.named_children():
        new = convert_batchnorm(child)
        if new is not child:
            setattr(module, name, new)
    return module
