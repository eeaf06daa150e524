"""Third-party methods register through the ``grip_bench.methods`` entry-point group.

A small distribution is written to a temporary folder (a package plus its ``.dist-info``
with ``entry_points.txt``, what ``pip install`` leaves behind) and put on ``sys.path``; the
suite then finds its method, lists it, predicts with it from the command line, and puts
its code into the cache keys of its units.
"""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from grip_bench.methods import api

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
