"""Third-party methods, metrics and tables register through the ``grip_bench.methods``,
``grip_bench.metrics`` and ``grip_bench.tables`` entry-point groups.

A small distribution is written to a temporary folder (a package plus its ``.dist-info``
with ``entry_points.txt``, what ``pip install`` leaves behind) and put on ``sys.path``; the
suite then finds its method, lists it, predicts with it from the command line, and puts
its code into the cache keys of its units.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from grip_bench.methods import api

REPO = Path(__file__).resolve().parents[2]

PLUGIN = '''
"""A third-party method: the input's wrists with every finger bent by 0.1 rad."""

from pathlib import Path

import numpy as np

from grip_bench.core.checkpoint import save_checkpoint
from grip_bench.methods.api import MethodSpec, PredictContext, TrainContext, register_method


class BentFingers:
    def __init__(self, name: str) -> None:
        self.name = name

    def train(self, data_dir: Path, out: Path, ctx: TrainContext) -> Path:
        return save_checkpoint(out, model_state={}, configs={}, meta={"method": self.name})

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        pass

    def predict(self, seq, ctx: PredictContext):
        bent = np.full((seq.n_frames, 45), 0.1)
        return seq.with_hands(right={"hand_pose": bent}, left={"hand_pose": bent})


register_method(MethodSpec(name="plugin-bent", description="bent fingers (a plug-in)",
                           factory=BentFingers, needs=("wrists",), trainable=False))
'''


@pytest.fixture
def plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    site = tmp_path / "site"
    (site / "bentplug").mkdir(parents=True)
    (site / "bentplug" / "__init__.py").write_text('"""bentplug."""\n')
    (site / "bentplug" / "method.py").write_text(PLUGIN)
    info = site / "bentplug-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: bentplug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent("""\
        [grip_bench.methods]
        plugin-bent = bentplug.method
        """))
    monkeypatch.syspath_prepend(str(site))
    # the registry and the module cache are global: each test gets its own, restored after
    monkeypatch.setattr(api.METHODS, "_items", dict(api.METHODS._items))
    for name in [m for m in sys.modules if m.split(".")[0] == "bentplug"]:
        monkeypatch.delitem(sys.modules, name)
    yield site
    for name in [m for m in sys.modules if m.split(".")[0] == "bentplug"]:
        del sys.modules[name]


def test_an_installed_plugin_is_listed_and_predicts(plugin: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    from grip_bench.cli.main import main
    from grip_bench.data.grab_io import list_sequences, read_grab
    from tests.grab_fixtures import write_dataset

    assert "bentplug.method" in api.plugin_modules()
    assert "plugin-bent" in api.load_all()
    assert main(["ls", "methods"]) == 0
    assert "plugin-bent" in capsys.readouterr().out
    data = tmp_path / "data"
    write_dataset(data, [("s1", "mug", "lift")], T=6)
    assert main(["predict", "--method", "plugin-bent", "--input", str(data),
                 "--out", str(tmp_path / "pred")]) == 0
    (pred,) = list_sequences(tmp_path / "pred")
    np.testing.assert_allclose(read_grab(pred).hand_params("right")["hand_pose"], 0.1)


def test_a_plugins_code_is_in_its_units_keys(plugin: Path) -> None:
    from grip_bench.bench.codehash import CodeIndex, installed_roots

    api.load_all()
    roots = installed_roots()
    assert roots["bentplug"] == plugin / "bentplug"
    index = CodeIndex(roots)
    closure = index.closure(["bentplug.method"])
    assert {"bentplug", "bentplug.method", "grip_bench.methods.api"} <= set(closure)
    before = index.digest(["bentplug.method"])
    (plugin / "bentplug" / "method.py").write_text(PLUGIN + "\nEDITED = True\n")
    assert CodeIndex(roots).digest(["bentplug.method"]) != before


def test_a_broken_plugin_is_a_clear_error(plugin: Path) -> None:
    from grip_bench.core.errors import InputError

    (plugin / "bentplug" / "method.py").write_text("raise RuntimeError('no luck')\n")
    with pytest.raises(InputError, match="bentplug.method.*no luck"):
        api.load_all()


# --- metric and table plug-ins ---------------------------------------------------------------
METRIC_PLUGIN = '''
"""A third-party metric: the wrist height, on every frame."""

import numpy as np

from grip_bench.metrics.evaluate import Measured
from grip_bench.metrics.registry import metric


@metric("wrist_y", "Wrist height", "mm", 1e3, True, "all", 1, "the wrist's y (a plug-in)")
def m_wrist_y(pair, side):
    y = np.asarray(pair.pred.hand_params(side)["transl"])[:, 1]
    return Measured(np.arange(len(y)), y)
