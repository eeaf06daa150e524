"""Cache keys see every code change: editing a module gives new keys to exactly the units
that run it (and to the units downstream of those), and ``run --dry-run`` says the same.

Each case copies the source tree (``grip_bench`` and ``grip_baselines``) to a temporary
folder, plans the smoke profile from the copy in a fresh interpreter, appends a comment to
one statement to one module of the copy, plans again and compares unit by unit. Comments
and docstrings are not code: editing them renews nothing.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import grip_baselines
import pytest

import grip_bench

PLAN_SCRIPT = """
import json, sys
import grip_bench
from grip_bench.bench.cache import Cache
from grip_bench.bench.plan import build_plan, make_config
cfg = make_config("smoke", out=sys.argv[1], progress=False)
plan = build_plan(cfg, Cache(cfg.out / "cache"))
units = [{"label": u.label, "kind": u.kind, "key": u.key, "deps": list(u.deps),
          "method": u.params.get("method"), "code": u.params["inputs"].get("code")}
         for u in plan.units]
print(json.dumps({"source": grip_bench.__file__, "units": units}))
"""

GRIP_FAMILY = {"grip", "grip-no-ambient", "grip-no-proximity", "grip-voxel-ambient",
               "grip-no-consist", "grip-output-consist", "grip-no-rnet", "grip-future0",
               "grip-future3", "grip-future5", "grip-future10", "grip-blind"}


@pytest.fixture(scope="module")
def source_copy(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("src")
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(Path(grip_bench.__file__).parent, src / "grip_bench", ignore=ignore)
    shutil.copytree(Path(grip_baselines.__file__).parent, src / "grip_baselines", ignore=ignore)
    return src


def _env(src: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), GRIP_BENCH_CACHE="off")
    return env


def _plan(src: Path, out: Path) -> dict[str, dict]:
    """``{label: unit}`` of the smoke plan made by the code under ``src``."""
    done = subprocess.run([sys.executable, "-c", PLAN_SCRIPT, str(out)], env=_env(src),
                          cwd=src, capture_output=True, text=True, check=True)
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert Path(found["source"]).is_relative_to(src), "the copy must be the code that plans"
    return {u["label"]: u for u in found["units"]}


def _downstream(units: dict[str, dict], labels: set[str]) -> set[str]:
    """``labels`` plus every unit that reads one of them, transitively."""
    by_key = {u["key"]: label for label, u in units.items()}
    out, grew = set(labels), True
    while grew:
        grew = False
        for label, u in units.items():
            if label not in out and any(by_key.get(d) in out for d in u["deps"]):
                out.add(label)
                grew = True
    return out


@pytest.fixture(scope="module")
def baseline(source_copy, tmp_path_factory) -> dict[str, dict]:
    return _plan(source_copy, tmp_path_factory.mktemp("plan0"))


CODE_EDIT = b"\n_CACHE_KEY_PROBE = 1  # a new statement: new code\n"


def _edit_and_plan(src: Path, rel: str, out: Path, edit: bytes = CODE_EDIT) -> dict[str, dict]:
    path = src / rel
    original = path.read_bytes()
    try:
        path.write_bytes(original + edit)
        return _plan(src, out)
    finally:
        path.write_bytes(original)


def _direct_and_changed(before, after) -> tuple[set[str], set[str]]:
    assert before.keys() == after.keys()
    direct = {label for label in before if before[label]["code"] != after[label]["code"]}
    changed = {label for label in before if before[label]["key"] != after[label]["key"]}
    return direct, changed


@pytest.mark.parametrize("rel, expect", [
    # GRIP's sensors: GRIP's variants and the retrieval baseline that reads GRIP's sensors
    ("grip_bench/sensors.py", "sensors"),
    # distances: SynthGRAB's grasp search, the metrics and every method, not the perturbation
    # (this and the next ~27 s each: `pytest -m slow`, to keep the default run under 10 min)
    pytest.param("grip_bench/geometry/distance.py", "distance", marks=pytest.mark.slow),
    # the hand model: everything poses hands
    pytest.param("grip_bench/bodies/hand.py", "hand", marks=pytest.mark.slow),
])
def test_an_edit_renews_exactly_the_units_that_run_the_code(source_copy, baseline, tmp_path,
                                                             rel, expect):
    after = _edit_and_plan(source_copy, rel, tmp_path / "out")
    direct, changed = _direct_and_changed(baseline, after)
    # a key changes when the unit's own code changed or a unit it reads changed, and only then
    assert changed == _downstream(baseline, direct)
    kinds = {baseline[label]["kind"] for label in direct}
    methods = {baseline[label]["method"] for label in direct} - {None}
    every_method = {u["method"] for u in baseline.values()} - {None}
    if expect == "sensors":
        assert kinds == {"checkpoint", "prediction", "runtime"}
        assert methods == (GRIP_FAMILY | {"nearest-neighbour"}) & every_method
        untouched = {u["kind"] for label, u in baseline.items() if label not in changed}
        assert {"dataset", "perturbed", "metrics"} <= untouched
        assert {u["method"] for label, u in baseline.items() if label not in changed} >= {
            "gt", "perturbed-input", "flat-input", "mean-pose", "grabnet", "toch", "manipnet"}
    elif expect == "distance":
        # the perturbation adds noise to hand parameters only: renewed as the dataset's child
        assert kinds == {"dataset", "checkpoint", "prediction", "metrics", "runtime"}
        assert methods == every_method
    else:
        assert direct == set(baseline)  # every unit runs the hand model


def test_dry_run_marks_exactly_the_changed_units_todo(source_copy, baseline, tmp_path):
    """A finished run (every unit cached), then an edit of sensors.py: the dry run of the
    edited code lists as [todo] exactly the units whose keys changed."""
    from grip_bench.bench.cache import Cache

    out = tmp_path / "run"
    cache = Cache(out / "cache")
    for u in baseline.values():
        cache.path(u["key"]).mkdir(parents=True)
    rel = "grip_bench/sensors.py"
    after = _edit_and_plan(source_copy, rel, tmp_path / "plan")
    _, changed = _direct_and_changed(baseline, after)
    path = source_copy / rel
    original = path.read_bytes()
    try:
        path.write_bytes(original + CODE_EDIT)
        done = subprocess.run([sys.executable, "-m", "grip_bench", "run", "--profile", "smoke",
                               "--out", str(out), "--dry-run", "--quiet"],
                              env=_env(source_copy), cwd=source_copy, capture_output=True,
                              text=True, check=True)
    finally:
        path.write_bytes(original)
    todo = {line[len("[todo]"):].split(maxsplit=1)[1] for line in done.stdout.splitlines()
            if line.startswith("[todo]")}
    assert todo == changed and todo
    assert any(line.startswith("[cached]") for line in done.stdout.splitlines())


def test_comments_and_docstrings_are_not_code(source_copy, baseline, tmp_path):
    """A docstring edit and a new comment in sensors.py renew no unit."""
    path = source_copy / "grip_bench/sensors.py"
    text = path.read_text(encoding="utf-8")
    doc_end = text.index('"""', 3)  # the end of the module docstring
    try:
        path.write_text(text[:doc_end] + " Edited.\n" + text[doc_end:] + "\n# a comment\n",
                        encoding="utf-8")
        after = _plan(source_copy, tmp_path / "out")
    finally:
        path.write_text(text, encoding="utf-8")
    assert {k: u["key"] for k, u in after.items()} == {k: u["key"] for k, u in baseline.items()}
