"""``grip-bench run --executor ray`` and ``[run] shard_sequences``.

The Ray tests start a local Ray cluster (``ray.cluster_utils.Cluster``: a head and a second
node on this machine, one CPU each, loopback only, torn down after) and run a tiny profile
on it from a separate driver process; they skip when Ray is not installed. The sharding
tests use the local executor. Data: the tiniest SynthGRAB set with a second object moved
into the test split, so the test split has two sequences to shard.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from grip_bench.bench.cache import Cache
from grip_bench.bench.codehash import CodeIndex
from grip_bench.bench.plan import SHARD_MODULE, STAGE_MODULES, build_plan, make_config, stage_code
from grip_bench.cli.main import main

REPO = Path(__file__).resolve().parents[2]
HAS_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(not HAS_RAY, reason='Ray is not installed (pip install ".[ray]")')

PROFILE = """
[run]
data = "synth"
synth_profile = "tiny"
data_seed = 0
dataset = ""
tables = {tables}
methods = {methods}
extra_methods = []
perturbations = {perturbations}
perturb_seed = 0
seed = 0
metrics = ["mpjpe", "mpvpe", "cc", "contact_ratio"]
per_frame = true
device = "cpu"
bootstrap_seed = 0
bootstrap_n = 200
runtime_sequences = 1
runtime_repeats = 1
physics_frames = 4
iv_frames = 0
figure_methods = ["mean-pose"]
validity_sequences = 0
viewer_sequences = {viewer}
seeds = []
capture_noise = "none"
"""
MERGED = ("results.csv", "frames.csv", "figures/heatmap_data.npz",
          "figures/penetration_depths.npz")


# --- fixtures --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """(root, data folder): tiny SynthGRAB with two test sequences (cubemedium, apple)."""
    from grip_bench.data.splits import write_splits
    from grip_bench.data.synth.generate import generate

    root = tmp_path_factory.mktemp("ray")
    generate(root / "data", profile="tiny", seed=0, workers=1, progress=False)
    write_splits(root / "data", {"train": ["cup"], "val": [], "test": ["cubemedium", "apple"]})
    return root, root / "data"


FULL = {"tables": ["table3_perturbation", "table4_grasp"],
        "methods": ["gt", "flat-input", "mean-pose", "perturbed-input"],
        "perturbations": ["T0.01"]}
SMALL = {"tables": ["table4_grasp"], "methods": ["gt", "flat-input"], "perturbations": []}


def _profile(root: Path, shard: int | None = None, viewer: int = 0, small: bool = False
             ) -> Path:
    """A profile file: the four cheap methods on the clean set and T0.01 (``small``: gt
    and flat-input on the clean set only)."""
    lists = {k: json.dumps(v) for k, v in (SMALL if small else FULL).items()}
    text = PROFILE.format(viewer=viewer, **lists)
    if shard is not None:
        text += f"shard_sequences = {shard}\n"
    path = root / f"p_{shard}_{viewer}_{int(small)}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _args(tiny, profile: Path, out: Path, *extra: str) -> list[str]:
    return ["run", "--profile", str(profile), "--data", str(tiny[1]), "--out", str(out),
            "--workers", "1", "--quiet", *extra]


@pytest.fixture(scope="module")
def local_out(tiny):
    """OUT of an unsharded local run (with a viewer page)."""
    out = tiny[0] / "local"
    assert main(_args(tiny, _profile(tiny[0], viewer=1), out)) == 0
    return out


def _units(out: Path) -> list[Path]:
    return sorted(p.parent for p in (out / "cache").glob("*/*/*/unit.json")
                  if not p.parts[-4].startswith("."))


# --- sharding (local executor) ---------------------------------------------------------------
def test_shard_sequences_zero_keeps_every_key(tiny):
    """``shard_sequences = 0`` plans exactly the units (and keys) of a profile without it."""
    root, data = tiny
    plans = [build_plan(make_config(str(_profile(root, shard)), data=data, out=root / "k",
                                    progress=False), Cache(root / "k" / "cache"))
             for shard in (None, 0)]
    assert [(u.label, u.key) for u in plans[0].units] == \
        [(u.label, u.key) for u in plans[1].units]
    assert not plans[1].deferred and plans[1].of("prediction")
    assert all("sequences" not in u.params for u in plans[1].units)
    # no stage module imports the shard code, so unsharded units' code digests (and keys)
    # do not change with it
    index = CodeIndex.installed()
    for module in STAGE_MODULES.values():
        assert SHARD_MODULE not in index.closure([f"grip_bench.bench.stages.{module}"])
    assert {u.params["inputs"]["code"] for u in plans[1].of("metrics")} == \
        {stage_code("metrics")}


def test_sharded_plan_waits_for_the_dataset_then_lists_its_sequences(tiny, tmp_path):
    root, data = tiny
    cfg = make_config(str(_profile(root, 1)), data=data, out=tmp_path, progress=False)
    cache = Cache(tmp_path / "cache")
    plan = build_plan(cfg, cache)
    assert plan.deferred and not plan.of("prediction") and not plan.of("metrics")
    assert "planned once the dataset unit exists" in plan.lines()[-1]
    from grip_bench.bench.execute import run_stage
    from grip_bench.bench.runner import replan, start
    from grip_bench.bench.stages.data import make_dataset
    from grip_bench.data.splits import sequences_in_split

    st = start(cfg)
    assert not replan(st)  # no dataset yet
    run_stage(st, "data", "dataset", make_dataset)
    assert replan(st) and not st.plan.deferred
    shards = [u.params["sequences"] for u in st.plan.of("prediction")
              if u.params["method"] == "gt"]
    test = sorted(p.relative_to(data).as_posix() for p in sequences_in_split(data, "test"))
    assert len(test) == 2 and shards == [[test[0]], [test[1]]]
    # 3 methods on the clean set + perturbed-input on T0.01, 2 shards each
    assert len(st.plan.of("prediction")) == len(st.plan.of("metrics")) == 8
    keys = {u.key for u in st.plan.units}
    assert len(keys) == len(st.plan.units)
    assert {u.params["inputs"]["code"] for u in st.plan.of("metrics")} == \
        {stage_code("metrics", SHARD_MODULE)}
    unsharded = build_plan(make_config(str(_profile(root, 0)), data=data, out=tmp_path,
                                       progress=False), cache)
    # everything but prediction and metrics is shared with the unsharded plan
    same = {u.key for u in unsharded.units if u.kind not in ("prediction", "metrics")}
    assert same <= keys and not ({u.key for u in unsharded.units} - same) & keys


@pytest.mark.parametrize("bad", ["-1", "1.5", "true"])
def test_shard_sequences_is_validated(tiny, tmp_path, bad, capsys):
    path = tmp_path / "bad.toml"
    text = PROFILE.format(viewer=0, **{k: json.dumps(v) for k, v in SMALL.items()})
    path.write_text(text + f"shard_sequences = {bad}\n", encoding="utf-8")
    assert main(["run", "--profile", str(path), "--data", str(tiny[1]), "--out",
                 str(tmp_path / "o"), "--dry-run"]) == 1
    assert "shard_sequences" in capsys.readouterr().err


@pytest.mark.slow
def test_sharded_run_merges_to_the_unsharded_results(tiny, local_out):
    """Per-sequence shards (2 per method and set) merge to byte-identical results, frames,
    contact statistics (figure data) and viewer pages."""
    out = tiny[0] / "sharded"
    assert main(_args(tiny, _profile(tiny[0], 1, viewer=1), out)) == 0
    for rel in (*MERGED, "viewer/index.json"):
        assert (out / rel).read_bytes() == (local_out / rel).read_bytes(), rel
    pages = sorted(p.name for p in (local_out / "viewer").glob("*.html"))
    assert pages and pages == sorted(p.name for p in (out / "viewer").glob("*.html"))
    kinds = [u.parts[-3] for u in _units(out)]
    assert kinds.count("prediction") == kinds.count("metrics") == 8  # 4 sets x 2 shards


# --- Ray -------------------------------------------------------------------------------------
def test_ray_executor_without_ray_is_a_one_line_error(tiny, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    assert main(_args(tiny, _profile(tiny[0]), tmp_path / "o", "--executor", "ray")) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'pip install "grip-bench[ray]"' in err
    assert not (tmp_path / "o" / "cache").exists() or not _units(tmp_path / "o")


def test_address_needs_the_ray_executor(tiny, tmp_path, capsys):
    assert main(_args(tiny, _profile(tiny[0]), tmp_path / "o", "--address", "auto")) == 1
    assert "--address" in capsys.readouterr().err


@pytest.mark.slow  # keeps the default run under 10 minutes; `pytest -m slow` runs it
@needs_ray
def test_ray_run_on_a_private_instance_matches_the_local_run(tiny):
    """Without --address the driver starts a private local Ray instance (one CPU here);
    gt and flat-input on the clean set give the local executor's bytes."""
    root = tiny[0]
    profile = _profile(root, small=True)
    assert main(_args(tiny, profile, root / "small_local")) == 0
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    cmd = [sys.executable, "-m", "grip_bench.cli.main",
           *_args(tiny, profile, root / "small_ray", "--executor", "ray")]
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for rel in MERGED:
        assert (root / "small_ray" / rel).read_bytes() == \
            (root / "small_local" / rel).read_bytes(), rel
    assert "submitted evaluate flat-input @ none" in \
        (root / "small_ray" / "run.log").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def cluster():
    """A local Ray cluster: the head and one more node, one CPU each (loopback)."""
    if not HAS_RAY:
        pytest.skip("Ray is not installed")
    from ray.cluster_utils import Cluster

    c = Cluster(initialize_head=True, head_node_args={
        "num_cpus": 1, "num_gpus": 0, "include_dashboard": False,
        "object_store_memory": 80 * 1024 * 1024})
    c.add_node(num_cpus=1, num_gpus=0, object_store_memory=80 * 1024 * 1024)
    c.wait_for_nodes()
    yield c.address
    c.shutdown()


