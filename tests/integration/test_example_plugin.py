"""The worked plug-in (``examples/grip-bench-example``) installed into a fresh environment.

A new virtual environment is layered on the current one (a ``.pth`` file adds this
environment's site-packages, so torch and grip-bench are not reinstalled), the example
is installed into it from a copy of its folder (``pip --no-deps --no-build-isolation
--no-index``: no network), and that environment's ``grip-bench`` lists, trains, predicts,
evaluates and runs the plug-in's method, metric and table. The current environment never
sees the plug-in. The plug-in metric's computation is also checked against a naive one.
"""

from __future__ import annotations

import csv
import importlib.metadata
import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "grip-bench-example"
TABLE = "example_wrist_follow"


def _console_script(venv: Path) -> Path:
    """``venv/bin/grip-bench``: grip-bench's own console entry point, written as pip does."""
    (ep,) = [e for e in importlib.metadata.entry_points(group="console_scripts")
             if e.name == "grip-bench"]
    module, _, func = ep.value.partition(":")
    script = venv / "bin" / "grip-bench"
    script.write_text(f"#!{venv / 'bin' / 'python'}\nimport sys\nfrom {module} import {func}\n"
                      f"if __name__ == '__main__':\n    sys.exit({func}())\n")
    script.chmod(0o755)
    return script


