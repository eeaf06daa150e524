"""`grip-bench data info|perturb` and `grip-bench export`, including the error convention."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from grip_bench.cli.main import main
from grip_bench.data.grab_io import read_grab, write_grab
from tests.grab_fixtures import (
    FakeMano,
    make_sequence,
    real_grab_arrays,
    write_dataset,
    write_mano_models,
    write_npz,
    write_subject_templates,
)


def _procedural_hand():
    import torch

    try:
        from grip_bench.bodies import ProceduralHand
    except Exception:
        try:
            from grip_bench.bodies.hand import ProceduralHand
        except Exception:
            return None
    return None if ProceduralHand.forward is torch.nn.Module.forward else ProceduralHand


needs_hand = pytest.mark.skipif(
    _procedural_hand() is None,
    reason="grip_bench.bodies.ProceduralHand is not importable yet (written by another helper)")


def _snapshot(folder):
    return sorted((p.relative_to(folder).as_posix(), p.stat().st_size, p.stat().st_mtime_ns)
                  for p in folder.rglob("*"))


def _run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


# --- info -------------------------------------------------------------------------------
def test_info_on_a_sequence(tmp_path, capsys):
    path = write_grab(make_sequence(T=20), tmp_path / "grab" / "s1" / "mug_lift_1.npz")
    code, out, err = _run(capsys, "data", "info", path, "--json")
    assert code == 0 and err == ""
    info = json.loads(out)
    assert info["frames"] == 20 and info["fps"] == 30.0 and info["object"] == "mug"
    assert info["subject"] == "s1" and info["intent"] == "lift"
    assert info["duration_s"] == pytest.approx(20 / 30, abs=1e-3)
    assert info["contact_frames"] == {"any": 15, "right": 10, "left": 10}
    code, out, _ = _run(capsys, "data", "info", path)
    assert code == 0 and "mug" in out and "contact_frames" in out


def test_info_on_a_dataset(tmp_path, capsys):
    specs = [
        ("s1", "mug", "lift"),
        ("s1", "cup", "pass"),
        ("s2", "mug", "use"),
        ("s10", "ball", "lift"),
    ]
    write_dataset(tmp_path, specs, T=8, splits={"train": ["cup"], "val": ["ball"], "test": ["mug"]})
    code, out, err = _run(capsys, "data", "info", tmp_path, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["sequences"] == 4 and info["frames_30fps"] == 32
    assert info["splits"] == {"train": 1, "val": 1, "test": 2}
    assert info["objects"] == {"ball": 1, "cup": 1, "mug": 2}
    assert info["intents"] == {"lift": 2, "pass": 1, "use": 1}
    assert info["subjects"] == {"s1": 2, "s10": 1, "s2": 1}


def test_info_with_model_path_expands_pca(tmp_path, capsys):
    mano = FakeMano()
    write_mano_models(tmp_path / "models", mano)
    raw = real_grab_arrays(T=9)
    path = write_npz(tmp_path / "grab" / "s1" / "mug_lift.npz", raw)
    write_subject_templates(tmp_path, raw, mano)  # J0 of the subject's hands, for transl
    code, _, err = _run(capsys, "data", "info", path)
    assert code == 1 and "--model-path" in err
    code, out, err = _run(
        capsys, "data", "info", path, "--json", "--model-path", tmp_path / "models"
    )
    assert code == 0, err
    info = json.loads(out)
    assert info["frames"] == 3 and info["source_fps"] == 120.0 and info["body_model"] == "smplx"


# --- errors: one line, exit 1, nothing touched ---------------------------------------------
class _Evil:
    def __init__(self, target):
        self.target = target

    def __reduce__(self):
        return (os.system, (f"touch {self.target}",))


def _obj(value):
    a = np.empty((), dtype=object)
    a[()] = value
    return a


def _bad_files(tmp_path):
    """(file, key) pairs of malformed inputs, each in its own folder."""
    base = real_grab_arrays(T=8, n_comps=45, framerate=30.0)
    cases = {}

    def case(name, key, **changes):
        arrays = dict(base)
        for k, v in changes.items():
            if v is None:
                arrays.pop(k)
            else:
                arrays[k] = v
        cases[name] = (write_npz(tmp_path / name / f"{name}.npz", arrays), key)

    def with_param(part, key, value):
        entry = dict(base[part].item())
        entry["params"] = {**entry["params"], key: value}
        return _obj(entry)

    case("hostile", "object", object=_obj({"params": _Evil(tmp_path / "hostile" / "pwned")}))
    case("missing", "contact", contact=None)
    case(
        "shape",
        "rhand.params.transl",
        rhand=with_param("rhand", "transl", np.zeros((8, 2), np.float32)),
    )
    case("nan", "lhand.params.global_orient",
         lhand=with_param("lhand", "global_orient", np.full((8, 3), np.nan, np.float32)))
    case("frames", "object.params.global_orient",
         object=_obj({"params": {"global_orient": np.zeros((7, 3), np.float32),
                                 "transl": np.zeros((8, 3), np.float32)}}))
    trunc = write_grab(make_sequence(T=8), tmp_path / "truncated" / "truncated.npz")
    trunc.write_bytes(trunc.read_bytes()[:-200])
    cases["truncated"] = (trunc, None)
    return cases


def test_malformed_inputs_give_one_line_errors(tmp_path, capsys):
    for name, (path, key) in _bad_files(tmp_path).items():
        before = _snapshot(path.parent)
        code, out, err = _run(capsys, "data", "info", path, "--model-path", tmp_path / "nomodels")
        assert code == 1, name
        assert out == "" and err.count("\n") == 1 and err.startswith(f"error: {path}: "), (
            name,
            err,
        )
        if key is not None:
            assert err.startswith(f"error: {path}: {key}: "), (name, err)
        assert "Traceback" not in err
        assert _snapshot(path.parent) == before, name
    assert not (tmp_path / "hostile" / "pwned").exists()


def test_hostile_file_through_the_real_entry_point(tmp_path):
    path, _ = _bad_files(tmp_path)["hostile"]
    r = subprocess.run([sys.executable, "-m", "grip_bench", "data", "info", str(path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr.startswith(f"error: {path}: object: refused") and r.stderr.count("\n") == 1
    assert not (tmp_path / "hostile" / "pwned").exists()


def test_missing_path(tmp_path, capsys):
    code, _, err = _run(capsys, "data", "info", tmp_path / "nope.npz")
    assert code == 1 and err == f"error: {tmp_path / 'nope.npz'}: no such file or folder\n"


# --- perturb ----------------------------------------------------------------------------
def test_perturb_cli(tmp_path, capsys):
    src = tmp_path / "src"
    write_dataset(src, [("s1", "mug", "lift"), ("s1", "cup", "use")], T=6,
                  splits={"train": ["cup"], "val": [], "test": ["mug"]})
    out = tmp_path / "out"
    code, stdout, err = _run(capsys, "data", "perturb", src, "--out", out, "--kind", "arm",
                             "--sigma", "0.02,0.04", "--seed", "9")
    assert code == 0, err
    assert "1 ANet-arm sequences" in stdout
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sigma"] == [0.02, 0.04] and manifest["seed"] == 9
    assert read_grab(out / "grab/s1/mug_lift_1.npz").n_frames == 6
    # bad usage of the values: one-line error, output untouched
    before = _snapshot(tmp_path)
    code, _, err = _run(capsys, "data", "perturb", src, "--out", tmp_path / "o2", "--kind", "T")
    assert code == 1 and err.startswith("error: sigma: ") and err.count("\n") == 1
    code, _, err = _run(capsys, "data", "perturb", src, "--out", out, "--kind", "T", "--sigma", "x")
    assert code == 1 and err.startswith("error: --sigma: ")
    assert _snapshot(tmp_path) == before


# --- export -----------------------------------------------------------------------------
def test_export_rejects_bad_frames_without_touching_anything(tmp_path, capsys):
    write_dataset(tmp_path / "d", [("s1", "mug", "lift")], T=6)
    seq_path = tmp_path / "d" / "grab" / "s1" / "mug_lift_1.npz"
    before = _snapshot(tmp_path)
    for spec in ("9:12", "a:b", "3"):
        code, _, err = _run(capsys, "export", seq_path, "--out", tmp_path / "ply", "--frames", spec)
        assert code == 1 and err.startswith("error: --frames: ") and err.count("\n") == 1
    assert _snapshot(tmp_path) == before


def test_export_needs_a_model_for_smplx_sequences(tmp_path, capsys):
    root = tmp_path / "d"
    write_dataset(root, [("s1", "mug", "lift")], T=4)
    seq = make_sequence(T=4, body_model="smplx")
    path = write_grab(seq, root / "grab" / "s1" / "mug_use_1.npz")
    code, _, err = _run(capsys, "export", path, "--out", tmp_path / "ply")
    assert code == 1 and err.startswith(f"error: {path}: body_model: ") and "--model-path" in err
    assert not (tmp_path / "ply").exists()


@needs_hand
def test_export_writes_watertight_meshes(tmp_path, capsys):
    root = tmp_path / "d"
    write_dataset(root, [("s1", "mug", "lift")], T=6)
    path = root / "grab" / "s1" / "mug_lift_1.npz"
    out = tmp_path / "ply"
    code, stdout, err = _run(capsys, "export", path, "--out", out, "--frames", "2:4")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == [
        "00002_lhand.ply", "00002_object.ply", "00002_rhand.ply",
        "00003_lhand.ply", "00003_object.ply", "00003_rhand.ply"]
    seq = read_grab(path)
    box = trimesh.load(root / seq.object_mesh, process=False)
    obj = trimesh.load(out / "00003_object.ply", process=False)
    np.testing.assert_allclose(obj.vertices, seq.object_vertices(box.vertices)[3], atol=1e-6)
    for side, tag in (("right", "rhand"), ("left", "lhand")):
        hand = trimesh.load(out / f"00002_{tag}.ply", process=False)
        assert hand.is_watertight, tag
        # metres, world frame: the hand lies within a hand's length of its wrist position
        wrist = seq.hand_params(side)["transl"][2]
        assert np.linalg.norm(hand.vertices - wrist, axis=1).max() < 0.3