def _ray_run(tiny, profile: Path, out: Path, address: str) -> subprocess.Popen:
    """The run's driver in its own process (as a user would start it), joining ``address``."""
    cmd = [sys.executable, "-m", "grip_bench.cli.main",
           *_args(tiny, profile, out, "--executor", "ray", "--address", address)]
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


@needs_ray
@pytest.mark.slow
def test_ray_run_matches_the_local_run(tiny, local_out, cluster):
    """The same units on a two-node Ray cluster: byte-identical results and figure data,
    every unit written by a worker, and a second run submits nothing."""
    out = tiny[0] / "ray"
    proc = _ray_run(tiny, _profile(tiny[0], viewer=1), out, cluster)
    log, _ = proc.communicate(timeout=900)
    assert proc.returncode == 0, log
    for rel in (*MERGED, "viewer/index.json"):
        assert (out / rel).read_bytes() == (local_out / rel).read_bytes(), rel
    assert sorted(u.name for u in _units(out)) == sorted(u.name for u in _units(local_out))
    run_log = (out / "run.log").read_text(encoding="utf-8")
    assert "submitted predict mean-pose @ none" in run_log
    assert "ray: " in run_log
    proc = _ray_run(tiny, _profile(tiny[0], viewer=1), out, cluster)
    log, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, log
    second = (out / "run.log").read_text(encoding="utf-8")[len(run_log):]
    assert "submitted" not in second and "ray: 0 unit(s)" in second


