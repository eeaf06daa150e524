"""Work-unit cache: keys, storage, atomicity under exceptions and kills, summary."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from grip_bench.bench import cache as C
from grip_bench.bench.cache import Cache, unit_key
from grip_bench.core.errors import InputError


def test_keys_are_canonical():
    a = unit_key("predict", {"method": "grip", "seq": "s1", "sigma": 0.1})
    assert a == unit_key("predict", {"sigma": 0.1, "seq": "s1", "method": "grip"})
    assert a.startswith("predict-") and len(a) == len("predict-") + 64
    assert a != unit_key("metrics", {"method": "grip", "seq": "s1", "sigma": 0.1})
    assert a != unit_key("predict", {"method": "grip", "seq": "s1", "sigma": 0.2})
    arr = np.arange(6.0).reshape(2, 3)
    assert unit_key("x", {"a": arr}) == unit_key("x", {"a": arr.copy()})
    assert unit_key("x", {"a": arr}) != unit_key("x", {"a": arr.T})


def test_code_version_is_part_of_the_key(monkeypatch):
    a = unit_key("predict", {"k": 1})
    monkeypatch.setattr(C, "CODE_VERSION", "other")
    assert unit_key("predict", {"k": 1}) != a


def test_bad_keys(tmp_path):
    with pytest.raises(InputError, match="kind"):
        unit_key("Bad Kind", {})
    with pytest.raises(InputError, match="plain data"):
        unit_key("x", {"v": float("nan")})
    with pytest.raises(InputError, match="malformed"):
        Cache(tmp_path).path("../etc")


def test_put_and_get(tmp_path):
    cache = Cache(tmp_path / "c")
    k1, k2, k3 = (unit_key("u", {"i": i}) for i in range(3))
    assert not cache.has(k1)
    cache.put_json(k1, {"b": 1, "a": [1.5, None]})
    assert cache.has(k1) and cache.get_json(k1) == {"a": [1.5, None], "b": 1}
    assert cache.put_bytes(k2, b"\x00\x01").read_bytes() == b"\x00\x01"
    src = tmp_path / "pred.npz"
    src.write_bytes(b"npz")
    assert cache.put_file(k3, src).name == "pred.npz"
    assert (cache.path(k3) / "pred.npz").read_bytes() == b"npz"
    with pytest.raises(InputError):
        cache.get_json(k2)


def _tmp_entries(root):
    tmp = root / ".tmp"
    return sorted(tmp.iterdir()) if tmp.is_dir() else []


def test_exception_inside_atomic_leaves_nothing(tmp_path):
    cache = Cache(tmp_path)
    key = unit_key("metrics", {"seq": "s"})
    with pytest.raises(RuntimeError), cache.atomic(key) as d:
        (d / "part.json").write_text("{")
        raise RuntimeError("metric crashed")
    assert not cache.has(key) and not cache.path(key).exists()
    assert _tmp_entries(tmp_path) == []


def test_second_writer_keeps_first_unit(tmp_path):
    cache = Cache(tmp_path)
    key = unit_key("u", {})
    cache.put_bytes(key, b"first", "x")
    cache.put_bytes(key, b"second", "x")
    assert (cache.path(key) / "x").read_bytes() == b"first" and _tmp_entries(tmp_path) == []


KILLED_WRITER = """
import os, sys
from grip_bench.bench.cache import Cache
cache = Cache(sys.argv[1])
with cache.atomic(sys.argv[2]) as d:
    (d / "half.bin").write_bytes(b"x" * 100)
    os._exit(9)  # killed mid-unit: no cleanup code runs
"""


def test_killed_writer_leaves_no_unit_and_temp_is_cleaned(tmp_path):
    key = unit_key("predict", {"seq": "s"})
    proc = subprocess.run([sys.executable, "-c", KILLED_WRITER, str(tmp_path), key],
                          capture_output=True, timeout=120, check=False)
    assert proc.returncode == 9
    assert len(_tmp_entries(tmp_path)) == 1  # the leftover temp folder
    cache = Cache(tmp_path)  # the dead writer's folder is cleaned on open
    assert cache.removed_stale == 1 and _tmp_entries(tmp_path) == []
    assert not cache.has(key)
    cache.put_json(key, {"ok": True})
    assert cache.get_json(key) == {"ok": True}


def test_live_writers_temp_is_kept(tmp_path):
    live = tmp_path / ".tmp" / f"{socket.gethostname()}__{os.getpid()}__u-{'0' * 64}__abc"
    other_host = tmp_path / ".tmp" / f"elsewhere__1__u-{'0' * 64}__abc"
    live.mkdir(parents=True)
    other_host.mkdir()
    cache = Cache(tmp_path)
    assert cache.removed_stale == 0
    assert live.is_dir() and other_host.is_dir()
    assert cache.clean_stale(own=True) == 1  # a stopping run drops its own, never another host's
    assert not live.exists() and other_host.is_dir()


def test_summary_counts_first_lookup(tmp_path):
    cache = Cache(tmp_path)
    done = [unit_key("predict", {"i": i}) for i in range(2)]
    for k in done:
        cache.put_json(k, {})
    fresh = Cache(tmp_path)
    todo = unit_key("metrics", {"i": 0})
    for k in [*done, todo]:
        fresh.has(k)
    fresh.put_json(todo, {})
    fresh.has(todo)  # later lookups do not turn a miss into a hit
    s = fresh.summary()
    assert (s["hits"], s["misses"], s["written"]) == (2, 1, 1)
    assert s["by_kind"] == {"metrics": {"hits": 0, "misses": 1},
                            "predict": {"hits": 2, "misses": 0}}
    assert fresh.summary_line() == "cache: reused 2 of 3 units (metrics 0/1, predict 2/2)"


def test_atomic_write_gives_normal_file_permissions(tmp_path):
    import os
    import stat

    from grip_bench.core.io import atomic_write_bytes

    path = atomic_write_bytes(tmp_path / "a.csv", b"x")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask
