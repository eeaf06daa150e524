"""`grip-bench run` and `grip-bench report`: layout of OUT, reuse, kill-and-resume, re-rendering.

A test-only profile (written below, passed by path) runs the fixed reference methods on
the tiniest SynthGRAB data (generated once per session and passed with --data), with the
cheap metrics only, so the whole module takes well under a minute of CPU.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from grip_bench.cli.main import main
from grip_bench.report.tables import TABLES

REPO = Path(__file__).resolve().parents[2]
METHODS = ["gt", "flat-input", "mean-pose", "perturbed-input"]
PERTURBATIONS = ["T0.01", "R0.3"]
METRICS = ["mpjpe", "mpvpe", "cc", "contact_ratio"]
FORMATS = ("md", "csv", "tex", "html")
KINDS = ("dataset", "perturbed", "prediction", "metrics", "runtime", "validity")
FIGURES = ("heatmap_data.npz", "penetration_depths.npz", "contact_heatmaps.png",
           "penetration_cdf.png", "per_object_mpvpe.png", "metric_validity.png")
# units of the tiny run: 1 dataset, 2 perturbed sets, 4 clean + 2 perturbed predictions
# (perturbed-input, Table 3's "before" row, has no clean run), as many metric sets, 4 runtime
# units, 1 metric-validity unit
N_UNITS = 1 + 2 + 5 + 5 + 4 + 1

PROFILE = f"""
[run]
data = "synth"
synth_profile = "tiny"
data_seed = 0
dataset = ""
tables = ["table3_perturbation", "table4_grasp", "runtime"]
methods = {json.dumps(METHODS)}
extra_methods = []
perturbations = {json.dumps(PERTURBATIONS)}
perturb_seed = 0
seed = 0
metrics = {json.dumps(METRICS)}
per_frame = true
device = "cpu"
bootstrap_seed = 0
bootstrap_n = 200
runtime_sequences = 1
runtime_repeats = 2
physics_frames = 4
iv_frames = 0
figure_methods = ["mean-pose"]
validity_sequences = 1
"""


# --- fixtures --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """(profile file, data folder): the test profile and the tiniest SynthGRAB data."""
    from grip_bench.data.synth.generate import generate

    root = tmp_path_factory.mktemp("run")
    profile = root / "tiny_run.toml"
    profile.write_text(PROFILE, encoding="utf-8")
    generate(root / "data", profile="tiny", seed=0, workers=1, progress=False)
    return profile, root / "data"


def _args(tiny, out, *extra) -> list[str]:
    profile, data = tiny
    return ["run", "--profile", str(profile), "--data", str(data), "--out", str(out),
            "--workers", "1", "--quiet", *extra]


@pytest.fixture(scope="module")
def finished(tiny, tmp_path_factory):
    """OUT of one uninterrupted run."""
    out = tmp_path_factory.mktemp("out") / "a"
    assert main(_args(tiny, out)) == 0
    return out


def _units(out: Path) -> list[Path]:
    """Finished units: cache/<kind>/<hh>/<key>/unit.json (temp folders are hidden)."""
    return sorted(p.parent for p in (out / "cache").glob("*/*/*/unit.json")
                  if not p.parts[-4].startswith("."))


def _snapshot(folder: Path) -> list[tuple]:
    return sorted((p.relative_to(folder).as_posix(), p.stat().st_mtime_ns)
                  for p in folder.rglob("*") if p.is_file())


def _csv(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


# --- layout ----------------------------------------------------------------------------------
def test_run_writes_the_documented_layout(finished):
    out = finished
    for name in ("results.csv", "frames.csv", "runtime.csv", "leaderboard.csv", "leaderboard.md",
                 "leaderboard.html", "manifest.json", "run.log"):
        assert (out / name).is_file(), name
    chosen = ("table3_perturbation", "table4_grasp", "runtime")  # PROFILE's tables
    for spec in TABLES:
        for fmt in FORMATS:  # the run's tables only: no table of "–" rows for the others
            assert (out / "tables" / f"{spec.id}.{fmt}").is_file() == (spec.id in chosen), \
                (spec.id, fmt)
    kinds = sorted({u.parts[-3] for u in _units(out)})
    assert kinds == sorted(KINDS)  # no checkpoint: the reference methods do not train
    assert len(_units(out)) == N_UNITS
    assert not any((out / "cache" / ".tmp").iterdir())
    for u in _units(out):  # each unit records its process's peak memory around its work
        rss = json.loads((u / "unit.json").read_text(encoding="utf-8"))["peak_rss_mib"]
        assert 0 < rss["before"] <= rss["after"]


def test_results_cover_methods_perturbations_and_metrics(finished):
    rows = _csv(finished / "results.csv")
    assert list(rows[0]) == ["method", "dataset", "split", "perturbation", "sequence", "object",
                             "hand", "metric", "value", "unit", "n_frames"]
    pairs = {(r["method"], r["perturbation"]) for r in rows}
    # perturbed-input runs only on the perturbed sets (on clean data it is gt again)
    assert pairs == {(m, "none") for m in METHODS if m != "perturbed-input"} | \
        {("perturbed-input", p) for p in PERTURBATIONS}
    assert {r["metric"] for r in rows} == set(METRICS)
    assert {r["dataset"] for r in rows} == {"synthgrab"}
    assert {r["split"] for r in rows} == {"test"}
    gt = [float(r["value"]) for r in rows if r["method"] == "gt" and r["metric"] == "mpvpe"]
    assert gt and all(v == 0.0 for v in gt)  # metric sanity row
    frames = _csv(finished / "frames.csv")
    assert "frame" in frames[0] and {r["method"] for r in frames} == set(METHODS)


def test_runtime_leaderboard_and_manifest(finished):
    runtime = _csv(finished / "runtime.csv")
    assert {r["method"] for r in runtime} == set(METHODS)
    assert {r["mode"] for r in runtime} == {"offline"}
    assert all(float(r["seconds_per_frame"]) > 0 for r in runtime)
    lb = _csv(finished / "leaderboard.csv")
    assert list(lb[0]) == ["method", "metric", "hand", "value", "ci_low", "ci_high", "unit",
                           "higher_is_better", "n_sequences"]
    assert {r["method"] for r in lb} == set(METHODS) - {"perturbed-input"}
    assert "<table" in (finished / "leaderboard.html").read_text(encoding="utf-8")
    man = json.loads((finished / "manifest.json").read_text(encoding="utf-8"))
    for key in ("versions", "git", "profile", "config", "seeds", "data_hash", "stage_times"):
        assert key in man, key
    assert set(man["stage_times"]) >= {"data", "perturb", "train", "predict", "evaluate",
                                       "runtime", "report", "total"}
    assert man["config"]["methods"] == METHODS
    assert man["config"]["report"]["bootstrap_n"] == 200
    assert len(man["data_hash"]) == 64


# --- reuse -----------------------------------------------------------------------------------
@pytest.mark.slow  # keeps the default run under 10 minutes; `pytest -m slow` runs it
def test_parallel_workers_give_the_same_results(finished, tiny, tmp_path):
    """Predictions in 2 worker processes: the same bytes as the one-process run."""
    out = tmp_path / "w2"
    args = [a if a != "1" else "2" for a in _args(tiny, out)]  # --workers 2
    assert main(args) == 0
    assert (out / "results.csv").read_bytes() == (finished / "results.csv").read_bytes()
    assert (out / "frames.csv").read_bytes() == (finished / "frames.csv").read_bytes()
    assert not any((out / "cache" / ".tmp").iterdir())


def test_second_run_reuses_everything(finished, tiny, capsys):
    before = _snapshot(finished / "cache")
    results = (finished / "results.csv").read_bytes()
    assert main(_args(tiny, finished)) == 0
    out = capsys.readouterr().out
    assert f"reused {N_UNITS} of {N_UNITS} units" in out
    assert _snapshot(finished / "cache") == before  # nothing recomputed or rewritten
    assert (finished / "results.csv").read_bytes() == results


def test_dry_run_lists_the_plan(finished, tiny, capsys):
    assert main(_args(tiny, finished, "--dry-run")) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == N_UNITS and all(line.startswith("[cached]") for line in lines)
    assert any("predict perturbed-input @ R0.3" in line for line in lines)


def test_grip_variants_train_after_the_first(tmp_path):
    """The first GRIP checkpoint builds the shared features; the others wait for it."""
    from grip_bench.bench.cache import Cache
    from grip_bench.bench.plan import build_plan, make_config

    cfg = make_config("smoke", out=tmp_path)
    ckpts = build_plan(cfg, Cache(tmp_path / "cache")).of("checkpoint")
    grip = [u for u in ckpts if u.params["method"].startswith("grip")]
    others = [u for u in ckpts if not u.params["method"].startswith("grip")]
    assert len(grip) >= 2 and grip[0].params["after"] is None
    assert all(u.params["after"] == grip[0].key for u in grip[1:])
    assert others and all(u.params["after"] is None for u in others)


def test_slowest_predictions_start_first(tmp_path):
    from grip_bench.bench.cache import Cache
    from grip_bench.bench.execute import _predict_cost
    from grip_bench.bench.plan import build_plan, make_config
    from grip_bench.methods.api import METHODS

    cfg = make_config("smoke", out=tmp_path)
    preds = build_plan(cfg, Cache(tmp_path / "cache")).of("prediction")
    order = sorted(preds, key=lambda u: -_predict_cost(u, METHODS))
    assert {u.params["method"] for u in order[:5]} == {"toch"}  # its 5 sets, the costliest
    costs = [_predict_cost(u, METHODS) for u in order]
    assert costs == sorted(costs, reverse=True) and costs[-1] < costs[0]
    rank = {u.key: i for i, u in enumerate(preds)}
    for a, b in zip(order, order[1:], strict=False):  # equal costs keep the plan order
        if _predict_cost(a, METHODS) == _predict_cost(b, METHODS):
            assert rank[a.key] < rank[b.key]


# --- report ----------------------------------------------------------------------------------
def _report_files(out: Path) -> dict[str, bytes]:
    files = [*(out / "tables").glob("*"), *out.glob("leaderboard.*")]
    if (out / "figures").is_dir():
        files += [p for p in (out / "figures").rglob("*") if p.is_file()]
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in files}


def test_report_rerenders_the_same_bytes(finished, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(finished, copy, ignore=shutil.ignore_patterns("cache"))
    expected = _report_files(finished)
    assert {f"figures/{name}" for name in FIGURES} <= set(expected)
    shutil.rmtree(copy / "tables")
    for p in [*copy.glob("leaderboard.*"), *(copy / "figures").glob("*.png")]:
        p.unlink()
    assert main(["report", str(copy)]) == 0  # without the cache: nothing is recomputed
    assert _report_files(copy) == expected
    assert "Averaging: per sequence" in (copy / "tables" / "table4_grasp.md").read_text()
    assert (finished / "validity.json").is_file()  # the runner's validity unit ran
    assert "verdict" in (copy / "tables" / "metric_validity.md").read_text()
    assert main(["report", str(copy), "--averaging", "pooled"]) == 0
    pooled = (copy / "tables" / "table4_grasp.md").read_text()
    assert "Averaging: pooled over frames" in pooled
    assert "Averaging: pooled over frames" in (copy / "leaderboard.md").read_text()


def test_figures_are_drawn_from_saved_figure_data(finished):
    import numpy as np

    from grip_bench.report.figures import read_heatmap_data
    from grip_bench.report.write import read_depth_data

    figs = finished / "figures"
    assert sorted(p.name for p in figs.iterdir()) == sorted(FIGURES)  # no iv: not computed
    for name in FIGURES:
        assert (figs / name).stat().st_size > 0, name
    stats = sorted((finished / "cache" / "metrics").glob("*/*/contact_stats.npz"))
    assert len(stats) == 5  # every metric unit saves its figure data
    heat = read_heatmap_data(figs / "heatmap_data.npz")
    assert list(heat) == ["gt", "mean-pose"]  # gt + [run] figure_methods
    for per_side in heat.values():
        assert set(per_side) == {"right", "left"}
        for freq in per_side.values():
            fin = freq[np.isfinite(freq)]  # all NaN for a hand that never grasps
            assert ((fin >= 0) & (fin <= 1)).all()
    assert np.nanmax(np.concatenate(list(heat["gt"].values()))) > 0  # GT hands touch objects
    depths = read_depth_data(figs / "penetration_depths.npz")
    assert list(depths) == ["gt", "mean-pose"] and all(d.size for d in depths.values())
    html = (finished / "leaderboard.html").read_text(encoding="utf-8")
    assert html.count("data:image/png;base64,") == sum(n.endswith(".png") for n in FIGURES)


def test_report_needs_results(tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 1
    assert "results.csv" in capsys.readouterr().err


# --- interrupted runs ------------------------------------------------------------------------
def _start(tiny, out: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "grip_bench", *_args(tiny, out)], cwd=REPO,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _stop_after(proc: subprocess.Popen, out: Path, n_units: int, sig: int) -> int:
    """Send ``sig`` once ``n_units`` units are finished; the process's exit code."""
    while len(_units(out)) < n_units and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be interrupted"
    proc.send_signal(sig)
    proc.communicate(timeout=120)
    return proc.returncode


