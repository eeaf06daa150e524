"""Executing a plan's units: the run state, one unit at a time or in a process pool.

Units are written through ``Cache.atomic``: a killed run leaves either a complete unit or
nothing, and the next run does only what is missing.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.progress import bar
from .cache import UNIT_FILE, Cache, jsonable
from .plan import Plan, RunConfig, Unit

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    from ..core.registry import Registry
    from ..methods.api import MethodSpec


# --- execution helpers ----------------------------------------------------------------------
class RunLog:
    """Messages to stderr (above the progress bars) and appended to ``OUT/run.log``."""

    def __init__(self, path: Path, echo: bool = True):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.echo = echo

    def __call__(self, msg: str) -> None:
        if self.echo:
            from tqdm import tqdm

            tqdm.write(msg, file=sys.stderr)
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {msg}\n")


@dataclass
class RunState:
    """What the stages share: configuration, cache, plan, log, timings, loaded methods."""

    cfg: RunConfig
    cache: Cache
    plan: Plan
    log: RunLog
    stage_times: dict = field(default_factory=dict)
    methods: dict = field(default_factory=dict)

    def unit_dir(self, key: str) -> Path:
        return self.cache.path(key)

    def data_dir(self, key: str) -> Path:
        """The GRAB-layout folder of a dataset or perturbed unit."""
        return self.cache.path(key) / "data"

    def info(self, key: str) -> dict:
        return json.loads((self.cache.path(key) / UNIT_FILE).read_text(encoding="utf-8"))


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far, MiB (Linux reports ``ru_maxrss`` in KiB)."""
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def execute(st: RunState, unit: Unit, work: Callable[[Path], dict | None]) -> Path:
    """Run ``work(tmp)`` for a unit unless it is cached; the unit appears atomically.

    ``work`` returns a small dict recorded in the unit's ``unit.json`` beside its inputs,
    the unit's wall time (``seconds``) and the peak resident memory of the process that ran
    it before and after (``peak_rss_mib``; a pool worker's peak only grows, so the unit whose
    ``after`` first reaches a worker's peak is the one that set it; work done in a child
    pool, as evaluation's, is not in it). Neither is part of any result.
    """
    if st.cache.has(unit.key):
        return st.unit_dir(unit.key)
    with st.cache.atomic(unit.key) as tmp:
        t0, rss0 = time.perf_counter(), peak_rss_mib()
        info = work(tmp) or {}
        record = {"kind": unit.kind, "label": unit.label, "inputs": unit.params["inputs"],
                  "info": info, "seconds": round(time.perf_counter() - t0, 3),
                  "peak_rss_mib": {"before": rss0, "after": peak_rss_mib()}}
        text = json.dumps(jsonable(record), sort_keys=True, indent=1) + "\n"
        (tmp / UNIT_FILE).write_text(text, encoding="utf-8")
    return st.unit_dir(unit.key)


def run_stage(
    st: RunState, name: str, kind: str, fn: Callable[[RunState, Unit, Path], dict]
) -> None:
    """Execute every unit of ``kind`` with one progress bar; time the stage.

    Training and prediction units run in parallel worker processes when ``--workers`` > 1
    on the CPU (:func:`run_parallel`); everything else runs here in plan order.
    """
    t0 = time.perf_counter()
    for note in st.cache.take_notes():  # damaged units found while planning: rebuilt below
        st.log(note)
    units = st.plan.of(kind)
    todo = [u for u in units if not st.plan.cached[u.key]]
    if units:
        st.log(f"stage {name}: {len(units)} unit(s), {len(units) - len(todo)} cached")
    workers = min(stage_workers(st.cfg), len(todo))
    if kind in PARALLEL_KINDS and workers > 1:
        run_parallel(st, name, todo, fn, workers)
    else:
        for unit in bar(units, name, st.cfg.progress):
            if not st.plan.cached[unit.key]:
                st.log(f"  {unit.label}")
            execute(st, unit, lambda tmp, u=unit: fn(st, u, tmp))
    st.stage_times[name] = round(time.perf_counter() - t0, 3)


# --- parallel units -------------------------------------------------------------------------
# Training and prediction run single-threaded (grip_bench.core.threads), so W processes give
# about W times the throughput of one process with W threads, and a unit's result does not
# depend on how many run beside it.
PARALLEL_KINDS = ("checkpoint", "prediction")
# Kinds whose every unit runs in a fresh worker process. A training unit's peak memory is
# its own (GrabNet ~2.5 GB, more while the geometry cache is cold), but a kept worker's
# peak only grows: reused across the train stage, one worker reached 7.4 GB on the default
# profile (docs/performance.md). A fresh process costs one interpreter start and import
# (~3 s) per unit, small beside a training unit's minutes.
FRESH_PROCESS_KINDS = ("checkpoint",)
# Predictions (seconds each) share workers. In s31's default run one worker's 22 units took it
# from 585 to 4,423 MiB (past #17's 4 GB): uncollected reference cycles, which
# release_unit_memory now frees after every unit (without a quota: 1,754 MiB at most, s32).
# A prediction worker is still replaced after this many units, as a second bound: ~6
# interpreter starts a default run (~20 s of CPU).
PREDICTION_TASKS_PER_WORKER = 8


