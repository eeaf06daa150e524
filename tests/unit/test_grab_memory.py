"""Reading 120 fps GRAB files: subsample while streaming, exactly what full-then-subsample gave.

:func:`read_grab` keeps frames 0, 4, 8, ... of a 120 fps file. It now streams the per-frame
arrays out of the pickled dicts keeping only those rows (and expands PCA on them only), so
the peak memory is about the kept data; the old reader unpickled every member whole and
subsampled afterwards. The figures are in docs/real_grab.md; the benchmark is
tests/benchmarks/test_bench_grab_read.py.
"""

from __future__ import annotations

import io
import os
import pickle
import tracemalloc
import zipfile

import numpy as np
import pytest

from grip_bench.core.errors import InputError, UnsafeFileError
from grip_bench.core.safe_pickle import load_npz
from grip_bench.data import grab_io
from grip_bench.data.grab_io import read_grab
from grip_bench.data.sequence import PART_DIMS, hand_fullpose
from tests.grab_fixtures import (
    FakeMano,
    full_size_grab_arrays,
    real_grab_arrays,
    write_npz,
    write_subject_templates,
)

STEP = 4


def _full_then_subsample(path, mano):
    """The reader before streaming: every member whole, PCA on all 120 fps frames, then
    frames 0, 4, ... copied; hand transl + J0 (the wrist, docs/real_grab.md)."""
    raw = load_npz(path)
    parts = {part: {k: np.asarray(raw[part]["params"][k]) for k in PART_DIMS[part]}
             for part in PART_DIMS}
    for part, key, side in grab_io._HAND_POSE_KEYS:
        full = mano.expand_pca(side, parts[part][key]).astype(parts[part][key].dtype)
        if part == "body":  # GRAB's SMPL-X hand poses are offsets from MANO's mean
            full = full + mano.hands_mean(side).astype(full.dtype)
        parts[part][key] = full
    parts = {part: {k: v[::STEP].copy() for k, v in p.items()} for part, p in parts.items()}
    for part, side in (("rhand", "right"), ("lhand", "left")):
        p = parts[part]
        p["fullpose"] = hand_fullpose(p["global_orient"], p["hand_pose"])
        template = grab_io.load_hand_template(raw[part]["vtemp"], [path.parents[2]], "test")
        j0 = np.float32(mano.rest_wrist(side, template)).astype(np.float64)
        p["transl"] = p["transl"].astype(np.float64) + j0
    contact = {k: v[::STEP].copy() for k, v in raw["contact"].items()}
    return parts, contact


def _assert_exact(seq, parts, contact):
    for part, params in parts.items():
        for k, want in params.items():
            got = seq.parts()[part][k]
            assert got.dtype == want.dtype and np.array_equal(got, want), (part, k)
    assert seq.contact.keys() == contact.keys()
    for k, want in contact.items():
        assert seq.contact[k].dtype == want.dtype and np.array_equal(seq.contact[k], want), k


def _grab_tree(tmp_path, raw, name="mug_lift.npz"):
    path = write_npz(tmp_path / "grab" / "s1" / name, raw)
    write_subject_templates(tmp_path, raw, FakeMano())
    return path


@pytest.mark.parametrize("T", [41, 203, 2310])
@pytest.mark.parametrize("dtype", [np.int8, np.int32])
def test_streamed_read_equals_full_then_subsample(tmp_path, T, dtype):
    """Exactly equal, for frame counts with and without a remainder modulo 4."""
    raw = full_size_grab_arrays(T=T, n_obj_verts=997, n_body_verts=301, contact_dtype=dtype)
    path = _grab_tree(tmp_path, raw)
    mano = FakeMano()
    seq = read_grab(path, mano_backend=mano)
    assert seq.n_frames == len(range(0, T, STEP))
    _assert_exact(seq, *_full_then_subsample(path, mano))


