"""Run manifest: keys, versions, git info, deterministic atomic JSON."""

from __future__ import annotations

import json
import math

import pytest

from grip_bench.core.errors import InputError
from grip_bench.results.manifest import (
    build_manifest,
    git_info,
    package_versions,
    read_manifest,
    write_manifest,
)

KEYS = {"schema", "grip_bench_version", "versions", "git", "platform", "cpu_count",
        "python_executable", "profile", "config", "seeds", "data_hash", "stage_times",
        "peak_memory_mib"}
VERSIONS = {"grip-bench", "python", "numpy", "torch", "trimesh", "manifold3d", "mujoco",
            "pandas", "matplotlib"}


def _manifest():
    return build_manifest(profile={"name": "smoke", "n_sequences": 4},
                          config={"methods": ("grip", "gt"), "out": "/tmp/x"},
                          seeds={"data": 0, "bootstrap": 0}, data_hash="abc123",
                          stage_times={"predict": 1.5, "metrics": 0.25})


def test_keys_and_versions():
    m = _manifest()
    assert KEYS <= set(m)
    assert VERSIONS <= set(m["versions"])
    assert m["versions"]["numpy"] and m["versions"]["pandas"]
    assert set(m["git"]) == {"revision", "dirty"}
    assert m["cpu_count"] >= 1 and m["config"]["methods"] == ["grip", "gt"]
    assert m["data_hash"] == "abc123" and m["stage_times"]["predict"] == 1.5
    assert m["peak_memory_mib"]["self"] > 10  # this Python process with numpy loaded


def test_missing_package_is_null():
    assert package_versions(["no-such-distribution-xyz"]) == {"no-such-distribution-xyz": None}


def test_git_outside_a_repository_is_null(tmp_path):
    assert git_info(tmp_path) == {"revision": None, "dirty": None}


def test_write_sorted_deterministic_and_readable(tmp_path):
    m = _manifest()
    a = write_manifest(tmp_path / "a.json", m).read_bytes()
    b = write_manifest(tmp_path / "b.json", dict(reversed(list(m.items())))).read_bytes()
    assert a == b and a.endswith(b"\n")
    assert list(json.loads(a)) == sorted(m)
    assert read_manifest(tmp_path / "a.json")["seeds"] == {"bootstrap": 0, "data": 0}


def test_nan_is_rejected(tmp_path):
    m = _manifest()
    m["stage_times"]["bad"] = math.nan
    with pytest.raises(InputError, match="not plain JSON"):
        write_manifest(tmp_path / "m.json", m)
    assert not (tmp_path / "m.json").exists()
