"""``grip-bench stream``: JSON lines over stdin/stdout and a localhost socket, on a tiny trained
GRIP; malformed lines, bad addresses."""

import io
import json
import socket
import subprocess
import sys

import numpy as np
import pytest
import torch

from grip_bench.cli.main import main
from grip_bench.cli.stream import parse_address
from grip_bench.core.errors import InputError
from grip_bench.data.grab_io import list_sequences, object_mesh_path, read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.grip.method import GripMethod
from grip_bench.grip.stream import GripStream, frame_of
from grip_bench.methods.api import TrainContext
from tests.grip_fixtures import tiny_profile, write_grip_dataset


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = write_grip_dataset(tmp_path_factory.mktemp("gripdata"), T=12)
    ckpt = tmp_path_factory.mktemp("ckpt") / "grip.pt"
    torch.set_num_threads(1)
    GripMethod().train(root, ckpt, TrainContext(profile=tiny_profile(), progress=False))
    seq = read_grab(list_sequences(root)[0])
    lines = [json.dumps(_jsonable(frame_of(seq, t))) for t in range(seq.n_frames)]
    return root, ckpt, seq, lines


def _jsonable(x):
    return {k: _jsonable(v) for k, v in x.items()} if isinstance(x, dict) else x.tolist()


def _args(root, ckpt, seq, *more):
    return ["stream", "--checkpoint", str(ckpt), "--precision", "fp32", "--threads", "1",
            "--object", str(object_mesh_path(root, seq.obj_name)), "--height", str(seq.height),
            "--hand-scale", str(seq.hand_scale), *more]


def _expected(root, ckpt, seq):
    stream = GripStream.from_checkpoint(ckpt, ObjectLibrary(root), seq.obj_name,
                                        height=seq.height, hand_scale=seq.hand_scale)
    return [stream.step(frame_of(seq, t)) for t in range(seq.n_frames)]


def _check(outs, expected):
    assert [o["frame"] for o in outs] == list(range(len(expected)))
    for o, e in zip(outs, expected, strict=True):
        assert o["ms"] > 0
        for side in ("left", "right"):
            for key in ("global_orient", "hand_pose", "transl"):
                np.testing.assert_allclose(o[side][key], e[side][key], atol=1e-9)
        np.testing.assert_allclose(o["body_pose"], e["body_pose"], atol=1e-9)


def test_stdin_stdout_round_trip(setup, monkeypatch, capsys):
    root, ckpt, seq, lines = setup
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n".join(lines) + "\n\n"))
    assert main(_args(root, ckpt, seq)) == 0
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    _check(out, _expected(root, ckpt, seq))


def test_reset_line_and_mesh_outside_a_data_folder(setup, monkeypatch, capsys, tmp_path):
    root, ckpt, seq, lines = setup
    mesh = tmp_path / f"{seq.obj_name}.obj"  # another format, another folder
    import trimesh

    trimesh.load(object_mesh_path(root, seq.obj_name), process=False).export(mesh)
    again = json.dumps({**json.loads(lines[0]), "reset": True})
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n".join(lines[:3] + [again]) + "\n"))
    args = _args(root, ckpt, seq)
    args[args.index("--object") + 1] = str(mesh)
    assert main(args) == 0
    out = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [o["frame"] for o in out] == [0, 1, 2, 0]
    np.testing.assert_allclose(out[3]["right"]["hand_pose"], out[0]["right"]["hand_pose"],
                               atol=1e-9)


@pytest.mark.parametrize("edit,message", [
    (lambda f: f.replace('"body_pose": [', '"body_pose": [0.5, '),
     "error: line 2: body.body_pose: expected 63 numbers, got shape (64,)"),
    (lambda f: f[:-5], "error: line 2: frame: not JSON"),
    (lambda f: json.dumps({k: v for k, v in json.loads(f).items() if k != "hands"}),
     "error: line 2: hands: missing field"),
])
def test_malformed_line_is_one_error(setup, monkeypatch, capsys, edit, message):
    root, ckpt, seq, lines = setup
    text = "\n".join([lines[0], edit(lines[1]), lines[2]]) + "\n"
    monkeypatch.setattr(sys, "stdin", io.StringIO(text))
    assert main(_args(root, ckpt, seq)) == 1
    cap = capsys.readouterr()
    assert len(cap.out.splitlines()) == 1  # frame 0 was answered before the bad line
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(message)


def test_socket_round_trip(setup):
    root, ckpt, seq, lines = setup
    proc = subprocess.Popen(
        [sys.executable, "-m", "grip_bench", *_args(root, ckpt, seq, "--socket", "127.0.0.1:0",
                                                   "--max-connections", "2")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stderr.readline()
        assert first.startswith("listening on 127.0.0.1:"), first + proc.stderr.read()
        port = int(first.strip().rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port), timeout=60) as conn, \
                conn.makefile("rw", encoding="utf-8") as f:
            out = []
            for line in lines:  # one frame at a time, as a live client does
                f.write(line + "\n")
                f.flush()
                out.append(json.loads(f.readline()))
        _check(out, _expected(root, ckpt, seq))
        with socket.create_connection(("127.0.0.1", port), timeout=60) as conn, \
                conn.makefile("rw", encoding="utf-8") as f:  # a new take, then a bad line
            f.write(lines[0] + "\n" + '{"body": 1}\n')
            f.flush()
            assert json.loads(f.readline())["frame"] == 0
            assert json.loads(f.readline()) == {"error": "line 2: body: expected an object"}
        assert proc.wait(timeout=60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


def test_socket_address_must_be_loopback():
    assert parse_address("127.0.0.1:0", False) == ("127.0.0.1", 0)
    assert parse_address("localhost:8765", False) == ("localhost", 8765)
    with pytest.raises(InputError, match="allow-remote"):
        parse_address("192.0.2.7:8765", False)
    assert parse_address("192.0.2.7:8765", True) == ("192.0.2.7", 8765)
    for bad in ("8765", "127.0.0.1:", "127.0.0.1:99999", "127.0.0.1:http"):
        with pytest.raises(InputError, match="HOST:PORT"):
            parse_address(bad, False)


def test_cli_refuses_remote_without_the_flag(setup, capsys):
    root, ckpt, seq, _ = setup
    assert main(_args(root, ckpt, seq, "--socket", "192.0.2.7:8765")) == 1
    assert "--socket: 192.0.2.7 is not a loopback address" in capsys.readouterr().err
