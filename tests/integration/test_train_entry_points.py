"""``grip-bench train`` and ``grip-bench run`` write byte-identical checkpoints for one seed.

Both go through ``bench.stages.train.train_checkpoint`` (one torch thread, the same
training context), and checkpoints hold no wall times. The run's training stage is
executed for real (planned by ``runner.start``, run by ``execute.run_stage``) on the
tiniest SynthGRAB data; the CLI then trains the same methods on the run's dataset.
"""

from __future__ import annotations

import pytest

from grip_bench.bench import runner
from grip_bench.bench.execute import run_stage
from grip_bench.bench.plan import make_config
from grip_bench.bench.stages.data import make_dataset
from grip_bench.bench.stages.train import train_method
from grip_bench.cli.main import main

METHODS = ["grip", "manipnet"]


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    from grip_bench.data.synth.generate import generate

    root = tmp_path_factory.mktemp("tiny")
    generate(root / "data", profile="tiny", seed=0, workers=1, progress=False)
    return root / "data"


def test_train_and_run_write_the_same_checkpoint_bytes(tiny_data, tmp_path):
    cfg = make_config("smoke", data=tiny_data, out=tmp_path / "run", methods=METHODS,
                      workers=1, progress=False)
    st = runner.start(cfg)
    run_stage(st, "data", "dataset", make_dataset)
    run_stage(st, "train", "checkpoint", train_method)
    data_dir = st.data_dir(st.plan.data_key)
    for unit in st.plan.of("checkpoint"):
        name = unit.params["method"]
        from_run = st.unit_dir(unit.key) / st.info(unit.key)["info"]["file"]
        out = tmp_path / f"{name}.ckpt"
        assert main(["train", name, "--data", str(data_dir), "--out", str(out),
                     "--profile", "smoke", "--seed", str(cfg.seed), "--no-progress"]) == 0
        assert out.read_bytes() == from_run.read_bytes(), name
    assert {u.params["method"] for u in st.plan.of("checkpoint")} == set(METHODS)
