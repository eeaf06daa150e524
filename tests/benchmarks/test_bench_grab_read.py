"""Benchmark: reading one full-size GRAB sequence (120 fps -> 30 fps), time and peak memory.

A synthetic file shaped like GRAB's largest: 2,310 frames at 120 fps, 24 PCA hand
coefficients, ``contact.object`` (2310, 48370) and ``contact.body`` (2310, 10475) labels,
stored uncompressed (``np.savez``) and compressed. The peak traced memory of one read is
recorded in ``extra_info`` (docs/real_grab.md has the before/after figures).
"""

from __future__ import annotations

import tracemalloc
import zipfile

import numpy as np
import pytest

from grip_bench.data.grab_io import read_grab
from tests.grab_fixtures import (
    FakeMano,
    full_size_grab_arrays,
    write_npz,
    write_subject_templates,
)


@pytest.fixture(scope="module", params=["stored", "deflated"])
def full_file(request, tmp_path_factory):
    root = tmp_path_factory.mktemp("grab_full")
    raw = full_size_grab_arrays(contact_dtype=np.int8)
    path = write_npz(root / "grab" / "s1" / "full.npz", raw)
    write_subject_templates(root, raw, FakeMano())
    if request.param == "deflated":  # np.savez_compressed's layout
        packed = path.with_name("full_deflated.npz")
        with zipfile.ZipFile(path) as zi, zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as zo:
            for info in zi.infolist():
                zo.writestr(info.filename, zi.read(info))
        path = packed
    return path


def test_bench_read_full_size_sequence(benchmark, full_file):
    mano = FakeMano()
    tracemalloc.start()
    seq = read_grab(full_file, mano_backend=mano)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    kept = sum(v.nbytes for v in seq.contact.values())
    benchmark.extra_info.update(peak_mib=round(peak / 2**20, 1), kept_contact_mib=round(
        kept / 2**20, 1))
    seq = benchmark.pedantic(read_grab, args=(full_file,), kwargs={"mano_backend": mano},
                             rounds=3, iterations=1)
    assert seq.n_frames == 578 and seq.contact["object"].shape == (578, 48370)
