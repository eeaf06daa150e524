"""Results schema: validation errors, deterministic bytes, atomic writes, runtime.csv."""

from __future__ import annotations

import math
import os

import numpy as np
import pandas as pd
import pytest

from grip_bench.core.errors import InputError
from grip_bench.results import schema as R
from grip_bench.results.schema import (
    FRAME_COLUMNS,
    RESULT_COLUMNS,
    ResultRow,
    read_results,
    read_runtime,
    write_results,
    write_runtime,
)

UNITS = {"mpvpe": "mm", "mpjpe": "mm", "cc": "mm", "iv": "cm3", "contact_ratio": "%",
         "sim_stable": "%", "sim_disp": "mm", "hold_sim": "%", "hold_sim_disp": "mm",
         "hold_qs": "%", "hold_qs_mu3": "%", "contact_drift": "mm"}


def synthetic_results(methods=("grip", "grip-no-rnet", "gt"), perturbations=("none",),
                      n_seq=6, objects=("mug", "apple", "torus"), metrics=("mpvpe", "cc"),
                      hands=("right", "left"), seed=0, dataset="synthgrab") -> pd.DataFrame:
    """A validated results frame: one value per (method, pert, sequence, hand, metric)."""
    rng = np.random.default_rng(seed)
    rows = []
    for m in methods:
        for p in perturbations:
            for k in range(n_seq):
                obj = objects[k % len(objects)]
                for h in hands:
                    for met in metrics:
                        rows.append(ResultRow(m, dataset, "test", p, f"s{k:02d}_{obj}", obj, h,
                                              met, float(rng.gamma(4.0, 2.0)), UNITS[met], 30))
    return R.validate(R.to_frame(rows))


def tiny_rows() -> list[ResultRow]:
    return [ResultRow("grip", "synthgrab", "test", "none", "s1", "mug", "right", "mpvpe",
                      7.88, "mm", 30),
            ResultRow("grip", "synthgrab", "test", "none", "s0", "mug", "left", "mpvpe",
                      math.nan, "mm", 12),
            ResultRow("flat-input", "synthgrab", "test", "none", "s0", "mug", "right", "mpvpe",
                      0.1, "mm", 30)]


def test_roundtrip_and_columns(tmp_path):
    path = write_results(tiny_rows(), tmp_path / "results.csv")
    text = path.read_text()
    assert text.splitlines()[0] == ",".join(RESULT_COLUMNS)
    assert text.endswith("\n") and "\r" not in text
    df = read_results(path)
    assert list(df.columns) == list(RESULT_COLUMNS)
    assert df["value"].dtype == np.float64 and df["n_frames"].dtype == np.int64
    assert df["method"].tolist() == ["flat-input", "grip", "grip"]  # sorted
    assert math.isnan(df.loc[1, "value"]) and df.loc[2, "value"] == 7.88
    assert ",nan,mm," in text


def test_bytes_identical_for_any_row_order(tmp_path):
    df = synthetic_results()
    a = write_results(df, tmp_path / "a.csv").read_bytes()
    shuffled = df.sample(frac=1.0, random_state=3)
    b = write_results(shuffled, tmp_path / "b.csv").read_bytes()
    assert a == b
    # read -> write is idempotent: floats round-trip exactly
    c = write_results(read_results(tmp_path / "a.csv"), tmp_path / "c.csv").read_bytes()
    assert a == c


@pytest.mark.parametrize("x", [0.1, 1 / 3, 1e-300, 123456.789, 7.88, -2.5, 0.0])
def test_float_repr_roundtrip(tmp_path, x):
    row = ResultRow("m", "d", "test", "none", "s", "o", "right", "mpvpe", x, "mm", 1)
    df = read_results(write_results([row], tmp_path / "r.csv"))
    assert df["value"].iloc[0] == x


def test_negative_zero_is_written_as_zero():
    assert R.format_float(-0.0) == "0.0" and R.format_float(float("nan")) == "nan"


def test_names_that_look_like_missing_values_stay_strings(tmp_path):
    row = ResultRow("NA", "d", "test", "none", "nan", "None", "right", "mpvpe", 1.0, "mm", 1)
    df = read_results(write_results([row], tmp_path / "r.csv"))
    assert df.loc[0, ["method", "sequence", "object"]].tolist() == ["NA", "nan", "None"]