@needs_ray
@pytest.mark.slow
def test_killed_ray_run_resumes_to_identical_results(tiny, local_out, cluster):
    """Kill the driver (SIGKILL) once some units are in the cache; the rerun reuses them,
    leaves no temp folder behind and ends with the local run's results."""
    out = tiny[0] / "ray_killed"
    profile = _profile(tiny[0])
    proc = _ray_run(tiny, profile, out, cluster)
    deadline = time.monotonic() + 600
    while len(_units(out)) < 4 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    before = {u.name for u in _units(out)}
    assert before and not (out / "results.csv").exists()
    proc = _ray_run(tiny, profile, out, cluster)
    log, _ = proc.communicate(timeout=900)
    assert proc.returncode == 0, log
    assert before <= {u.name for u in _units(out)}
    for rel in MERGED:
        assert (out / rel).read_bytes() == (local_out / rel).read_bytes(), rel
    resumed = (out / "run.log").read_text(encoding="utf-8").split("grip-bench run:")[-1]
    assert f"{len(before)} cached" in resumed.splitlines()[0]
    deadline = time.monotonic() + 60  # workers of the killed driver are stopped by Ray
    while any((out / "cache" / ".tmp").iterdir()) and time.monotonic() < deadline:
        time.sleep(0.5)
        Cache(out / "cache")  # removes temp folders of dead writers
    assert not any((out / "cache" / ".tmp").iterdir())
    assert json.loads((out / "manifest.json").read_text("utf-8"))["config"]["executor"] == "ray"
