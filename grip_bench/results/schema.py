"""Typed results schema: ``results.csv`` and ``frames.csv``, tidy and deterministic.

Columns: docs/contract.md, "Results".

One row per (method, dataset, split, perturbation, sequence, hand, metric); ``frames.csv``
adds ``frame``. ``value`` is in the metric's REPORT unit (mm, cm3, %), named in ``unit``;
NaN marks a failed computation and is kept (and counted downstream), never replaced by 0.

Determinism: rows are sorted by :data:`SORT_KEYS`, floats are written with Python's
shortest round-trip ``repr`` (``7.88``, ``0.1``, ``nan``) so a value read back and written
again is bit-identical, and lines end with ``\\n``. Two runs producing the same values
therefore produce byte-identical files.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..core.io import atomic_write_text

STR_COLUMNS = ("method", "dataset", "split", "perturbation", "sequence", "object", "hand",
               "metric", "unit")
RESULT_COLUMNS = ("method", "dataset", "split", "perturbation", "sequence", "object", "hand",
                  "metric", "value", "unit", "n_frames")
FRAME_COLUMNS = RESULT_COLUMNS + ("frame",)
SORT_KEYS = ("method", "dataset", "split", "perturbation", "sequence", "object", "hand",
             "metric")
# One value per (these) in results.csv; ``frame`` extends it in frames.csv.
UNIQUE_KEYS = ("method", "dataset", "split", "perturbation", "sequence", "hand", "metric")


@dataclass(frozen=True)
class ResultRow:
    """One tidy result: a metric of one hand of one sequence, in the report unit.

    ``frame`` is set only for per-frame rows (``frames.csv``).
    """

    method: str
    dataset: str
    split: str
    perturbation: str
    sequence: str
    object: str
    hand: str
    metric: str
    value: float
    unit: str
    n_frames: int
    frame: int | None = None


def format_float(x: float) -> str:
    """Shortest round-trip text of a float (``repr``); ``nan`` for NaN, ``0.0`` for ``-0.0``."""
    x = float(x)
    if math.isnan(x):
        return "nan"
    return repr(x + 0.0)  # + 0.0 folds -0.0 into 0.0


def to_frame(rows: Iterable[ResultRow] | pd.DataFrame) -> pd.DataFrame:
    """Rows (dataclasses or a DataFrame) as a DataFrame with the schema's columns."""
    if isinstance(rows, pd.DataFrame):
        return rows.copy()
    records = [asdict(r) for r in rows]
    if not records:
        return pd.DataFrame({f.name: [] for f in fields(ResultRow) if f.name != "frame"})
    df = pd.DataFrame.from_records(records)
    if df["frame"].isna().all():
        df = df.drop(columns="frame")
    return df


def _columns_for(df: pd.DataFrame) -> tuple[str, ...]:
    return FRAME_COLUMNS if "frame" in df.columns else RESULT_COLUMNS


def _check_columns(df: pd.DataFrame, where: str | os.PathLike | None) -> tuple[str, ...]:
    expected = _columns_for(df)
    missing = [c for c in expected if c not in df.columns]
    extra = [c for c in df.columns if c not in expected]
    if missing or extra:
        msg = []
        if missing:
            msg.append(f"missing column(s) {', '.join(missing)}")
        if extra:
            msg.append(f"unexpected column(s) {', '.join(map(str, extra))}")
        raise InputError("; ".join(msg) + f" (expected: {', '.join(expected)})", where=where)
    return expected


def _check_strings(df: pd.DataFrame, where: str | os.PathLike | None) -> None:
    for col in STR_COLUMNS:
        bad = ~df[col].map(lambda v: isinstance(v, str) and v != "")
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"column '{col}' needs a non-empty string, row {i + 1} has "
                             f"{df[col].iloc[i]!r}", where=where)


def _to_float(
    df: pd.DataFrame, where: str | os.PathLike | None, col: str = "value"
) -> pd.Series:
    def conv(v: object) -> float:
        if isinstance(v, bool):
            raise ValueError
        if isinstance(v, str) and not v.strip():
            return math.nan  # spreadsheets write NaN as an empty cell
        return float(v)

    out = []
    for i, v in enumerate(df[col]):
        try:
            f = conv(v)
        except (TypeError, ValueError):
            raise InputError(f"column '{col}' needs a number or nan, row {i + 1} has {v!r}",
                             where=where) from None
        if math.isinf(f):
            raise InputError(f"column '{col}' is infinite in row {i + 1} (failures are nan)",
                             where=where)
        out.append(f)
    return pd.Series(out, index=df.index, dtype="float64")


def _as_count(v: object) -> int | None:
    """An integer >= 0 from text, an int or an integral float; ``None`` otherwise."""
    n = None
    if isinstance(v, bool):
        n = None
    elif isinstance(v, str):
        n = int(v) if v.strip().lstrip("+").isdigit() else None
    elif isinstance(v, int | np.integer):
        n = int(v)
    elif isinstance(v, float | np.floating) and float(v).is_integer():
        n = int(v)
    return n if n is not None and n >= 0 else None


def _to_int(df: pd.DataFrame, col: str, where: str | os.PathLike | None) -> pd.Series:
    out = []
    for i, v in enumerate(df[col]):
        n = _as_count(v)
        if n is None:
            raise InputError(f"column '{col}' needs an integer >= 0, row {i + 1} has {v!r}",
                             where=where)
        out.append(n)
    return pd.Series(out, index=df.index, dtype="int64")