def worker_quota(kind: str) -> int | None:
    """How many units of ``kind`` a worker process runs before it is replaced: 1 for
    :data:`FRESH_PROCESS_KINDS`, :data:`PREDICTION_TASKS_PER_WORKER` for predictions, None
    (no limit) otherwise. The process pool and the Ray executor both follow it."""
    if kind in FRESH_PROCESS_KINDS:
        return 1
    return PREDICTION_TASKS_PER_WORKER if kind == "prediction" else None


def tasks_per_worker(units: list[Unit]) -> int | None:
    """``max_tasks_per_child`` of the pool running ``units``: the smallest
    :func:`worker_quota` of their kinds (None: workers live for the whole stage)."""
    quotas = [q for q in (worker_quota(u.kind) for u in units) if q is not None]
    return min(quotas) if quotas else None


def stage_workers(cfg: RunConfig) -> int:
    from ..metrics.aggregate import default_workers

    return 1 if cfg.device != "cpu" else (cfg.workers or default_workers())


def _init_unit_worker() -> None:
    import signal

    import torch

    from ..core.procs import exit_with_parent
    from ..methods.api import load_all

    exit_with_parent()  # a run killed outright must not leave its workers behind
    torch.set_num_threads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops its workers itself
    load_all()  # a spawned process starts with an empty method registry


def _unit_task(st: RunState, unit: Unit, fn: Callable[[RunState, Unit, Path], dict]) -> str:
    try:
        execute(st, unit, lambda tmp: fn(st, unit, tmp))
    finally:
        release_unit_memory(st)
    return unit.key


def release_unit_memory(st: RunState) -> None:
    """Free what a worker's unit left behind before its next unit: the methods it loaded
    (``st`` is the task's own copy, so nothing else uses them) and the reference cycles its
    work made. Python collects cycles only now and then, so without this a kept worker grew
    with every unit (smoke profile, one worker per stage, no worker quota: largest worker
    793 MiB without, 696 MiB with; GRIP variants +20-30 MiB each before, ~0 after)."""
    import gc

    st.methods.clear()
    gc.collect()


def _ready(unit: Unit, pending_keys: set[str]) -> bool:
    """A unit waits for the unit named in its ``after`` parameter (a shared-cache leader)."""
    return unit.params.get("after") not in pending_keys


def run_parallel(
    st: RunState,
    name: str,
    units: list[Unit],
    fn: Callable[[RunState, Unit, Path], dict],
    workers: int,
) -> None:
    """Run ``units`` in a spawn pool of ``workers`` processes, at most ``workers`` at a time.

    Units are started leaders first (a unit with ``after`` waits for that unit: GRIP's
    variants wait for the first one, which builds the shared sensor features and ANet),
    then the costliest predictions (``MethodSpec.predict_cost``), otherwise in plan order,
    so that the stage does not end with one long unit on one worker. Training units each get
    a fresh process, prediction workers are replaced every few units (:func:`tasks_per_worker`).
    On an interrupt or a failure the workers are terminated and their unfinished temp folders
    removed; finished units stay in the cache.
    """
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from ..methods.api import METHODS

    child = RunState(dataclasses.replace(st.cfg, progress=False), st.cache, st.plan, st.log)
    leaders = {u.params.get("after") for u in units}
    pending = sorted(units, key=lambda u: (u.key not in leaders, -_predict_cost(u, METHODS)))
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                               initializer=_init_unit_worker,
                               max_tasks_per_child=tasks_per_worker(units))
    running: dict = {}
    progress = _counter(len(units), name, st.cfg.progress)
    try:
        while pending or running:
            keys = {u.key for u in pending} | {u.key for u in running.values()}
            for unit in [u for u in pending if _ready(u, keys)][:workers - len(running)]:
                st.log(f"  {unit.label}")
                running[pool.submit(_unit_task, child, unit, fn)] = unit
                pending.remove(unit)
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in done:
                running.pop(fut)
                fut.result()  # re-raise a unit's error here
                progress.update()
    except BaseException:
        _stop_workers(pool)
        st.cache.clean_stale()
        raise
    finally:
        progress.close()
        pool.shutdown(wait=True, cancel_futures=True)


def _counter(total: int, desc: str, enabled: bool) -> tqdm:
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="unit", leave=False, file=sys.stderr,
                dynamic_ncols=True, disable=not enabled)


def _predict_cost(unit: Unit, methods: Registry[MethodSpec]) -> float:
    name = unit.params.get("method")
    if unit.kind != "prediction" or name not in methods:
        return 0.0
    return methods.get(name).predict_cost


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Terminate the pool's processes now (``shutdown`` would wait for running units)."""
    for proc in list(getattr(pool, "_processes", {}).values()):  # private, but the only handle
        proc.terminate()
    for proc in list(getattr(pool, "_processes", {}).values()):
        proc.join(timeout=10)
