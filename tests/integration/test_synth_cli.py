"""``grip-bench data synth`` end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from grip_bench.cli.data import dataset_info
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
    # same seed -> same bytes, whatever the worker count (the manifest's timing and worker
    # count aside)
    written = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert written == sorted(p.relative_to(out2) for p in out2.rglob("*") if p.is_file())
    for rel in written:
        if rel.name != "manifest.json":
            assert (out / rel).read_bytes() == (out2 / rel).read_bytes(), rel
    m2 = json.loads((out2 / "manifest.json").read_text())
    drop = ("wall_time_s", "workers")
    assert {k: v for k, v in manifest.items() if k not in drop} == \
        {k: v for k, v in m2.items() if k not in drop}
    # every grasping hand's type is in the manifest, and `data info` counts them per family
    assert manifest["version"] == "2.5" and set(manifest["sequences"]) == {
        f.relative_to(out).as_posix() for f in files}
    info = dataset_info(out)
    # (a regrasping hand's first grasp counts too)
    hands = sum(len(e["grasps"]) + len(e.get("regrasp", {}))
                for e in manifest["sequences"].values())
    assert sum(sum(c.values()) for c in info["grasp_types"].values()) == hands
    assert info["grasp_types"] == manifest["counts"]["grasp_types"]
    for shape in manifest["objects"].values():
        assert len(shape["stretch"]) == 3 and any(abs(x - 1) > 1e-3 for x in shape["stretch"])


@pytest.mark.slow
def test_synth_smoke_profile(tmp_path):
    out = tmp_path / "smoke"
    assert main(["data", "synth", "--out", str(out), "--profile", "smoke", "--quiet"]) == 0
    _check_dataset(out, 15)


def test_synth_rejects_bad_workers(tmp_path, capsys):
    assert main(["data", "synth", "--out", str(tmp_path / "x"), "--workers", "0"]) == 1
