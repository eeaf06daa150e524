"""Portable numerics (``core/numerics.py``): the pins, the modes, the cache key, and that the
pins reach numpy, OpenBLAS and torch in a fresh process."""

import json
import os
import subprocess
import sys

import pytest

from grip_bench.bench.cache import unit_key
from grip_bench.core import numerics as N

CLEAN = {k: v for k, v in os.environ.items() if k not in N.PINS and k != N.MODE_VAR}


@pytest.fixture(autouse=True)
def _keep_late(monkeypatch):
    """pin() records which libraries had loaded; the tests below call it again."""
    monkeypatch.setattr(N, "_late", N._late)


@pytest.mark.parametrize("machine, flags, expect", [
    ("x86_64", set(N.NEEDS) | {"sse2", "avx512f"}, True),
    ("AMD64", set(N.NEEDS), True),
    ("x86_64", set(N.NEEDS) - {"movbe"}, False),
    ("x86_64", {"avx", "sse4_2"}, False),  # no AVX2: the pinned kernels would crash
    ("aarch64", {"avx2", "fma"}, False),
])
def test_can_pin_needs_x86_64_with_avx2_and_fma(machine, flags, expect):
    assert N.can_pin(machine, flags) is expect


def test_pin_sets_every_pin_and_keeps_what_the_user_set(monkeypatch):
    monkeypatch.setattr(N, "can_pin", lambda: True)
    env = {"MKL_CBWR": "AVX2"}
    assert N.pin(env) == "portable"
    assert env == {**N.PINS, "MKL_CBWR": "AVX2"}
    assert N.mode(env) == "custom"
    env["MKL_CBWR"] = N.PINS["MKL_CBWR"]
    assert N.mode(env) == "portable"


def test_native_mode_and_unpinnable_processors_set_nothing(monkeypatch):
    monkeypatch.setattr(N, "can_pin", lambda: True)
    env = {N.MODE_VAR: "native"}
    assert N.pin(env) == "native" and env == {N.MODE_VAR: "native"}
    monkeypatch.setattr(N, "can_pin", lambda: False)
    env = {}
    assert N.pin(env) == "native" and env == {} and N.mode(env) == "native"


def test_unknown_mode_is_a_one_line_error_naming_the_variable(capsys):
    with pytest.raises(SystemExit) as e:
        N.pin({N.MODE_VAR: "fast"})
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and N.MODE_VAR in err and "'fast'" in err


def test_key_names_the_processor_only_outside_portable_mode():
    portable = N.key(dict(N.PINS))
    assert portable == {"mode": "portable", "pins": dict(N.PINS)}
    native = N.key({})
    assert native["mode"] == "native" and native["cpu"]["model"] is not None


def test_cache_keys_differ_between_portable_and_native_units(monkeypatch):
    for k, v in N.PINS.items():
        monkeypatch.setenv(k, v)
    portable = unit_key("dataset", {"seed": 0})
    assert unit_key("dataset", {"seed": 0}) == portable  # stable
    monkeypatch.delenv("MKL_CBWR")
    custom = unit_key("dataset", {"seed": 0})
    for k in N.PINS:
        monkeypatch.delenv(k, raising=False)
    assert len({portable, custom, unit_key("dataset", {"seed": 0})}) == 3


_PROBE = ("import json, grip_bench, numpy, torch; torch.ones(2) @ torch.ones(2); "
          "from grip_bench.core.numerics import state; print(json.dumps(state()))")


def _state(env: dict) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not N.can_pin(), reason="needs an x86-64-v3 processor (AVX2, FMA)")
def test_the_pins_reach_numpy_openblas_and_torch_in_a_fresh_process():
    s = _state(CLEAN)
    assert s["mode"] == "portable" and s["pins"] == N.PINS
    assert s["numpy_avx512"] == [] and s["torch_capability"] == "AVX2"
    assert s["openblas_core"] in (None, "Haswell")  # None: a numpy built without OpenBLAS
    assert s["loaded_before_pins"] == []


def test_native_mode_leaves_the_libraries_alone_in_a_fresh_process():
    s = _state({**CLEAN, N.MODE_VAR: "native"})
    assert s["mode"] == "native" and set(s["pins"].values()) == {None}
    assert "cpu" in s


def test_a_library_loaded_before_the_pins_is_named():
    probe = ("import numpy, grip_bench, json; from grip_bench.core.numerics import state; "
             "print(json.dumps(state()['loaded_before_pins']))")
    out = subprocess.run([sys.executable, "-c", probe], env=CLEAN, capture_output=True,
                         text=True, check=True)
    assert json.loads(out.stdout) == ["numpy"]


def _worker_state() -> dict:
    import torch

    from grip_bench.core.numerics import state

    torch.ones(2) @ torch.ones(2)
    return state()


@pytest.mark.skipif(not N.can_pin(), reason="needs an x86-64-v3 processor (AVX2, FMA)")
def test_a_spawned_worker_inherits_the_pins():
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
        s = pool.submit(_worker_state).result(timeout=120)
    assert s["mode"] == "portable" and s["numpy_avx512"] == []
    assert s["torch_capability"] == "AVX2" and s["openblas_core"] in (None, "Haswell")


