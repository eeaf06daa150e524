"""Hostile object meshes through ``grip-bench predict``: one ``error: <file>: <what>``, exit 1."""

import struct

import numpy as np
import pytest
import trimesh

from grip_bench.cli.main import main
from grip_bench.core import constants
from grip_bench.data.grab_io import object_mesh_path
from tests.grab_fixtures import write_dataset


@pytest.fixture
def data(tmp_path):
    root = tmp_path / "data"
    write_dataset(root, [("s1", "box", "lift")], T=8)
    return root


def _predict(data, tmp_path, capsys, *extra):
    code = main(["predict", "--method", "gt", "--input", str(data), "--out",
                 str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    return code, [ln for ln in err if ln.startswith("error:")]


def _obj(path, verts, faces):
    """An ASCII PLY of exactly these vertices and faces (no validation on the way)."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(verts)}", "property float x",
             "property float y", "property float z", f"element face {len(faces)}",
             "property list uchar int vertex_indices", "end_header"]
    lines += [f"{x!r} {y!r} {z!r}" for x, y, z in np.asarray(verts, float).tolist()]
    lines += [f"3 {a} {b} {c}" for a, b, c in np.asarray(faces).tolist()]
    path.write_text("\n".join(lines) + "\n")


BOX = trimesh.creation.box((0.05, 0.05, 0.05))


def _case(name, path):
    """Write the hostile mesh for ``name`` at ``path`` (a .ply path; may write another)."""
    if name == "nan":
        v = BOX.vertices.copy()
        v[0, 0] = np.nan
        _obj(path, v, BOX.faces)
    elif name == "degenerate":
        _obj(path, np.zeros((3, 3)) + [[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]], [[0, 1, 2]])
    elif name == "out-of-range":
        _obj(path, BOX.vertices, np.vstack([BOX.faces, [[0, 1, 99]]]))
    elif name == "empty":
        path.write_bytes(b"")
    elif name == "too-many-faces":
        header = (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
                  b"property float x\nproperty float y\nproperty float z\n"
                  b"element face 5000000\nproperty list uchar int vertex_indices\nend_header\n")
        path.write_bytes(header + struct.pack("<9f", *np.eye(3).ravel()))
    elif name == "millimetres":
        trimesh.creation.box((50.0, 50.0, 50.0)).export(path, file_type="ply")
    elif name == "unreadable":
        path.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, np.uint8).tobytes())


CASES = {
    "nan": "mesh has NaN or infinite vertex coordinates",
    "degenerate": "mesh is flat",
    "out-of-range": "face indices point past the vertex list",
    "empty": "mesh file is empty (0 bytes)",
    "too-many-faces": f"mesh has 5000000 faces, over the {constants.MESH_MAX_FACES}",
    "millimetres": "looks like millimetres: pass --mesh-scale 0.001",
    "unreadable": "",
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_hostile_mesh_is_one_error_line(name, data, tmp_path, capsys):
    path = object_mesh_path(data, "box")
    _case(name, path)
    code, errors = _predict(data, tmp_path, capsys)
    assert code == 1 and len(errors) == 1, errors
    assert errors[0].startswith(f"error: {path}: ") and CASES[name] in errors[0]


def test_millimetre_mesh_accepted_with_scale(data, tmp_path, capsys):
    _case("millimetres", object_mesh_path(data, "box"))
    code, errors = _predict(data, tmp_path, capsys, "--mesh-scale", "0.001")
    assert code == 0 and not errors


@pytest.mark.slow
def test_open_mug_through_predict_and_evaluate(tmp_path, capsys):
    """An imperfect mug (seams, overlapping shells, a punched hole) is repaired once, reported
    on stderr and in both manifests, and the metrics are finite."""
    import json

    from tests.mesh_fixtures import open_mug

    data = tmp_path / "data"
    write_dataset(data, [("s1", "mug", "lift")], T=8, splits={"train": [], "val": [],
                                                              "test": ["mug"]})
    open_mug().export(object_mesh_path(data, "mug"))
    code, errors = _predict(data, tmp_path, capsys)
    assert code == 1 and "--accept-repair" in errors[0]
    assert main(["predict", "--method", "gt", "--input", str(data), "--out",
                 str(tmp_path / "out"), "--accept-repair", "2"]) == 0
    line = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("mesh ")]
    assert len(line) == 1 and "winding-number" in line[0] and "(cached)" not in line[0]
    report = json.loads((tmp_path / "out" / "manifest.json").read_text())["meshes"]["mug"]
    assert 0 < report["max_mm"] <= 2
    assert main(["evaluate", "--pred", str(tmp_path / "out"), "--gt", str(data), "--out",
                 str(tmp_path / "eval"), "--accept-repair", "2", "--metrics", "mpjpe,pen_depth",
                 "--no-progress"]) == 0
    again = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("mesh ")]
    assert len(again) == 1 and "(cached)" in again[0]  # evaluate reads the repaired mesh back
    info = json.loads((tmp_path / "eval" / "evaluation.json").read_text())
    assert info["meshes"]["mug"]["max_mm"] == report["max_mm"]
    import pandas as pd

    res = pd.read_csv(tmp_path / "eval" / "results.csv")
    assert np.isfinite(res.loc[res["n_frames"] > 0, "value"]).all() and (res["n_frames"] > 0).any()
