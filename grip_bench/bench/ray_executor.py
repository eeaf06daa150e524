"""``grip-bench run --executor ray``: the plan's units as Ray tasks over the same cache.

The head (this process) only schedules: it submits every missing unit of the plan as one
Ray task (``ray.remote``) whose arguments include the tasks of the units it reads
(``Unit.deps``, and a shared-cache leader named by ``after``), so Ray starts a unit when
those are in the cache. Workers read and write the cache folder directly, so ``OUT`` must
be on a filesystem every node mounts at the same path; each task runs the unit through
:func:`bench.execute.execute` (temp folder, integrity record, atomic rename), exactly as
the local executor does, so a unit already in the cache is not submitted and a killed Ray
run, run again, continues where it stopped. Nothing here decides what to compute: the
plan (``bench.plan``) does, for both executors.

Resources per unit (:func:`unit_resources`): one CPU for a unit that runs a method
(training, prediction and timing run single-threaded) plus one GPU when the device is CUDA;
the run's evaluation workers (``--workers``, else one per CPU up to 8, at most the largest
node's CPUs) for a unit with a process pool (dataset, metrics, validity), which the task
then uses as its ``--workers``. No unit requests memory: none has an estimate yet.
Timing units (``runtime``) run last, one at a time, so no other unit of the run competes
with the method being timed.

Ray is an optional dependency (``pip install "grip-bench[ray]"``).
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core import numerics
from ..core.errors import InputError
from .cache import Cache
from .execute import RunLog, RunState, execute, release_unit_memory, worker_quota

if TYPE_CHECKING:
    from .plan import Plan, RunConfig, Unit

StageFn = Callable[[RunState, "Unit", Path], dict]
INSTALL_HINT = 'Ray is not installed: pip install "grip-bench[ray]" (or pip install ray)'
METHOD_KINDS = ("checkpoint", "prediction", "runtime")  # units that build and run a method
POOL_KINDS = ("dataset", "metrics", "validity", "sensitivity")  # a pool of --workers


def import_ray() -> Any:
    """The ``ray`` module, or a one-line :class:`InputError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise InputError(INSTALL_HINT, where="--executor ray") from None
    return ray


def unit_resources(unit: Unit, cfg: RunConfig, max_cpus: int) -> dict:
    """Ray task options of ``unit``: ``num_cpus`` and ``num_gpus`` (see the module docstring).

    ``max_cpus``: the CPUs of the largest node, so that every unit fits somewhere.
    """
    from ..metrics.aggregate import default_workers

    gpus = 1 if cfg.device.startswith("cuda") and unit.kind in METHOD_KINDS else 0
    cpus = 1
    if unit.kind in POOL_KINDS:
        cpus = max(1, min(cfg.workers or default_workers(), max_cpus))
        if unit.params.get("sequences"):  # a shard needs no more workers than sequences
            cpus = min(cpus, len(unit.params["sequences"]))
    return {"num_cpus": cpus, "num_gpus": gpus}


def _run_unit(cfg: RunConfig, plan: Plan, unit: Unit, fn: StageFn, *_deps: str,
              numerics_mode: str = "portable") -> str:
    """Body of a unit's Ray task (on a worker): the unit through the shared cache.

    ``_deps``: the keys the tasks of the units it reads returned (Ray passes them once
    those tasks finished, so the units are in the cache). ``numerics_mode``: the driver's
    (``core/numerics.py``); a worker whose kernels differ stops before writing a unit under
    a key that names other kernels."""
    import torch

    from ..methods.api import load_all

    numerics.check_worker(numerics_mode)

    torch.set_num_threads(1)  # as the local workers: the same floating-point path
    load_all()  # a fresh worker starts with an empty method registry
    st = RunState(cfg, Cache(cfg.out / "cache"), plan, RunLog(cfg.out / "run.log", echo=False))
    try:
        execute(st, unit, lambda tmp: fn(st, unit, tmp))
    finally:
        release_unit_memory(st)  # a Ray worker runs several units, as a pool worker does
    return unit.key


def connect(ray: Any, cfg: RunConfig) -> bool:
    """Join the cluster at ``cfg.address`` (``auto``: the one ``ray start`` made on this
    machine), or start a private local Ray instance with ``--workers`` CPUs. True when this
    call connected (the run then disconnects at its end)."""
    if ray.is_initialized():
        return False
    # The pins reach a node's workers as they start, before anything there loads numpy:
    # a cluster's nodes do not inherit this process's environment (core/numerics.py).
    kwargs: dict = {"include_dashboard": False, "log_to_driver": False,
                    "configure_logging": False,
                    "runtime_env": {"env_vars": numerics.env()}}
    if cfg.address is None:
        kwargs.update(address="local", num_cpus=cfg.workers)
    else:
        kwargs["address"] = cfg.address
    try:
        ray.init(**kwargs)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise InputError(f"cannot join the Ray cluster: {' '.join(str(e).split())[:300]}",
                         where=f"--address {cfg.address}") from None
    return True


def _largest_node_cpus(ray: Any) -> int:
    cpus = [n.get("Resources", {}).get("CPU", 0) for n in ray.nodes() if n.get("Alive")]
    return max(1, int(max(cpus, default=1)))


class _Submitter:
    """Submits units as Ray tasks, each once, with its dependencies as task arguments."""

    def __init__(self, ray: Any, st: RunState, fns: dict[str, StageFn]):
        self.ray, self.st, self.fns = ray, st, fns
        self.max_cpus = _largest_node_cpus(ray)
        # workers run elsewhere (another node, another working directory): absolute paths
        self.cfg = dataclasses.replace(
            st.cfg, progress=False, out=st.cfg.out.resolve(),
            data=st.cfg.data.resolve() if st.cfg.data else None,
            model_path=str(Path(st.cfg.model_path).resolve()) if st.cfg.model_path else None)
        self.refs: dict[str, Any] = {}  # unit key -> its task
        self.labels: dict[Any, str] = {}  # task -> unit label
        self.tasks: dict[str, Any] = {}  # unit kind -> its remote function
        self.plan_ref = None

    def submit(self, plan: Plan, units: Sequence[Unit], after: Any = None) -> Any:
        """Submit the units not cached and not submitted yet, in plan order; returns the
        last task (``after``: a task every one of them waits for too)."""
        self.plan_ref = self.ray.put(plan)
        last = after
        for unit in units:
            if plan.cached[unit.key] or unit.key in self.refs:
                continue
            reads = [*unit.deps, unit.params.get("after")]
            deps = [self.refs[k] for k in reads if k in self.refs]
            deps += [after] if after is not None else []
            res = unit_resources(unit, self.cfg, self.max_cpus)
            cfg = self.cfg
            if unit.kind in POOL_KINDS:  # the pool the task reserved CPUs for
                cfg = dataclasses.replace(cfg, workers=res["num_cpus"])
            ref = self._task(unit.kind).options(**res, name=unit.label[:60]).remote(
                cfg, self.plan_ref, unit, self.fns[unit.kind], *deps,
                numerics_mode=numerics.mode())
            self.refs[unit.key] = last = ref
            self.labels[ref] = unit.label
            self.st.log(f"  submitted {unit.label} ({res['num_cpus']} CPU"
                        f"{', 1 GPU' if res['num_gpus'] else ''})")
        return last

    def _task(self, kind: str) -> Any:
        """The remote function for units of ``kind``: a worker runs at most
        ``execute.worker_quota(kind)`` of them before Ray replaces it (``max_calls``, which
        ``options`` cannot override: one remote function per kind), as the local pool does."""
        if kind not in self.tasks:
            quota = worker_quota(kind)
            self.tasks[kind] = (self.ray.remote(max_calls=quota)(_run_unit) if quota
                                else self.ray.remote(_run_unit))
        return self.tasks[kind]

    def wait(self, refs: list) -> None:
        """Until every task of ``refs`` finished; a unit's error is raised here."""
        pending = list(refs)
        while pending:
            done, pending = self.ray.wait(pending, num_returns=1)
            self.ray.get(done[0])  # re-raises the unit's error (its own exception type)
            self.st.log(f"  done {self.labels.get(done[0], '')}")

    def cancel(self) -> None:
        for ref in self.refs.values():
            try:
                self.ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - a finished task cannot be cancelled; fine
                pass


def run_ray(st: RunState, stages: Sequence[tuple[str, str, StageFn]],
            replan: Callable[[RunState], bool]) -> None:
    """Execute the plan's missing units on Ray (see the module docstring).

    ``stages``: ``(stage name, unit kind, stage function)`` as the local executor's;
    ``replan(st)``: the runner's re-planning once the dataset exists (sharded runs).
    """
    import time

    ray = import_ray()
    connected = connect(ray, st.cfg)
    fns = {kind: fn for _, kind, fn in stages}
    sub = _Submitter(ray, st, fns)
    t0 = time.perf_counter()
    for note in st.cache.take_notes():
        st.log(note)
    try:
        body = [u for u in st.plan.units if u.kind != "runtime"]
        sub.submit(st.plan, body)
        if st.plan.deferred:  # shards list the dataset's sequences: plan them once it exists
            sub.wait([sub.refs[st.plan.data_key]] if st.plan.data_key in sub.refs else [])
            replan(st)
            sub.submit(st.plan, [u for u in st.plan.units if u.kind != "runtime"])
        sub.wait(list(sub.refs.values()))
        last = None
        for unit in st.plan.of("runtime"):  # one at a time, after everything else
            last = sub.submit(st.plan, [unit], after=last)
        sub.wait(list(sub.refs.values()))
    except BaseException:
        sub.cancel()
        st.cache.clean_stale()
        raise
    finally:
        sys.stderr.flush()
        if connected:
            ray.shutdown()
    st.log(f"ray: {len(sub.refs)} unit(s) run on the cluster")
    st.stage_times["ray"] = round(time.perf_counter() - t0, 3)