def _write_with_protocol(path, raw, protocol):
    """An npz whose object members are pickled with ``protocol`` (GRAB's were written by older
    numpy and Python versions), plain members as numpy writes them."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w") as zf:
        for key, arr in raw.items():
            buf = io.BytesIO()
            if arr.dtype.hasobject:
                np.lib.format.write_array_header_1_0(
                    buf, {"descr": "|O", "fortran_order": False, "shape": arr.shape})
                pickle.dump(arr, buf, protocol=protocol)
            else:
                np.lib.format.write_array(buf, arr)
            zf.writestr(f"{key}.npy", buf.getvalue())
    return path


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_every_pickle_protocol_reads_the_same(tmp_path, protocol):
    raw = full_size_grab_arrays(T=97, n_obj_verts=513, n_body_verts=40)
    _grab_tree(tmp_path, raw)  # the templates
    path = _write_with_protocol(tmp_path / "grab" / "s1" / f"p{protocol}.npz", raw, protocol)
    mano = FakeMano()
    _assert_exact(read_grab(path, mano_backend=mano), *_full_then_subsample(path, mano))
    members, ids = grab_io._stream_members(path, 97, STEP)
    # protocols 3 and 4 carry raw bytes (BINBYTES): those arrays stream; 2 and 5 encode
    # them otherwise and are subsampled after reading, with the same result
    assert (len(ids) > 0) == (protocol in (3, 4))
    if ids:
        assert id(members["contact"]["object"]) in ids
        assert members["contact"]["object"].shape == (25, 513)
        assert members["contact"]["object"].flags.writeable


def test_fortran_order_and_odd_arrays_fall_back(tmp_path):
    raw = real_grab_arrays(T=41)
    contact = dict(raw["contact"].item())
    contact["object"] = np.asfortranarray(np.arange(41 * 7, dtype=np.int16).reshape(41, 7))
    contact["extra"] = np.arange(41 * 3, dtype=np.int32).reshape(41, 3)[::1]
    wrapped = np.empty((), object)
    wrapped[()] = contact
    path = _grab_tree(tmp_path, {**raw, "contact": wrapped})
    seq = read_grab(path, mano_backend=FakeMano())
    np.testing.assert_array_equal(seq.contact["object"], contact["object"][::STEP])
    np.testing.assert_array_equal(seq.contact["extra"], contact["extra"][::STEP])


def test_peak_memory_is_about_the_kept_frames(tmp_path):
    """The old reader peaked at about twice the unpacked file; this stays near the kept data
    (a memory bound, not a timing)."""
    raw = full_size_grab_arrays(T=1200, n_obj_verts=8000, n_body_verts=2000,
                                contact_dtype=np.int32)
    unpacked = sum(v.nbytes for v in raw["contact"].item().values())
    path = _grab_tree(tmp_path, raw)
    del raw
    mano = FakeMano()
    tracemalloc.start()
    try:
        seq = read_grab(path, mano_backend=mano)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    kept = sum(v.nbytes for v in seq.contact.values())
    assert kept == unpacked // STEP
    assert peak < kept + 3 * grab_io._CHUNK_BYTES + (4 << 20)  # the zip reader copies a chunk
    assert peak < 0.6 * unpacked


def test_hostile_120fps_files_fail_cleanly(tmp_path):
    target = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {target}",))

    raw = real_grab_arrays(T=41)
    evil = np.empty((), object)
    evil[()] = {"params": Evil()}
    path = write_npz(tmp_path / "grab" / "s1" / "evil.npz", {**raw, "object": evil})
    with pytest.raises(UnsafeFileError, match="refused") as e:
        read_grab(path, mano_backend=FakeMano())
    assert e.value.where == f"{path}: object" and not target.exists()
    # a payload claiming more bytes than its member holds allocates nothing
    good = write_npz(tmp_path / "grab" / "s1" / "good.npz", raw)
    data = bytearray(good.read_bytes())
    with zipfile.ZipFile(good) as zf:
        member = zf.read("contact.npy")
    at = data.find(member)
    assert at > 0  # np.savez stores members uncompressed
    lengths = [i for i in range(len(member) - 5) if member[i] == pickle.BINBYTES[0]]
    assert lengths
    for i in lengths:
        data[at + i + 1: at + i + 5] = (1 << 31).to_bytes(4, "little")
    bad = tmp_path / "grab" / "s1" / "bad.npz"
    bad.write_bytes(bytes(data))
    with pytest.raises(InputError) as e:
        read_grab(bad, mano_backend=FakeMano())
    assert e.value.where == f"{bad}: contact" and "\n" not in str(e.value)
    # truncated
    cut = tmp_path / "grab" / "s1" / "cut.npz"
    cut.write_bytes(good.read_bytes()[: len(data) // 2])
    with pytest.raises(InputError):
        read_grab(cut, mano_backend=FakeMano())


def test_non_finite_values_name_the_source_frame(tmp_path):
    raw = real_grab_arrays(T=41)
    rhand = dict(raw["rhand"].item())
    params = dict(rhand["params"])
    params["transl"] = params["transl"].copy()
    params["transl"][13, 1] = np.nan  # a dropped frame (13 % 4 != 0): never looked at
    rhand["params"] = params
    wrapped = np.empty((), object)
    wrapped[()] = rhand
    path = _grab_tree(tmp_path, {**raw, "rhand": wrapped})
    assert read_grab(path, mano_backend=FakeMano()).n_frames == 11
    params["transl"][20, 0] = np.inf  # a kept frame
    path = write_npz(path, {**raw, "rhand": wrapped})
    with pytest.raises(InputError, match=r"first at frame 20\)") as e:
        read_grab(path, mano_backend=FakeMano())
    assert e.value.where == f"{path}: rhand.params.transl"