def test_killed_run_resumes_to_identical_results(finished, tiny, tmp_path, capsys):
    # the kills land in the predictions and only the results are compared, so the validity
    # report and the viewer pages (half of a resumed tiny run's time) are switched off; the
    # results must be the same bytes as the full profile's
    light = tmp_path / "light_run.toml"
    light.write_text(PROFILE.replace("validity_sequences = 1", "validity_sequences = 0")
                     + "viewer_sequences = 0\n", encoding="utf-8")
    tiny = (light, tiny[1])
    out = tmp_path / "b"
    # SIGTERM: a clean stop (exit 130) that leaves no unfinished unit behind
    assert _stop_after(_start(tiny, out), out, 2, signal.SIGTERM) == 130
    assert not any((out / "cache" / ".tmp").iterdir()), list((out / "cache" / ".tmp").iterdir())
    # SIGKILL in the middle of the predictions: no cleanup at all
    done = len(_units(out))
    assert _stop_after(_start(tiny, out), out, done + 5, signal.SIGKILL) == -signal.SIGKILL
    assert not (out / "results.csv").exists()
    assert main(_args(tiny, out)) == 0
    assert "reused" in capsys.readouterr().out
    assert (out / "results.csv").read_bytes() == (finished / "results.csv").read_bytes()
    assert (out / "frames.csv").read_bytes() == (finished / "frames.csv").read_bytes()
    assert not any((out / "cache" / ".tmp").iterdir())  # the killed writer's folder is gone