@pytest.fixture(scope="module")
def venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("plugin-env")
    env_dir = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env_dir)], check=True)
    (purelib,) = (env_dir / "lib").glob("python*/site-packages")
    # the current environment under the new one (what --system-site-packages does for a
    # base interpreter; the current interpreter may itself be a venv)
    lines = [f"import site; site.addsitedir({p!r})" for p in site.getsitepackages()]
    (purelib / "_grip_bench_parent.pth").write_text("\n".join(lines) + "\n")
    src = root / "src"  # a copy: building writes build/ and *.egg-info beside the sources
    shutil.copytree(EXAMPLE, src, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    subprocess.run([str(env_dir / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps",
                    "--no-build-isolation", "--no-index", "--disable-pip-version-check",
                    str(src)], check=True, cwd=root)
    _console_script(env_dir)
    return env_dir


def grip_bench(venv: Path, *args: object, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run([str(venv / "bin" / "grip-bench"), *map(str, args)], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=300)


def ok(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


@pytest.fixture(scope="module")
def data(venv: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Tiny SynthGRAB (3 sequences: train cup, val apple, test cubemedium)."""
    root = tmp_path_factory.mktemp("plugin-data")
    ok(grip_bench(venv, "data", "synth", "--profile", "tiny", "--out", root / "data",
                  "--quiet", cwd=root))
    return root / "data"


def _rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_the_plugin_is_only_in_the_new_environment(venv: Path, tmp_path: Path) -> None:
    from grip_bench.core.plugins import GROUPS, plugin_modules

    out = ok(grip_bench(venv, "ls", cwd=tmp_path))
    sections = dict(zip(("methods", "metrics", "tables"), _split_sections(out), strict=True))
    (method,) = [ln for ln in sections["methods"] if ln.split()[0] == "wrist-follow"]
    assert "train" in method and f"tables={TABLE}" in method
    assert any(ln.split()[0] == "mean-pose" and TABLE in ln for ln in sections["methods"])
    (metric,) = [ln for ln in sections["metrics"] if ln.split()[0] == "tip_dist"]
    assert metric.split()[1:4] == ["mm", "lower", "frames=held"]
    assert sections["metrics"][-1] == metric  # plug-ins after the suite's own metrics
    (table,) = [ln for ln in sections["tables"] if ln.split()[0] == TABLE]
    assert "3 rows x 2 columns" in table
    # this (the test's) environment has no plug-in installed
    assert not any(m.startswith("grip_bench_example") for g in GROUPS for m in plugin_modules(g))


def _split_sections(out: str) -> list[list[str]]:
    """``ls`` output -> the entry lines of its three sections, in order."""
    sections: list[list[str]] = []
    for line in out.splitlines():
        if line.startswith("  "):
            sections[-1].append(line.strip())
        else:
            sections.append([])
    return sections


@pytest.fixture(scope="module")
def trained(venv: Path, data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``train``, ``predict`` (test split) and ``evaluate`` through the new environment."""
    root = tmp_path_factory.mktemp("plugin-cli")
    ok(grip_bench(venv, "train", "wrist-follow", "--data", data, "--out", root / "wf.pt",
                  "--no-progress", cwd=root))
    ok(grip_bench(venv, "predict", "--method", "wrist-follow", "--checkpoint", root / "wf.pt",
                  "--input", data, "--split", "test", "--out", root / "pred", cwd=root))
    ok(grip_bench(venv, "evaluate", "--pred", root / "pred", "--gt", data, "--out",
                  root / "eval", "--metrics", "mpvpe,tip_dist", "--method", "wrist-follow",
                  "--no-progress", cwd=root))
    return root


@pytest.mark.slow  # 70 s of training, prediction and evaluation through the new environment
def test_train_predict_evaluate(trained: Path, data: Path) -> None:
    from grip_bench.data.grab_io import list_sequences, read_grab

    (pred_file,) = list_sequences(trained / "pred")
    pred = read_grab(pred_file)
    gt = read_grab(data / pred_file.relative_to(trained / "pred"))
    for side in ("right", "left"):  # the input wrists, learned fingers
        p, g = pred.hand_params(side), gt.hand_params(side)
        np.testing.assert_array_equal(p["transl"], g["transl"])
        np.testing.assert_array_equal(p["global_orient"], g["global_orient"])
    assert not np.allclose(pred.hand_params("right")["hand_pose"],
                           gt.hand_params("right")["hand_pose"])
    rows = _rows(trained / "eval" / "results.csv")
    assert {r["metric"] for r in rows} == {"mpvpe", "tip_dist"}
    (tip,) = [r for r in rows if r["metric"] == "tip_dist" and r["hand"] == "right"]
    assert tip["unit"] == "mm" and int(tip["n_frames"]) > 0 and 0 < float(tip["value"]) < 100


@pytest.mark.slow  # keeps the default run under 10 minutes; `pytest -m slow` runs it
def test_run(venv: Path, data: Path, trained: Path, tmp_path: Path) -> None:
    profile = tmp_path / "tiny.toml"
    profile.write_text(PROFILE, encoding="utf-8")
    out = tmp_path / "out"
    ok(grip_bench(venv, "run", "--profile", profile, "--data", data, "--out", out,
                  "--methods", "wrist-follow", "gt", "mean-pose", "--tables", TABLE,
                  "--quiet", cwd=tmp_path))
    rows = _rows(out / "results.csv")
    tips = {r["method"]: float(r["value"]) for r in rows
            if r["metric"] == "tip_dist" and r["hand"] == "right"}
    assert set(tips) == {"wrist-follow", "gt", "mean-pose"}
    assert all(np.isfinite(v) for v in tips.values())
    # same data, training and code: the value `grip-bench evaluate` measured
    (evaluated,) = [float(r["value"]) for r in _rows(trained / "eval" / "results.csv")
                    if r["metric"] == "tip_dist" and r["hand"] == "right"]
    assert tips["wrist-follow"] == pytest.approx(evaluated, rel=1e-9)
    table = (out / "tables" / f"{TABLE}.md").read_text(encoding="utf-8")
    for label in ("Mean pose", "Wrist-follow (plug-in)", "Ground truth"):
        (line,) = [ln for ln in table.splitlines() if ln.startswith(f"| {label} |")]
        assert "–" not in line, line  # every cell computed
    assert "Tip dist. (mm)" in table and "MPVPE (mm)" in table
    board = (out / "leaderboard.md").read_text(encoding="utf-8")
    assert "Fingertip-surface distance R-Hand (mm)" in board


PROFILE = """
[run]
data = "synth"
synth_profile = "tiny"
data_seed = 0
dataset = ""
tables = []
methods = []
extra_methods = []
perturbations = []
perturb_seed = 0
seed = 0
metrics = ["mpvpe", "tip_dist"]
per_frame = false
device = "cpu"
bootstrap_seed = 0
bootstrap_n = 200
runtime_sequences = 1
runtime_repeats = 1
physics_frames = 4
iv_frames = 0
figure_methods = []
validity_sequences = 0
"""


# --- the metric's computation against a naive one -------------------------------------------
@pytest.fixture(scope="module")
def tips_module():
    """``grip_bench_example.tips`` from the source folder (pure numpy: registers nothing)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "_example_tips", EXAMPLE / "grip_bench_example" / "tips.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _naive_distance(point: np.ndarray, mesh) -> float:
    """Unsigned distance of one point to a mesh: the closest point of every triangle."""
    import trimesh

    tri = mesh.triangles
    closest = trimesh.triangles.closest_point(tri, np.tile(point, (len(tri), 1)))
    return float(np.min(np.linalg.norm(closest - point, axis=1)))


def test_tip_distance_against_a_naive_reference(tips_module) -> None:
    import trimesh

    from grip_bench.geometry.distance import DistanceField

    box = trimesh.creation.box(extents=(0.08, 0.12, 0.2))  # metres, centred
    rng = np.random.default_rng(0)
    tips = rng.uniform(-0.09, 0.09, size=(4, 5, 3))  # inside, on and off the box
    got = tips_module.fingertip_surface_distance(tips, DistanceField(box).exact_signed_distance)
    naive = np.array([np.mean([_naive_distance(p, box) for p in frame]) for frame in tips])
    np.testing.assert_allclose(got, naive, atol=1e-9)
    # analytic: every tip 1 cm beyond a face, or 1 cm inside it (depth counts)
    out = np.tile([[0.05, 0.0, 0.0]], (1, 5, 1))
    inside = np.tile([[0.0, 0.0, 0.09]], (1, 5, 1))
    field = DistanceField(box).exact_signed_distance
    np.testing.assert_allclose(tips_module.fingertip_surface_distance(out, field), [0.01])
    np.testing.assert_allclose(tips_module.fingertip_surface_distance(inside, field), [0.01])
    with pytest.raises(ValueError, match="should be"):
        tips_module.fingertip_surface_distance(np.zeros((5, 3)), field)