def test_frames_schema(tmp_path):
    rows = [ResultRow("grip", "d", "test", "none", "s", "o", "right", "mpvpe", v, "mm", 1,
                      frame=f) for f, v in [(2, 3.0), (0, 1.0), (1, 2.0)]]
    path = write_results(rows, tmp_path / "frames.csv")
    assert path.read_text().splitlines()[0] == ",".join(FRAME_COLUMNS)
    df = read_results(path)
    assert df["frame"].tolist() == [0, 1, 2] and df["value"].tolist() == [1.0, 2.0, 3.0]
    assert R.rows_from_frame(df)[0].frame == 0


def _write_raw(tmp_path, text):
    p = tmp_path / "results.csv"
    p.write_text(text)
    return p


HEADER = ",".join(RESULT_COLUMNS)


@pytest.mark.parametrize("body, needle", [
    ("method,dataset\nx,y\n", "missing column(s) split"),
    (HEADER + ",extra\n" + "m,d,test,none,s,o,right,mpvpe,1.0,mm,3,z\n", "unexpected column"),
    (HEADER + "\nm,d,test,none,s,o,right,mpvpe,abc,mm,3\n", "column 'value' needs a number"),
    (HEADER + "\nm,d,test,none,s,o,right,mpvpe,inf,mm,3\n", "infinite"),
    (HEADER + "\nm,d,test,none,s,o,right,mpvpe,1.0,mm,-1\n", "column 'n_frames'"),
    (HEADER + "\nm,d,test,none,s,o,right,mpvpe,1.0,mm,2.5\n", "column 'n_frames'"),
    (HEADER + "\n,d,test,none,s,o,right,mpvpe,1.0,mm,2\n", "column 'method' needs a non-empty"),
    (HEADER + "\nm,d,test,none,s,o,right,mpvpe,1.0,mm,2\nm,d,test,none,s,o,right,mpvpe,2.0,mm,2\n",
     "duplicate result"),
    ("", "not a readable CSV"),
])
def test_read_errors_name_file_and_problem(tmp_path, body, needle):
    p = _write_raw(tmp_path, body)
    with pytest.raises(InputError) as e:
        read_results(p)
    assert e.value.where == str(p)
    assert needle in e.value.what


def test_missing_file_and_row_number(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_results(tmp_path / "nope.csv")
    p = _write_raw(tmp_path, HEADER + "\nm,d,test,none,s,o,right,mpvpe,1.0,mm,2\n"
                   "m,d,test,none,s2,o,right,mpvpe,x,mm,2\n")
    with pytest.raises(InputError, match="row 2"):
        read_results(p)


def test_empty_value_reads_as_nan(tmp_path):
    p = _write_raw(tmp_path, HEADER + "\nm,d,test,none,s,o,right,mpvpe,,mm,2\n")
    assert math.isnan(read_results(p)["value"].iloc[0])


def test_write_rejects_bad_rows_and_leaves_no_file(tmp_path):
    bad = ResultRow("m", "d", "test", "none", "s", "o", "right", "mpvpe", math.inf, "mm", 1)
    with pytest.raises(InputError):
        write_results([bad], tmp_path / "r.csv")
    assert not (tmp_path / "r.csv").exists()


def test_write_is_atomic(tmp_path, monkeypatch):
    path = write_results(tiny_rows(), tmp_path / "results.csv")
    before = path.read_bytes()

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError):
        write_results(synthetic_results(), path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.csv"]  # no temp left


def test_runtime_roundtrip_and_validation(tmp_path):
    df = pd.DataFrame({"method": ["grip", "toch"], "mode": ["full", "refine"],
                       "device": ["cpu", "cpu"], "batch": [1, 8],
                       "seconds_per_frame": [0.022, 0.1], "frames_per_second": [45.0, 10.0]})
    path = write_runtime(df, tmp_path / "runtime.csv")
    back = read_runtime(path)
    assert back["batch"].tolist() == [1, 8] and back["seconds_per_frame"].tolist() == [0.022, 0.1]
    with pytest.raises(InputError, match="runtime columns"):
        write_runtime(df.drop(columns="device"), tmp_path / "bad.csv")
