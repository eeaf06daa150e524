"""Training units each run in a fresh worker process (their peak memory is their own);
prediction units share the stage's workers, each replaced after
``PREDICTION_TASKS_PER_WORKER`` units. Real spawn pools, trivial units."""

import dataclasses
import json
import os
from pathlib import Path

from grip_bench.bench.cache import Cache
from grip_bench.bench.execute import (
    PREDICTION_TASKS_PER_WORKER,
    RunState,
    run_parallel,
    tasks_per_worker,
    worker_quota,
)
from grip_bench.bench.plan import Plan, Unit


@dataclasses.dataclass
class _Cfg:  # the fields run_parallel reads
    progress: bool = False


def _no_log(msg: str) -> None:
    pass


def _record_pid(st, unit, tmp) -> dict:  # module level: a spawned worker imports it
    return {"pid": os.getpid()}


def _units(kind: str, n: int) -> list[Unit]:
    return [Unit(kind, f"{kind}-{i:064x}", f"{kind} {i}", {"inputs": {"i": i}}) for i in range(n)]


def _pids(tmp_path: Path, kind: str, n: int) -> list[int]:
    units = _units(kind, n)
    cache = Cache(tmp_path / "cache")
    plan = Plan(units, {u.key: False for u in units}, data_key="", dataset="")
    st = RunState(_Cfg(), cache, plan, log=_no_log)
    run_parallel(st, kind, units, _record_pid, workers=2)
    return [json.loads((cache.path(u.key) / "unit.json").read_text())["info"]["pid"]
            for u in units]


def test_the_policy_per_kind_and_per_pool():
    assert (worker_quota("checkpoint"), worker_quota("prediction")) == (
        1, PREDICTION_TASKS_PER_WORKER)
    assert worker_quota("metrics") is None  # the Ray executor follows the same quotas
    assert tasks_per_worker(_units("checkpoint", 2)) == 1
    assert tasks_per_worker(_units("prediction", 2)) == PREDICTION_TASKS_PER_WORKER
    assert tasks_per_worker(_units("metrics", 2)) is None
    assert tasks_per_worker(_units("prediction", 1) + _units("checkpoint", 1)) == 1


def test_each_training_unit_gets_its_own_process(tmp_path):
    pids = _pids(tmp_path, "checkpoint", 3)
    assert len(set(pids)) == 3 and os.getpid() not in pids


def test_prediction_units_reuse_the_stage_workers(tmp_path):
    pids = _pids(tmp_path, "prediction", 4)
    assert len(set(pids)) <= 2 and os.getpid() not in pids


def test_a_prediction_worker_is_replaced_after_its_quota(tmp_path, monkeypatch):
    """Two workers cannot run 2 k + 1 units without one of them passing its quota of k (k = 2
    here: the pool reads the quota in this process, and each spawn costs seconds)."""
    from grip_bench.bench import execute

    monkeypatch.setattr(execute, "PREDICTION_TASKS_PER_WORKER", 2)
    pids = _pids(tmp_path, "prediction", 5)
    assert len(set(pids)) >= 3 and os.getpid() not in pids
    assert max(pids.count(p) for p in set(pids)) <= 2


class _Cyclic:
    """A loaded method stand-in caught in a reference cycle (as real ones can be)."""

    def __init__(self):
        self.me = self


def test_a_worker_frees_its_units_methods_and_cycles_after_each_unit(tmp_path):
    """``_unit_task`` (a pool worker's unit) ends with ``release_unit_memory``: the task's
    loaded methods are dropped (also when the unit fails) and the cycles its work made are
    collected at once, so a kept worker does not grow from unit to unit."""
    import gc
    import weakref

    import pytest

    from grip_bench.bench.execute import _unit_task

    units = _units("prediction", 2)
    plan = Plan(units, {u.key: False for u in units}, data_key="", dataset="")
    st = RunState(_Cfg(), Cache(tmp_path / "cache"), plan, log=_no_log)
    refs = []

    def work(state, unit, tmp, fail=False):
        made = _Cyclic()
        state.methods[("m", unit.key)] = made
        garbage = _Cyclic()  # left behind by the unit's own work
        refs.extend([weakref.ref(made), weakref.ref(garbage)])
        if fail:
            raise RuntimeError("unit failed")
        return {}

    gc.disable()  # only release_unit_memory may collect here
    try:
        assert _unit_task(st, units[0], work) == units[0].key
        assert not st.methods and all(r() is None for r in refs)
        with pytest.raises(RuntimeError, match="unit failed"):
            _unit_task(st, units[1], lambda s, u, t: work(s, u, t, fail=True))
        assert not st.methods  # (its objects live on in the traceback pytest keeps)
    finally:
        gc.enable()
