"""``grip-bench data synth`` end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from grip_bench.cli.main import main
from grip_bench.data.grab_io import list_sequences, read_grab
from grip_bench.data.splits import read_splits
from grip_bench.geometry.meshes import load_object_mesh


def _check_dataset(out, n_min):
    files = list_sequences(out)
    assert len(files) >= n_min
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["generator"] == "SynthGRAB" and manifest["counts"]["sequences"] == len(files)
    assert manifest["quality"]["unsupported_object_moves"] == 0
    splits = read_splits(out)
    for f in files:
        seq = read_grab(f)
        mesh = load_object_mesh(out / seq.object_mesh)
        assert seq.contact["object"].shape[1] == len(mesh.vertices)
        assert any(seq.obj_name in v for v in splits.values())
    return files, manifest


def test_synth_tiny_end_to_end(tmp_path, capsys):
    out = tmp_path / "data"
    assert main(["data", "synth", "--out", str(out), "--profile", "tiny", "--workers", "1"]) == 0
    assert "right-hand contact frequency" in capsys.readouterr().out
    files, manifest = _check_dataset(out, 2)
    out2 = tmp_path / "again"
    assert (
        main(
            ["data", "synth", "--out", str(out2), "--profile", "tiny", "--workers", "2", "--quiet"]
        )
        == 0
    )
    for f in files:
        a, b = np.load(f, allow_pickle=True), np.load(out2 / f.relative_to(out), allow_pickle=True)
        pa, pb = a["body"].item()["params"], b["body"].item()["params"]
        assert all(pa[k].tobytes() == pb[k].tobytes() for k in pa)
        assert a["contact"].item()["object"].tobytes() == b["contact"].item()["object"].tobytes()


@pytest.mark.slow
def test_synth_smoke_profile(tmp_path):
    out = tmp_path / "smoke"
    assert main(["data", "synth", "--out", str(out), "--profile", "smoke", "--quiet"]) == 0
    _check_dataset(out, 15)


def test_synth_rejects_bad_workers(tmp_path, capsys):
    assert main(["data", "synth", "--out", str(tmp_path / "x"), "--workers", "0"]) == 1