'''

TABLE_PLUGIN = '''
id = "plug_table"
version = 1
title = "A plug-in table"
description = "wrist height of gt"
[defaults]
split = "test"
perturbation = "none"
hand = "right"
[[rows]]
label = "GT"
method = "gt"
[[columns]]
metric = "wrist_y"
'''


def _distribution(site: Path, name: str, files: dict[str, str], entry_points: str) -> None:
    """``site/<files>`` plus ``site/<name>-0.1.dist-info`` declaring ``entry_points``."""
    for rel, text in files.items():
        (site / rel).parent.mkdir(parents=True, exist_ok=True)
        (site / rel).write_text(text)
    info = site / f"{name}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entry_points))


@pytest.fixture
def metric_site(tmp_path: Path) -> Path:
    site = tmp_path / "msite"
    _distribution(site, "tipplug", {"tipplug/__init__.py": '"""tipplug."""\n',
                                    "tipplug/metric.py": METRIC_PLUGIN,
                                    "tipplug/tables/__init__.py": '"""tables."""\n',
                                    "tipplug/tables/plug_table.toml": TABLE_PLUGIN},
                  """\
                  [grip_bench.metrics]
                  wrist_y = tipplug.metric
                  [grip_bench.tables]
                  plug = tipplug.tables
                  """)
    return site


def _cli(site: Path, *args: str) -> subprocess.CompletedProcess:
    """``python -m grip_bench ARGS`` in a fresh process that sees ``site``."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)])}
    return subprocess.run([sys.executable, "-m", "grip_bench", *args], env=env, cwd=site,
                          capture_output=True, text=True, timeout=120)


def test_metric_and_table_plugins_are_listed(metric_site: Path) -> None:
    proc = _cli(metric_site, "ls")
    assert proc.returncode == 0, proc.stderr
    assert "wrist_y              mm    higher frames=all " in proc.stdout
    assert "plug_table           v1  1 rows x 1 columns  A plug-in table" in proc.stdout
    assert re.search(r"\n  gt .*tables=.*plug_table", proc.stdout)


@pytest.mark.parametrize(("change", "fragments"), [
    pytest.param({"tipplug/metric.py": "raise RuntimeError('no metric today')\n"},
                 ("entry points grip_bench.metrics", "'tipplug.metric' failed to import",
                  "RuntimeError: no metric today"), id="metric-raises"),
    pytest.param({"tipplug/tables/plug_table.toml": "id = [\n"},
                 ("plug_table.toml", "plug-in table of 'tipplug.tables'", "not valid TOML"),
                 id="table-not-toml"),
    pytest.param({"tipplug/tables/plug_table.toml": TABLE_PLUGIN.replace("plug_table",
                                                                         "table4_grasp")},
                 ("plug_table.toml", "must match the file name"), id="table-id"),
    pytest.param({"tipplug/tables/__init__.py": "import nowhere_to_be_found\n"},
                 ("entry points grip_bench.tables", "'tipplug.tables' failed to import",
                  "nowhere_to_be_found"), id="table-package-raises"),
])
def test_a_broken_metric_or_table_plugin_is_one_line(metric_site: Path, change: dict,
                                                     fragments: tuple) -> None:
    for rel, text in change.items():
        (metric_site / rel).write_text(text)
    proc = _cli(metric_site, "ls")
    assert proc.returncode == 1
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("error: ")
    for fragment in fragments:
        assert fragment in line, line


def test_a_duplicate_plugin_table_id_is_refused(metric_site: Path) -> None:
    copy = TABLE_PLUGIN.replace('id = "plug_table"', 'id = "table4_grasp"')
    (metric_site / "tipplug/tables/plug_table.toml").unlink()
    (metric_site / "tipplug/tables/table4_grasp.toml").write_text(copy)
    proc = _cli(metric_site, "ls", "tables")
    assert proc.returncode == 1
    assert "table id 'table4_grasp' is already defined by" in proc.stderr


def test_a_metric_plugins_code_is_in_the_metric_units_keys(
        metric_site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from grip_bench.bench import plan
    from grip_bench.bench.codehash import CodeIndex, installed_roots

    without = {k: plan.stage_code(k) for k in ("metrics", "validity", "prediction")}
    monkeypatch.syspath_prepend(str(metric_site))
    # a fresh index per call (the installed one is built once per process)
    monkeypatch.setattr(CodeIndex, "installed", classmethod(lambda cls: cls(installed_roots())))
    assert installed_roots()["tipplug"] == metric_site / "tipplug"
    first = {k: plan.stage_code(k) for k in without}
    (metric_site / "tipplug/metric.py").write_text(METRIC_PLUGIN + "\nEDITED = 1\n")
    second = {k: plan.stage_code(k) for k in without}
    for kind in ("metrics", "validity"):  # units that compute metrics: renewed twice
        assert len({without[kind], first[kind], second[kind]}) == 3
    assert without["prediction"] == first["prediction"] == second["prediction"]


def test_a_table_entry_point_may_name_paths(metric_site: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    from grip_bench.core.errors import InputError
    from grip_bench.report.tables import load_table, plugin_table_files

    toml = metric_site / "tipplug" / "tables" / "plug_table.toml"
    (metric_site / "tipplug" / "paths.py").write_text(
        f"PATHS = [{str(toml)!r}]\n\ndef listed():\n    return PATHS\n\nMISSING = ['/nope.toml']\n")
    monkeypatch.syspath_prepend(str(metric_site))
    for name in [m for m in sys.modules if m.split(".")[0] == "tipplug"]:
        monkeypatch.delitem(sys.modules, name)
    assert plugin_table_files("tipplug.tables") == [toml]  # a package: its *.toml resources
    assert plugin_table_files("tipplug.paths:PATHS") == [toml]  # an iterable of paths
    assert plugin_table_files("tipplug.paths:listed") == [toml]  # or a callable returning one
    assert load_table(toml).id == "plug_table"
    for value, fragment in (("tipplug.paths", "names a module, not a package"),
                            ("tipplug.paths:nothing", "has no attribute 'nothing'"),
                            ("tipplug.paths:MISSING", "table file(s) not found: /nope.toml")):
        with pytest.raises(InputError, match=re.escape(fragment)) as e:
            plugin_table_files(value)
        assert e.value.where == f"entry points grip_bench.tables: {value}"
    for name in [m for m in sys.modules if m.split(".")[0] == "tipplug"]:
        del sys.modules[name]
