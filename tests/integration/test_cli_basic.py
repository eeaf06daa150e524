"""The CLI skeleton: help, version, ls, and the error convention.

The convention: docs/contract.md, "Command line".
"""

import subprocess
import sys

import pytest

from grip_bench import __version__
from grip_bench.cli.main import main
from grip_bench.core.errors import InputError


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "grip_bench", *args],
                          capture_output=True, text=True, timeout=120)


def test_version_and_help():
    r = run_cli("--version")
    assert r.returncode == 0 and __version__ in r.stdout
    r = run_cli("--help")
    assert r.returncode == 0 and "ls" in r.stdout and "--debug" in r.stdout


def test_start_up_imports_neither_torch_nor_trimesh():
    """Every command's parser is built at start-up: a command module that imports torch or
    trimesh at its top costs every `grip-bench` call seconds (`--help` took 4.7 s, s36)."""
    code = ("import sys; from grip_bench.cli.main import build_parser; build_parser(); "
            "print(sorted(m for m in ('torch', 'trimesh', 'mujoco') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stdout + r.stderr


def test_stream_precision_choices_are_the_pipelines():
    from grip_bench.cli import stream
    from grip_bench.grip.frozen import STREAM_PRECISION_CHOICES

    assert stream.STREAM_PRECISION_CHOICES == STREAM_PRECISION_CHOICES


def test_ls_lists_three_kinds(capsys):
    assert main(["ls"]) == 0
    out = capsys.readouterr().out
    for kind in ("methods", "metrics", "tables"):
        assert f"{kind} (" in out


def test_bad_usage_exits_2():
    r = run_cli("ls", "nonsense")
    assert r.returncode == 2
    r = run_cli("no-such-command")
    assert r.returncode == 2


def test_input_error_is_one_line_exit_1(monkeypatch, capsys):
    import grip_bench.cli.ls as ls

    def boom(args):
        raise InputError("shape (3,) should be (T, 3)", "seq.npz: rhand.transl")

    monkeypatch.setattr(ls, "run", boom)
    assert main(["ls"]) == 1  # parser built after the patch, so the patched run is used
    err = capsys.readouterr().err
    assert err == "error: seq.npz: rhand.transl: shape (3,) should be (T, 3)\n"


def test_debug_shows_traceback(monkeypatch):
    import grip_bench.cli.ls as ls

    def boom(args):
        raise InputError("bad", "x")

    monkeypatch.setattr(ls, "run", boom)
    with pytest.raises(InputError):
        main(["--debug", "ls"])