def validate(df: pd.DataFrame, where: str | os.PathLike | None = None) -> pd.DataFrame:
    """Check columns, types and key uniqueness; return a typed, sorted copy.

    Raises :class:`InputError` naming ``where`` (a path) and the first offending row.
    """
    cols = _check_columns(df, where)
    df = df.loc[:, list(cols)].reset_index(drop=True)
    _check_strings(df, where)
    df["value"] = _to_float(df, where)
    df["n_frames"] = _to_int(df, "n_frames", where)
    if "frame" in cols:
        df["frame"] = _to_int(df, "frame", where)
    keys = list(UNIQUE_KEYS) + (["frame"] if "frame" in cols else [])
    dup = df.duplicated(subset=keys)
    if dup.any():
        row = df.loc[dup].iloc[0]
        raise InputError("duplicate result for " + ", ".join(f"{k}={row[k]}" for k in keys),
                         where=where)
    return sort_rows(df)


def sort_rows(df: pd.DataFrame) -> pd.DataFrame:
    """Stable canonical order: :data:`SORT_KEYS` (then ``frame``), strings by code point."""
    keys = list(SORT_KEYS) + (["frame"] if "frame" in df.columns else [])
    return df.sort_values(keys, kind="mergesort").reset_index(drop=True)


def to_csv_text(df: pd.DataFrame) -> str:
    """Serialise a validated frame with deterministic float text (see module docstring)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    cols = _columns_for(df)
    w.writerow(cols)
    for rec in df.itertuples(index=False):
        row = rec._asdict()
        w.writerow([format_float(row[c]) if c == "value" else row[c] for c in cols])
    return buf.getvalue()


def write_results(rows: Iterable[ResultRow] | pd.DataFrame, path: str | os.PathLike) -> Path:
    """Validate and write ``results.csv`` atomically.

    ``frames.csv`` when the rows carry ``frame``.
    """
    df = validate(to_frame(rows), where=path)
    return atomic_write_text(path, to_csv_text(df))


def _read_csv_text(path: str | os.PathLike, what: str) -> tuple[pd.DataFrame, Path]:
    """Every cell of a CSV file as text (names like "nan" or "NA" stay names; the value
    columns are parsed by the validators, with row-numbered errors)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} file not found", where=path)
    try:
        return pd.read_csv(path, dtype=str, keep_default_na=False, na_filter=False), path
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"not a readable CSV file: {e}", where=path) from None


def read_results(path: str | os.PathLike) -> pd.DataFrame:
    """Read and validate a ``results.csv`` / ``frames.csv``; typed columns, canonical order."""
    df, path = _read_csv_text(path, "results")
    return validate(df, where=path)


def rows_from_frame(df: pd.DataFrame) -> list[ResultRow]:
    """The typed rows of a validated frame (handy in tests and small tools)."""
    has_frame = "frame" in df.columns
    return [ResultRow(**{c: getattr(r, c) for c in RESULT_COLUMNS},
                      frame=int(r.frame) if has_frame else None)
            for r in df.itertuples(index=False)]


# --- runtime.csv (written by the runner, read by the runtime table) -------------------------
RUNTIME_COLUMNS = ("method", "mode", "device", "batch", "seconds_per_frame",
                   "frames_per_second")
RUNTIME_SORT_KEYS = ("method", "mode", "device", "batch")


def validate_runtime(df: pd.DataFrame, where: str | os.PathLike | None = None) -> pd.DataFrame:
    """Check ``runtime.csv`` columns and types; typed copy in canonical order.

    Several rows per (method, mode, device, batch) are allowed: repeated measurements.
    """
    missing = [c for c in RUNTIME_COLUMNS if c not in df.columns]
    extra = [c for c in df.columns if c not in RUNTIME_COLUMNS]
    if missing or extra:
        raise InputError(f"runtime columns must be {', '.join(RUNTIME_COLUMNS)} (missing: "
                         f"{', '.join(missing) or 'none'}; unexpected: "
                         f"{', '.join(map(str, extra)) or 'none'})", where=where)
    df = df.loc[:, list(RUNTIME_COLUMNS)].reset_index(drop=True)
    for col in ("method", "mode", "device"):
        bad = ~df[col].map(lambda v: isinstance(v, str) and v != "")
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"column '{col}' needs a non-empty string, row {i + 1}",
                             where=where)
    df["batch"] = _to_int(df, "batch", where)
    for col in ("seconds_per_frame", "frames_per_second"):
        df[col] = _to_float(df, where, col)
    keys = list(RUNTIME_SORT_KEYS) + ["seconds_per_frame"]
    return df.sort_values(keys, kind="mergesort").reset_index(drop=True)


def write_runtime(df: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Validate and write ``runtime.csv`` atomically with deterministic float text."""
    df = validate_runtime(pd.DataFrame(df), where=path)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(RUNTIME_COLUMNS)
    for rec in df.itertuples(index=False):
        w.writerow([format_float(v) if isinstance(v, float) else v for v in rec])
    return atomic_write_text(path, buf.getvalue())


def read_runtime(path: str | os.PathLike) -> pd.DataFrame:
    """Read and validate ``runtime.csv``."""
    df, path = _read_csv_text(path, "runtime")
    return validate_runtime(df, where=path)
