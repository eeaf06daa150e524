"""The run's ``validity`` unit: planned when ``[run] validity_sequences`` > 0, keyed by the
dataset unit, the sequences, the seed, the levels, the options and its code; its stage
function writes ``validity.csv``; the runner assembles ``OUT/validity.{csv,json}`` (or
removes stale ones); ``grip-bench report`` renders the table and the figure from them."""

from __future__ import annotations

import json
import re
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest

from grip_bench.bench.cache import Cache
from grip_bench.bench.plan import Unit, build_plan, make_config, stage_code
from grip_bench.bench.runner import VALIDITY_REPORT, assemble_validity
from grip_bench.bench.stages.validity import VALIDITY_FILE, measure_validity
from grip_bench.cli.main import main
from grip_bench.metrics import validity as V
from tests.eval_fixtures import grasp_dataset
from tests.run_fixtures import tiny_run_profile


def _plan(tmp_path: Path, n: int = 2, seed: int = 0, data_seed: int = 0):
    path = tmp_path / f"p_{n}_{seed}_{data_seed}.toml"
    # viewer_sequences 2: the optional key's default
    tiny_run_profile(path, validity_sequences=n, seed=seed, data_seed=data_seed,
                     viewer_sequences=2)
    cfg = make_config(str(path), out=tmp_path / "out", progress=False)
    return build_plan(cfg, Cache(tmp_path / "out" / "cache"))


def test_the_unit_is_keyed_by_data_sequences_seed_levels_and_code(tmp_path):
    plan = _plan(tmp_path)
    (unit,) = plan.of("validity")
    assert plan.units[-1] is unit  # after every other unit
    assert unit.deps == (plan.data_key,)
    inputs = unit.params["inputs"]
    assert inputs["data"] == plan.data_key and inputs["sequences"] == 2 and inputs["seed"] == 0
    assert inputs["levels"] == V.degradation_levels()
    assert inputs["code"] == stage_code("validity")
    options = inputs["options"]
    assert options["max_physics_frames"] == V.VALIDITY_PHYSICS_FRAMES
    assert options["max_sim_frames"] == V.VALIDITY_SIM_FRAMES < V.VALIDITY_PHYSICS_FRAMES
    assert options["max_iv_frames"] == V.VALIDITY_IV_FRAMES
    assert options["metrics"] == ("mpjpe", "mpvpe", "cc", "contact_ratio")  # the run's metrics
    assert set(inputs["versions"]) == set(options["metrics"])
    keys = {unit.key}
    for kw in ({"n": 3}, {"seed": 1}, {"data_seed": 1}):
        other = _plan(tmp_path, **kw)
        keys.add(other.of("validity")[0].key)
        if "data_seed" in kw:
            assert other.data_key != plan.data_key
    assert len(keys) == 4
    assert _plan(tmp_path, n=0).of("validity") == []
    with pytest.raises(Exception, match="validity_sequences"):
        _plan(tmp_path, n=-1)


def test_the_unit_runs_the_metric_and_evaluation_code_and_nothing_else():
    from grip_bench.bench.codehash import CodeIndex

    closure = set(CodeIndex.installed().closure(["grip_bench.bench.stages.validity"]))
    assert {"grip_bench.metrics.validity", "grip_bench.metrics.evaluate",
            "grip_bench.metrics.contact", "grip_bench.geometry.distance",
            "grip_bench.bodies.hand"} <= closure
    assert "grip_bench.metrics.physics" in closure  # physics responses are measured too
    assert not {m for m in closure if re.match(r"grip_bench\.(report|grip|sensors|cli)\b", m)}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("validity_data")
    grasp_dataset(root, T=40)
    return root


def _state(out: Path, data: Path, units: list[Unit]):
    """The little of a RunState the validity stage and its assembly read."""
    cache = Cache(out / "cache")
    return SimpleNamespace(cfg=SimpleNamespace(out=out, progress=False, workers=1),
                           data_dir=lambda key: data, unit_dir=cache.path,
                           plan=SimpleNamespace(of=lambda kind: units if kind == "validity"
                                                else []))


def test_stage_writes_validity_csv_and_report_renders_it(data, tmp_path, capsys):
    levels = {"wrist": (0.0, 0.01), "jitter": (0.0, 0.0025)}
    inputs = {"data": "k", "split": "test", "sequences": 1, "seed": 0, "levels": levels,
              "options": {"physics": False, "max_iv_frames": 2,
                          "metrics": ["mpjpe", "mpvpe", "cdev", "accel_err"]}}
    unit = Unit("validity", "validity-" + "f" * 64, "metric validity", {"inputs": inputs},
                ("k",))
    out = tmp_path / "out"
    st = _state(out, data, [unit])
    tmp = st.unit_dir(unit.key)
    tmp.mkdir(parents=True)
    info = measure_validity(st, unit, tmp)
    assert info == {"sequences": 1, "broken_claims": []}
    df = pd.read_csv(tmp / VALIDITY_FILE, keep_default_na=False)
    assert set(df["degradation"]) == {"wrist", "jitter"} and len(df) == 2 * 2 * 4
    assert set(df["metric"]) == {"mpjpe", "mpvpe", "cdev", "accel_err"}
    assembled = assemble_validity(st)
    assert assembled is None and (out / "validity.csv").read_bytes() == (
        tmp / VALIDITY_FILE).read_bytes()
    assert json.loads((out / "validity.json").read_text())["unit"] == unit.key
    from grip_bench.results.schema import write_results

    write_results([], out / "results.csv")
    assert main(["report", str(out)]) == 0
    capsys.readouterr()
    md = (out / "tables" / "metric_validity.md").read_text()
    assert "| mpjpe | mm | 0.00 | 10.00 | up | PASS |" in md and "FAIL" not in md
    assert (out / "figures" / "metric_validity.png").read_bytes()[:4] == b"\x89PNG"
    # the profile turned validity off: the run's stale files go
    assemble_validity(_state(out, data, []))
    assert not any((out / rel).exists() for rel in VALIDITY_REPORT)