# A run that stops at a chosen point and waits there to be killed: inside the second metrics
# unit (its files written, the unit not yet renamed into place) or inside report writing
# (after the report's third atomic rename). The marker file says it got there.
_PAUSING_RUN = """
import os, sys, time
from grip_bench.bench import runner
from grip_bench.cli.main import main

where, marker = sys.argv[1], sys.argv[2]


def pause():
    with open(marker, "w") as f:
        f.write(str(os.getpid()))
    time.sleep(600)


if where == "evaluate":
    stages = list(runner.STAGE_FUNCTIONS)
    i = [kind for _, kind, _ in stages].index("metrics")
    name, kind, fn = stages[i]
    done = []

    def paused(st, unit, tmp):
        info = fn(st, unit, tmp)
        done.append(unit.key)
        if len(done) == 2:
            pause()
        return info

    stages[i] = (name, kind, paused)
    runner.STAGE_FUNCTIONS = tuple(stages)
else:
    real_replace, write_report, renames = os.replace, runner.write_report, []

    def replace(src, dst):
        real_replace(src, dst)
        renames.append(dst)
        if len(renames) == 3:
            pause()

    def paused_report(*args, **kwargs):
        os.replace = replace
        return write_report(*args, **kwargs)

    runner.write_report = paused_report
sys.exit(main(sys.argv[3:]))
"""


