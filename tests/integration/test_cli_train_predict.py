"""``grip-bench train`` / ``predict`` end to end on a tiny dataset (smoke-sized GRIP)."""

import json

import numpy as np
import pytest
import torch

from grip_bench.cli.main import main
from grip_bench.data.grab_io import list_sequences, read_grab
from tests.grip_fixtures import write_grip_dataset


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_grip_dataset(tmp_path_factory.mktemp("clidata"), T=16)


@pytest.fixture(scope="module")
def profile(tmp_path_factory):
    from grip_bench.profiles import PROFILE_DIR

    text = (PROFILE_DIR / "smoke.toml").read_text()
    for key, value in (("epochs_cnet", 1), ("epochs_anet", 1), ("epochs_rnet", 1)):
        text = "\n".join(f"{key} = {value}" if line.startswith(f"{key} =") else line
                         for line in text.splitlines())
    path = tmp_path_factory.mktemp("profile") / "tiny.toml"
    path.write_text(text)
    return path


def test_train_then_predict(data, profile, tmp_path, capsys):
    ckpt = tmp_path / "grip.pt"
    assert (
        main(
            [
                "train",
                "grip",
                "--data",
                str(data),
                "--out",
                str(ckpt),
                "--profile",
                str(profile),
                "--no-progress",
            ]
        )
        == 0
    )
    assert ckpt.is_file()
    out = tmp_path / "pred"
    assert (
        main(
            [
                "predict",
                "--method",
                "grip-no-rnet",
                "--checkpoint",
                str(ckpt),
                "--input",
                str(data),
                "--split",
                "test",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    files = list_sequences(out)
    assert [f.relative_to(out) for f in files] == [f.relative_to(data) for f in list_sequences(data)
                                                  if read_grab(f).obj_name == "bowl"]
    pred = read_grab(files[0])
    assert np.isfinite(pred.rhand["hand_pose"]).all()
    assert (out / "splits.json").is_file() and (out / "tools").is_dir()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["method"] == "grip-no-rnet" and len(manifest["checkpoint_sha256"]) == 64
    # one file, online
    one = tmp_path / "one"
    assert (
        main(
            [
                "predict",
                "--method",
                "grip",
                "--checkpoint",
                str(ckpt),
                "--input",
                str(files[0]).replace(str(out), str(data)),
                "--out",
                str(one),
                "--online",
                "--no-anet",
            ]
        )
        == 0
    )
    assert len(list_sequences(one)) == 1
    # errors: one line, exit 1
    capsys.readouterr()
    assert (
        main(
            [
                "predict",
                "--method",
                "grip-future5",
                "--checkpoint",
                str(ckpt),
                "--input",
                str(data),
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 1
    )
    assert "trained for" in capsys.readouterr().err


def test_clear_errors(data, tmp_path, capsys):
    assert main(["train", "nope", "--data", str(data), "--out", str(tmp_path / "a.pt")]) == 1
    err = capsys.readouterr().err
    assert "unknown method 'nope'" in err and "grip-no-ambient" in err
    assert main(["predict", "--method", "grip", "--checkpoint", str(tmp_path / "missing.pt"),
                 "--input", str(data), "--out", str(tmp_path / "p")]) == 1
    assert "checkpoint file not found" in capsys.readouterr().err
    assert main(["train", "grip", "--data", str(data), "--out", str(tmp_path / "b.pt"),
                 "--profile", "huge"]) == 1
    assert "unknown profile" in capsys.readouterr().err