@pytest.mark.skipif(not N.can_pin(), reason="needs an x86-64-v3 processor (AVX2, FMA)")
def test_the_test_process_is_pinned_too():
    """tests/conftest.py imports grip_bench before any test module imports numpy."""
    if os.environ.get(N.MODE_VAR, "portable") != "portable":
        pytest.skip(f"{N.MODE_VAR} asks for native kernels")
    s = N.state()
    assert s["loaded_before_pins"] == [] and s["numpy_avx512"] == []


def test_libraries_loaded_before_pins_count_only_when_the_pins_were_not_inherited(monkeypatch):
    monkeypatch.setattr(N, "can_pin", lambda: True)
    N.pin(dict(N.PINS))  # a worker started with the pins: numpy read them as it loaded
    assert N._late == ()
    N.pin({})  # numpy and torch are loaded in this process, the pins were not there
    assert set(N._late) == {"numpy", "torch"}


@pytest.mark.parametrize("s, ok", [
    ({"mode": "native", "numpy_avx512": ["X86_V4"], "openblas_core": "SkylakeX"}, True),
    ({"mode": "portable", "numpy_avx512": [], "openblas_core": "Haswell",
      "torch_capability": "AVX2"}, True),
    ({"mode": "portable", "numpy_avx512": [], "openblas_core": None}, True),
    ({"mode": "portable", "numpy_avx512": ["X86_V4"], "openblas_core": "Haswell"}, False),
    ({"mode": "portable", "numpy_avx512": [], "openblas_core": "SkylakeX"}, False),
    ({"mode": "portable", "numpy_avx512": [], "openblas_core": "Haswell",
      "torch_capability": "AVX512"}, False),
])
def test_in_effect_reads_what_the_libraries_run(s, ok):
    assert N.in_effect(s) is ok


def test_a_worker_with_other_kernels_stops_with_one_line(monkeypatch):
    from grip_bench.core.errors import GripBenchError

    good = {"mode": "portable", "numpy_avx512": [], "openblas_core": "Haswell",
            "in_effect": True}
    monkeypatch.setattr(N, "state", lambda: good)
    N.check_worker("portable")
    with pytest.raises(GripBenchError, match=N.MODE_VAR) as e:
        N.check_worker("native")
    assert "\n" not in str(e.value)
    monkeypatch.setattr(N, "state", lambda: {**good, "numpy_avx512": ["X86_V4"],
                                             "in_effect": False})
    with pytest.raises(GripBenchError, match="AVX-512"):
        N.check_worker("portable")


def test_a_ray_cluster_gets_the_pins_as_its_workers_start(monkeypatch):
    """A cluster's nodes do not inherit the driver's environment: ray.init carries them."""
    from types import SimpleNamespace

    from grip_bench.bench import ray_executor as R

    seen = {}
    fake = SimpleNamespace(is_initialized=lambda: False, init=lambda **kw: seen.update(kw))
    for k, v in N.PINS.items():
        monkeypatch.setenv(k, v)
    assert R.connect(fake, SimpleNamespace(address="ray://head:10001", workers=None))
    assert seen["runtime_env"] == {"env_vars": {**N.PINS, **N.env()}}
    assert set(N.PINS) <= set(seen["runtime_env"]["env_vars"])


def test_geometry_cache_entries_are_kept_apart_by_kernels(monkeypatch):
    """Derived geometry built with one processor's native kernels is not read as portable."""
    import numpy as np

    from grip_bench.geometry.cache import bytes_key, mesh_key

    v, f = np.eye(3), np.array([[0, 1, 2]])
    for k, val in N.PINS.items():
        monkeypatch.setenv(k, val)
    portable = mesh_key("sdf_grid", v, f), bytes_key("repaired-mesh", (b"x",))
    for k in N.PINS:
        monkeypatch.delenv(k)
    native = mesh_key("sdf_grid", v, f), bytes_key("repaired-mesh", (b"x",))
    assert portable[0] != native[0] and portable[1] != native[1]


_NUMERIC = {"numpy", "scipy", "torch", "trimesh", "mujoco", "igl", "manifold3d", "matplotlib",
            "pandas", "numba", "sklearn", "coacd"}


def _imports(path):
    """(line, top-level module) of every import in the file, in source order."""
    import ast

    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.append((node.lineno, node.module.split(".")[0]))
    return sorted(out)


def test_every_probe_in_tools_imports_grip_bench_before_a_numeric_library():
    """A probe run as ``python tools/x.py`` computes what the run computes only if the pins are
    set before numpy (or torch, or a library built on them) loads: docs/reproducibility.md."""
    from pathlib import Path

    tools = sorted((Path(__file__).resolve().parents[2] / "tools").glob("*.py"))
    assert tools
    late = []
    for path in tools:
        seq = _imports(path)
        first_numeric = next((ln for ln, m in seq if m in _NUMERIC), None)
        first_ours = next((ln for ln, m in seq if m == "grip_bench"), None)
        if first_numeric is not None and (first_ours is None or first_ours > first_numeric):
            late.append(f"{path.name}:{first_numeric}")
    assert not late, f"numeric library imported before grip_bench: {late}"