def _kill_at(tiny, out: Path, where: str, tmp_path: Path) -> None:
    """Run until the pause point ``where``, then SIGKILL (no cleanup at all)."""
    marker = tmp_path / f"paused-{where}"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", _PAUSING_RUN, where, str(marker),
                             *_args(tiny, out)], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    while not marker.exists() and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()[1].decode()[-2000:]
    proc.kill()
    proc.communicate(timeout=120)


def _shows_runtime(rel: str) -> bool:
    """Report files showing wall times, which each run's runtime units measure afresh."""
    return rel.startswith("tables/runtime.")


@pytest.mark.slow
def test_run_killed_in_evaluation_and_in_report_resumes_identically(finished, tiny, tmp_path,
                                                                     capsys):
    """SIGKILL inside a metrics unit, then (resumed) inside report writing: the next run
    gives byte-identical results, tables, leaderboards and figures."""
    out = tmp_path / "k"
    _kill_at(tiny, out, "evaluate", tmp_path)
    kinds = {u.parts[-3] for u in _units(out)}
    assert "metrics" in kinds and "runtime" not in kinds  # it died in the evaluation stage
    assert not (out / "results.csv").exists()
    _kill_at(tiny, out, "report", tmp_path)
    assert len(_units(out)) == N_UNITS and not (out / "manifest.json").exists()
    assert main(_args(tiny, out)) == 0
    assert f"reused {N_UNITS} of {N_UNITS} units" in capsys.readouterr().out
    for name in ("results.csv", "frames.csv", "validity.csv"):
        assert (out / name).read_bytes() == (finished / name).read_bytes(), name
    assert _report_files(out).keys() == _report_files(finished).keys()
    differ = [k for k, v in _report_files(out).items() if v != _report_files(finished)[k]
              and not _shows_runtime(k)]
    assert not differ, differ
    assert not any((out / "cache" / ".tmp").iterdir())
    assert not list(out.rglob(".*.tmp"))  # no half-written report file survived


