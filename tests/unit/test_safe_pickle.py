"""The restricted loader: plain data in, code refused before it can run."""

from __future__ import annotations

import contextlib
import os
import pickle
import sys
import types
import zipfile

import numpy as np
import pytest
import scipy.sparse as sp

from grip_bench.core.errors import InputError, UnsafeFileError
from grip_bench.core.safe_pickle import load_npz, load_pickle


class Evil:
    """Runs a shell command when unpickled by plain pickle."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


@contextlib.contextmanager
def fake_chumpy():
    """``chumpy.ch.Ch`` as a stand-in class, registered only while pickling."""
    pkg, mod = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    mod.Ch, pkg.ch = Ch, mod
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = pkg, mod
    try:
        yield Ch
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]


def grab_like(rng) -> dict:
    """Members the way GRAB stores them: dicts in 0-d object arrays, strings, numbers."""
    params = {"global_orient": rng.normal(size=(5, 3)), "transl": rng.normal(size=(5, 3))}
    return {
        "gender": np.array("male"), "framerate": np.array(120.0), "n_frames": np.array(5),
        "body": np.array({"params": params, "vtemp": "tools/subject_meshes/male/s1.ply"},
                         dtype=object),
        "contact": np.array({"body": np.zeros((5, 10), dtype=np.int8)}, dtype=object),
        "markers": rng.normal(size=(5, 4, 3)).astype(np.float32),
    }


def test_grab_style_npz_round_trips(tmp_path):
    src = grab_like(np.random.default_rng(0))
    np.savez(tmp_path / "seq.npz", **src)
    out = load_npz(tmp_path / "seq.npz")
    assert set(out) == set(src)
    assert out["gender"] == "male" and out["n_frames"] == 5
    assert out["body"]["vtemp"] == src["body"].item()["vtemp"]
    for key, value in src["body"].item()["params"].items():
        np.testing.assert_array_equal(out["body"]["params"][key], value)
    assert out["contact"]["body"].dtype == np.int8
    np.testing.assert_array_equal(out["markers"], src["markers"])


def test_hostile_npz_member_is_refused_and_does_not_run(tmp_path):
    marker = tmp_path / "pwned"
    src = grab_like(np.random.default_rng(1))
    src["body"] = np.array({"params": Evil(marker)}, dtype=object)
    np.savez(tmp_path / "evil.npz", **src)
    with pytest.raises(UnsafeFileError, match="system") as err:
        load_npz(tmp_path / "evil.npz")
    assert "body" in str(err.value)
    assert not marker.exists()


def test_truncated_archive_names_the_file(tmp_path):
    np.savez(tmp_path / "seq.npz", **grab_like(np.random.default_rng(2)))
    raw = (tmp_path / "seq.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(InputError) as err:
        load_npz(tmp_path / "cut.npz")
    assert err.value.where == str(tmp_path / "cut.npz")


def test_corrupt_member_names_file_and_key(tmp_path):
    path = tmp_path / "seq.npz"
    big = np.arange(4096, dtype=np.float64)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        with zf.open("ok.npy", "w") as f:
            np.save(f, np.zeros(3))
        with zf.open("data.npy", "w") as f:
            np.save(f, big)
    raw = bytearray(path.read_bytes())
    at = raw.find(big[100:101].tobytes())  # inside the member payload
    raw[at: at + 8] = b"\xff" * 8
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError) as err:
        load_npz(path)
    assert err.value.where == f"{path}: data"


def test_chumpy_and_sparse_become_arrays(tmp_path):
    reg = sp.csc_matrix(np.eye(4)[:3])
    with fake_chumpy() as Ch:
        data = {"shapedirs": Ch(np.ones((2, 3))), "nested": Ch(Ch(np.arange(3.0))),
                "J_regressor": reg, "tags": {"a", "b"}, "kind": "lbs"}
        for proto in (2, 4):
            with open(tmp_path / f"m{proto}.pkl", "wb") as f:
                pickle.dump(data, f, protocol=proto)
    for proto in (2, 4):
        out = load_pickle(tmp_path / f"m{proto}.pkl", allow_chumpy=True, allow_sparse=True)
        np.testing.assert_array_equal(out["shapedirs"], np.ones((2, 3)))
        np.testing.assert_array_equal(out["nested"], np.arange(3.0))
        np.testing.assert_array_equal(out["J_regressor"], np.eye(4)[:3])
        assert out["tags"] == {"a", "b"} and out["kind"] == "lbs"
    with pytest.raises(UnsafeFileError, match="chumpy"):
        load_pickle(tmp_path / "m2.pkl")


def test_dtype_module_dunders_are_refused(tmp_path):
    # GLOBAL 'numpy.dtypes __loader__' would reach the import machinery.
    (tmp_path / "x.pkl").write_bytes(b"cnumpy.dtypes\n__loader__\n.")
    with pytest.raises(UnsafeFileError, match="__loader__"):
        load_pickle(tmp_path / "x.pkl")
    arr = np.arange(3.0)
    (tmp_path / "ok.pkl").write_bytes(pickle.dumps({"a": arr, "dt": arr.dtype}, protocol=5))
    assert load_pickle(tmp_path / "ok.pkl")["dt"] == np.float64


def test_garbage_pickle_is_input_error(tmp_path):
    (tmp_path / "bad.pkl").write_bytes(b"\x80\x02}q\x00(X\x01")
    with pytest.raises(InputError, match="bad.pkl"):
        load_pickle(tmp_path / "bad.pkl")
    with pytest.raises(InputError, match="missing.pkl"):
        load_pickle(tmp_path / "missing.pkl")