# --- errors ----------------------------------------------------------------------------------
def test_paper_profile_needs_data(tmp_path, capsys):
    assert main(["run", "--profile", "paper", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: --data:") and "GRAB" in err


def test_unknown_method_and_table_are_input_errors(tiny, tmp_path, capsys):
    assert main(_args(tiny, tmp_path, "--methods", "no-such-method", "--dry-run")) == 1
    assert "unknown method 'no-such-method'" in capsys.readouterr().err
    assert main(_args(tiny, tmp_path, "--tables", "table9", "--dry-run")) == 1
    assert "unknown table 'table9'" in capsys.readouterr().err


def test_unknown_profile_is_an_input_error(tmp_path, capsys):
    assert main(["run", "--profile", "nope", "--out", str(tmp_path)]) == 1
    assert "profile" in capsys.readouterr().err


# --- the smoke profile -----------------------------------------------------------------------
# 246 s idle (2 cores): the default suite was 12 min with it; the tiny-profile run tests above
# keep a whole run (plan, units, report, resume) in the default suite
@pytest.mark.slow
def test_smoke_profile_end_to_end(tmp_path, capsys):
    """The real thing at smoke size: SynthGRAB generation, GRIP training, every table.

    About 4 minutes on 2 cores from a cold geometry cache; part of the default run because
    it is the only test that trains every method on generated data end to end.
    """
    from grip_bench.methods.api import load_all

    out = tmp_path / "smoke"
    assert main(["run", "--profile", "smoke", "--out", str(out), "--quiet"]) == 0
    assert "cache: reused 0 of" in capsys.readouterr().out
    for spec in TABLES:
        for fmt in FORMATS:
            assert (out / "tables" / f"{spec.id}.{fmt}").is_file()
    rows = _csv(out / "results.csv")
    methods = {r["method"] for r in rows}
    registered = set(load_all().names())
    assert {"gt", "grip", "grip-no-rnet"} <= methods <= registered
    assert {r["perturbation"] for r in rows if r["method"] == "grip"} == \
        {"none", "T0.01", "T0.02", "R0.3", "R0.5"}
    assert {"checkpoint", "dataset", "metrics", "perturbed", "prediction", "runtime"} == \
        {u.parts[-3] for u in _units(out)}
    runtime = _csv(out / "runtime.csv")
    assert {"offline", "online"} == {r["mode"] for r in runtime if r["method"] == "grip"}
    man = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    assert man["config"]["profile_name"] == "smoke" and man["profile"]["grip"]["hidden"] > 0
    for name in ("contact_heatmaps", "penetration_cdf", "per_object_mpvpe", "per_object_iv"):
        assert (out / "figures" / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    board = _csv(out / "leaderboard.csv")
    from grip_bench.methods.api import variants

    assert {r["method"] for r in board} == {r["method"] for r in rows
                                            if r["perturbation"] == "none"} - variants()
    on_board = {r["method"] for r in board}
    assert "grip" in on_board
    assert "grip-no-ambient" in methods and "grip-no-ambient" not in on_board  # Table 2 only
    assert "perturbed-input" not in {r["method"] for r in board}  # gt again on clean data
    # single-hand models have no left-hand rows: that hand is their input, not a prediction
    assert {r["hand"] for r in board if r["method"] == "grabnet"} == {"right"}
    assert "| grip |" in (out / "leaderboard.md").read_text(encoding="utf-8")
