"""Table definitions as data: one versioned TOML file per table, next to this module.

A table is a grid of cells. Each row and each column carries *filters* on the results
(``method, dataset, split, perturbation, metric, hand``); a cell selects the results
matching ``defaults | row | column`` (row and column may not disagree), averages them per
sequence and reports the mean over sequences with a 95% object-stratified bootstrap
interval. ``hand = "mean"`` averages all hand rows of a sequence (right, left, both).

A ``before`` table (top level or per column) turns cells into "before → after" pairs: the
before value uses the same selection with the ``before`` filters swapped in (Table 3: the
perturbed input). Rows with ``reference = true`` (ground truth, perturbed input) are never
marked best. ``source = "runtime"`` tables read ``runtime.csv`` instead; their columns name
a ``field`` of that file.

Several training seeds (``[run] seeds``): the rows of a further seed are labelled
``<method>@seed<N>`` (:func:`seed_label`). A table any of whose row methods has such rows is
*seeded*: each cell reports the mean over seeds (the per-sequence values averaged over the
seeds, then the usual bootstrap interval over sequences) and the per-seed means
(``Cell.seed_means``, rendered as their range). A seeded table with ``compare_to = "<method>"``
judges every other row against that row's (:func:`judge`): "differs" only when the difference
of seed means exceeds both the seed spread and its 95% paired bootstrap interval. Tables
without seed rows compute exactly as before.

Installed plug-ins add tables through the ``grip_bench.tables`` entry-point group
(:func:`plugin_table_files`); they come after the suite's own and may not reuse an id.

File format (all keys listed in ``_TABLE_KEYS`` / ``_ROW_KEYS`` / ``_COLUMN_KEYS``)::

    id = "table4_future"          # = the file name
    version = 1                   # bump when the definition changes meaning
    title = "..."
    description = "..."
    notes = ["..."]
    [defaults]  split = "test"  perturbation = "none"
    [[columns]] metric = "mpvpe"  hand = "right"  group = "MPVPE"
    [[rows]]    label = "0"  method = "grip-future0"
    compare_to = "grip"           # optional: seeded tables judge each row against this method
    [[gates]]   row = "Ground truth"  metric = "hold_qs"  min = 80.0   # optional sanity gates:
                row = "..." metric = "..." max = 5.0 | between = ["row a", "row b"]

A gate is checked on the table's own cells (a row's value in the column of ``metric``,
report units) and printed under the table (PASS / FAIL with the measured value; NOT
CHECKED when a row it names has no value): a metric shows there that it can rank
(docs/contract.md, "Tables", "Sanity gates").
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ...core.constants import BOOTSTRAP_ALPHA, BOOTSTRAP_N, BOOTSTRAP_SEED, REPORT_DECIMALS
from ...core.errors import InputError
from ...core.registry import Registry
from ...results.stats import (
    AVERAGING_NOTES,
    CI,
    SEQUENCE_KEYS,
    bootstrap_ci,
    per_sequence,
    pooled_per_sequence,
    sequence_ci,
    stratified_draws,
)

if TYPE_CHECKING:
    from ...metrics.registry import MetricSpec

FILTER_KEYS = ("method", "dataset", "split", "perturbation", "metric", "hand")
SOURCES = ("results", "runtime")
RUNTIME_FIELDS = ("seconds_per_frame", "frames_per_second")
HAND_LABELS = {"right": "R-Hand", "left": "L-Hand", "both": "Both hands", "mean": ""}
MEAN_HAND = "mean"

_TABLE_KEYS = {
    "id": str,
    "version": int,
    "order": int,
    "title": str,
    "description": str,
    "notes": list,
    "source": str,
    "row_header": str,
    "defaults": dict,
    "before": dict,
    "compare_to": str,
    "rows": list,
    "columns": list,
    "gates": list,
}
_TABLE_REQUIRED = ("id", "version", "title", "description", "rows", "columns")
_ROW_KEYS = {"label": str, "group": str, "reference": bool, "mode": str,
             **{k: str for k in FILTER_KEYS}}
_COLUMN_KEYS = {"label": str, "group": str, "decimals": int, "before": dict, "field": str,
                "unit": str, "higher_is_better": bool, **{k: str for k in FILTER_KEYS}}
_GATE_KEYS = {"row": str, "metric": str, "min": float, "max": float, "between": list}


# --- specification --------------------------------------------------------------------------
@dataclass(frozen=True)
class RowSpec:
    """One row: a label, its filters (usually ``method``), an optional section heading."""

    label: str
    filters: dict
    group: str | None = None
    reference: bool = False
    mode: str | None = None  # runtime tables: restrict to one inference mode


@dataclass(frozen=True)
class ColumnSpec:
    """One column: filters (usually ``metric`` and ``hand``), header labels, optional pairing."""

    filters: dict
    label: str | None = None
    group: str | None = None
    before: dict | None = None
    decimals: int | None = None
    field: str | None = None  # runtime tables: a column of runtime.csv
    unit: str | None = None  # runtime tables (results tables take it from the metric)
    higher_is_better: bool | None = None  # runtime tables


@dataclass(frozen=True)
class GateSpec:
    """A sanity gate on one cell: ``row``'s value (report units) in the column of ``metric``
    is at least ``min``, at most ``max``, or strictly between the values of the two rows
    ``between`` (in either order)."""

    row: str
    metric: str
    min: float | None = None
    max: float | None = None
    between: tuple[str, str] | None = None

    def describe(self, name: str, unit: str) -> str:
        if self.between is not None:
            return f"{self.row} between {self.between[0]} and {self.between[1]} on {name}"
        bound = f">= {self.min:g}" if self.min is not None else f"<= {self.max:g}"
        return f"{self.row} {bound} {unit} on {name}"


@dataclass(frozen=True)
class TableSpec:
    """A table definition loaded from ``grip_bench/report/tables/<id>.toml``."""

    id: str
    version: int
    title: str
    description: str
    rows: tuple[RowSpec, ...]
    columns: tuple[ColumnSpec, ...]
    notes: tuple[str, ...] = ()
    source: str = "results"
    row_header: str = "Method"
    defaults: dict = field(default_factory=dict)
    order: int = 1000
    path: str = ""
    compare_to: str | None = None  # seeded tables: judge each row against this method's row
    gates: tuple[GateSpec, ...] = ()

    def describe(self) -> str:
        """One line for ``grip-bench ls tables``."""
        return (f"{self.id:<20} v{self.version}  {len(self.rows)} rows x "
                f"{len(self.columns)} columns  {self.title}")

    def cell_filters(self, row: RowSpec, col: ColumnSpec) -> dict:
        """Filters of the cell at (row, col): defaults, then row, then column."""
        return {**self.defaults, **row.filters, **col.filters}

    def methods(self) -> list[str]:
        """Every method id the table reads (rows, columns and ``before`` pairings)."""
        found = {self.cell_filters(r, c).get("method") for r in self.rows for c in self.columns}
        found |= {c.before.get("method") for c in self.columns if c.before}
        return sorted(m for m in found if m)


# --- loading and validation -----------------------------------------------------------------
def _check_keys(
    obj: object, allowed: dict, where: str, required: Iterable[str] = ()
) -> None:
    if not isinstance(obj, dict):
        raise InputError(f"expected a table of keys, got {type(obj).__name__}", where=where)
    for key, value in obj.items():
        if key not in allowed:
            raise InputError(f"unknown key '{key}' (allowed: {', '.join(sorted(allowed))})",
                             where=where)
        typ = allowed[key]
        if not isinstance(value, typ) or (typ is int and isinstance(value, bool)):
            raise InputError(f"'{key}' must be {typ.__name__}, got {value!r}", where=where)
    for key in required:
        if key not in obj:
            raise InputError(f"missing required field '{key}'", where=where)


def _filters(obj: dict, where: str) -> dict:
    flt = {k: obj[k] for k in FILTER_KEYS if k in obj}
    _check_keys(flt, {k: str for k in FILTER_KEYS}, where)
    return flt


def _row(obj: Any, where: str) -> RowSpec:
    _check_keys(obj, _ROW_KEYS, where, required=("label",))
    return RowSpec(label=obj["label"], filters=_filters(obj, where), group=obj.get("group"),
                   reference=obj.get("reference", False), mode=obj.get("mode"))


def _column(obj: Any, where: str, source: str) -> ColumnSpec:
    _check_keys(obj, _COLUMN_KEYS, where, required=("field",) if source == "runtime" else ())
    before = obj.get("before")
    if before is not None:
        _check_keys(before, {k: str for k in FILTER_KEYS}, f"{where}.before")
    if source == "runtime" and obj["field"] not in RUNTIME_FIELDS:
        raise InputError(f"'field' must be one of {', '.join(RUNTIME_FIELDS)}", where=where)
    return ColumnSpec(filters=_filters(obj, where), label=obj.get("label"),
                      group=obj.get("group"), before=before, decimals=obj.get("decimals"),
                      field=obj.get("field"), unit=obj.get("unit"),
                      higher_is_better=obj.get("higher_is_better"))


def _check_cells(spec: TableSpec, where: str) -> None:
    """Row and column filters agree, and every results cell names a method, metric and hand."""
    for i, row in enumerate(spec.rows):
        for j, col in enumerate(spec.columns):
            clash = [k for k in row.filters
                     if k in col.filters and row.filters[k] != col.filters[k]]
            cell = f"{where}: rows[{i}] x columns[{j}]"
            if clash:
                raise InputError(f"row and column disagree on '{clash[0]}'", where=cell)
            flt = spec.cell_filters(row, col)
            needed = ("method", "metric", "hand") if spec.source == "results" else ("method",)
            for key in needed:
                if key not in flt:
                    raise InputError(f"missing required field '{key}' (in the row, the "
                                     "column or [defaults])", where=cell)


def _metric_column(spec: TableSpec, metric: str) -> int | None:
    """Index of the first column of ``spec`` whose cells read ``metric`` (None: none)."""
    return next((j for j, c in enumerate(spec.columns)
                 if {**spec.defaults, **c.filters}.get("metric") == metric), None)


def _gate(obj: Any, where: str, spec: TableSpec) -> GateSpec:
    if isinstance(obj, dict):  # TOML writes 80 for 80.0: accept integers as bounds
        obj = {k: float(v) if k in ("min", "max") and isinstance(v, int)
               and not isinstance(v, bool) else v for k, v in obj.items()}
    _check_keys(obj, _GATE_KEYS, where, required=("row", "metric"))
    labels = [r.label for r in spec.rows]
    between = obj.get("between")
    named = [obj["row"], *(between or [])]
    bounds = [k for k in ("min", "max", "between") if k in obj]
    if len(bounds) != 1:
        raise InputError("a gate needs exactly one of 'min', 'max', 'between'", where=where)
    if between is not None and (len(between) != 2 or not all(isinstance(b, str)
                                                              for b in between)):
        raise InputError("'between' must name two rows", where=where)
    missing = [n for n in named if n not in labels]
    if missing:
        raise InputError(f"no row labelled {missing[0]!r}", where=where)
    if _metric_column(spec, obj["metric"]) is None:
        raise InputError(f"no column of metric {obj['metric']!r}", where=where)
    return GateSpec(row=obj["row"], metric=obj["metric"], min=obj.get("min"),
                    max=obj.get("max"), between=tuple(between) if between else None)


def parse_table(data: dict, where: str | Path) -> TableSpec:
    """Validate one parsed TOML document; errors name the file and the field."""
    where = str(where)
    _check_keys(data, _TABLE_KEYS, where, required=_TABLE_REQUIRED)
    source = data.get("source", "results")
    if source not in SOURCES:
        raise InputError(f"'source' must be one of {', '.join(SOURCES)}", where=where)
    if Path(where).suffix == ".toml" and Path(where).stem != data["id"]:
        raise InputError(f"id '{data['id']}' must match the file name", where=where)
    if not data["columns"]:
        raise InputError("a table needs at least one column", where=f"{where}: columns")
    notes = data.get("notes", [])
    if not all(isinstance(n, str) for n in notes):
        raise InputError("'notes' must be a list of strings", where=f"{where}: notes")
    _check_keys(data.get("defaults", {}), {k: str for k in FILTER_KEYS}, f"{where}: defaults")
    defaults = dict(data.get("defaults", {}))
    top_before = data.get("before")
    if top_before is not None:
        _check_keys(top_before, {k: str for k in FILTER_KEYS}, f"{where}: before")
    columns = []
    for j, c in enumerate(data["columns"]):
        col = _column(c, f"{where}: columns[{j}]", source)
        if col.before is None and top_before is not None:
            col = replace(col, before=dict(top_before))
        columns.append(col)
    spec = TableSpec(
        id=data["id"], version=data["version"], title=data["title"],
        description=data["description"], notes=tuple(notes), source=source,
        row_header=data.get("row_header", "Method"), defaults=defaults,
        rows=tuple(_row(r, f"{where}: rows[{i}]") for i, r in enumerate(data["rows"])),
        columns=tuple(columns), order=data.get("order", 1000), path=where,
        compare_to=data.get("compare_to"),
    )
    spec = replace(spec, gates=tuple(_gate(g, f"{where}: gates[{i}]", spec)
                                     for i, g in enumerate(data.get("gates", []))))
    _check_cells(spec, where)
    if spec.compare_to is not None and spec.compare_to not in {
            spec.cell_filters(r, spec.columns[0]).get("method") for r in spec.rows}:
        raise InputError(f"compare_to {spec.compare_to!r} is not the method of any row",
                         where=f"{where}: compare_to")
    return spec


def load_table(path: str | Path) -> TableSpec:
    """Read and validate one table file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"not valid TOML: {e}", where=path) from None
    except OSError as e:
        raise InputError(f"cannot read table file: {e.strerror}", where=path) from None
    return parse_table(data, path)


def _toml_files(package: str) -> list[Path]:
    """The ``*.toml`` files of a package's resource folder, sorted by name."""
    folder = resources.files(package)
    return sorted((Path(str(e)) for e in folder.iterdir() if e.name.endswith(".toml")),
                  key=lambda p: p.name)


def plugin_table_files(value: str) -> list[Path]:
    """Table files of one ``grip_bench.tables`` entry point: ``"pkg.tables"`` names a
    package whose resource folder holds ``*.toml`` tables; ``"pkg.mod:attr"`` names an
    iterable of paths, or a callable returning one. Errors name the entry point."""
    from ...core.plugins import TABLES_GROUP, import_plugin

    name, _, attr = (part.strip() for part in value.partition(":"))
    where = f"entry points {TABLES_GROUP}: {value}"
    module = import_plugin(name, TABLES_GROUP)
    if not attr:
        if not hasattr(module, "__path__"):
            raise InputError("names a module, not a package with table files (use "
                             "'module:attribute' for a module listing its paths)", where)
        return _toml_files(name)
    if not hasattr(module, attr):
        raise InputError(f"module {name!r} has no attribute {attr!r}", where)
    found = getattr(module, attr)
    try:
        paths = [Path(p) for p in (found() if callable(found) else found)]
    except Exception as e:  # noqa: BLE001 - any failure of third-party code
        raise InputError(f"cannot list table paths: {type(e).__name__}: {e}", where) from e
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise InputError(f"table file(s) not found: {', '.join(missing)}", where)
    return paths


def _plugin_specs() -> list[TableSpec]:
    from ...core.plugins import TABLES_GROUP, entry_values

    specs = []
    for value in entry_values(TABLES_GROUP):
        for path in plugin_table_files(value):
            try:
                specs.append(load_table(path))
            except InputError as e:
                raise InputError(f"plug-in table of {value!r}: {e.what}", e.where) from e
    return specs


def _all_tables() -> Registry[TableSpec]:
    """The suite's tables (this folder), then those of installed plug-ins; an id used twice
    is an error naming the second file."""
    reg: Registry[TableSpec] = Registry("table")
    builtin = [load_table(p) for p in _toml_files(__name__)]
    for spec in [*sorted(builtin, key=lambda s: (s.order, s.id)),
                 *sorted(_plugin_specs(), key=lambda s: (s.order, s.id))]:
        if spec.id in reg:
            raise InputError(f"table id {spec.id!r} is already defined by "
                             f"{reg.get(spec.id).path}", spec.path)
        reg.register(spec.id, spec)
    return reg


TABLES: Registry[TableSpec] = _all_tables()


# --- computed tables ------------------------------------------------------------------------
@dataclass(frozen=True)
class Cell:
    """A computed cell. ``ci`` is ``None`` when no result matched (rendered "–")."""

    ci: CI | None
    before: CI | None = None
    paired: bool = False
    before_method: str | None = None
    best: bool = False
    # not the best, but the best of its column does not beat it: bold too (``mark_tied``)
    tied: bool = False
    metric: str | None = None
    unit: str = ""
    higher_is_better: bool | None = None
    decimals: int = 2
    filters: dict = field(default_factory=dict)
    # seeded tables only: the mean of each seed (first seed first); empty otherwise
    seed_means: tuple[float, ...] = ()
    judged: Judgement | None = None  # seeded tables with compare_to: this cell vs the reference


@dataclass(frozen=True)
class Column:
    """A computed column header: top-level ``group``, sub ``label``, unit and direction.

    ``unit`` and ``higher_is_better`` are ``None`` when the metric varies by row (Table 3).
    """

    group: str
    label: str
    unit: str | None
    higher_is_better: bool | None
    paired: bool = False


@dataclass(frozen=True)
class Row:
    """A computed row; ``group`` starts a new section when it differs from the previous row."""

    label: str
    cells: tuple[Cell, ...]
    group: str | None = None
    group_unit: str | None = None
    group_higher_is_better: bool | None = None
    reference: bool = False
    verdict: str | None = None  # seeded tables with compare_to: the row's verdict text
    # a trivial control (flat hand, mean pose): ranked, never marked best; where it scores as
    # well as the best method, no cell of that column is marked (``mark_best``)
    control: bool = False


@dataclass(frozen=True)
class TableData:
    """Everything a renderer needs; produced by :func:`compute_table` or a leaderboard."""

    id: str
    title: str
    version: int
    description: str
    row_header: str
    columns: tuple[Column, ...]
    rows: tuple[Row, ...]
    notes: tuple[str, ...] = ()
    n_seeds: int = 1  # > 1: a seeded table (cells carry seed_means)
    verdict_header: str | None = None  # the verdict column's header (seeded, compare_to)
    # (check, passed: True / False / None = not checked, measured), also in the notes
    gates: tuple[tuple[str, bool | None, str], ...] = ()


# --- seeds -----------------------------------------------------------------------------------
SEED_TAG = "@seed"  # "<method>@seed<N>": the result rows of a further training seed
_SEED_LABEL = re.compile(r"^(?P<method>.+)@seed(?P<seed>\d+)$")
VERDICT_DIFFERS, VERDICT_NOISE, VERDICT_REFERENCE = "differs", "within noise", "reference"


def seed_label(method: str, seed: int) -> str:
    """The ``method`` column of a further seed's rows: ``grip`` -> ``grip@seed1``."""
    return f"{method}{SEED_TAG}{int(seed)}"


def split_seed_label(label: str) -> tuple[str, int | None]:
    """``"grip@seed1"`` -> ``("grip", 1)``; a plain method name -> ``(name, None)``."""
    m = _SEED_LABEL.match(label)
    return (m["method"], int(m["seed"])) if m else (label, None)


def is_seed_label(label: str) -> bool:
    """Whether ``label`` names a further seed's rows (kept out of leaderboards, viewers)."""
    return split_seed_label(label)[1] is not None


def seed_labels(methods: Iterable[str]) -> dict[str, list[str]]:
    """``{method: [its further seeds' labels, by seed]}`` among the labels ``methods``."""
    found: dict[str, list[tuple[int, str]]] = {}
    for label in set(methods):
        base, seed = split_seed_label(label)
        if seed is not None:
            found.setdefault(base, []).append((seed, label))
    return {m: [lab for _, lab in sorted(v)] for m, v in found.items()}


@dataclass(frozen=True)
class Judgement:
    """A row's cell against the reference row's (seeded tables, ``compare_to``).

    ``diff``: seed mean of the row minus the reference's; ``ci``: its 95% paired bootstrap
    interval over the test sequences both have (the seed-averaged per-sequence values);
    ``spread``: the larger seed range (max - min of the per-seed means) of the two rows;
    ``verdict``: :data:`VERDICT_DIFFERS`, :data:`VERDICT_NOISE` or ``None`` (not judged:
    fewer than two seeds on a row, or no finite value).
    """

    diff: float
    ci: CI | None
    spread: float
    verdict: str | None


def judge(row_seed_means: Sequence[float], ref_seed_means: Sequence[float],
          diff_ci: CI | None) -> Judgement:
    """Whether a difference is real: the difference of the two rows' seed means must exceed
    both the seed spread (the larger max - min over seeds of the two rows) and the 95%
    interval of the difference (the paired bootstrap interval ``diff_ci`` excludes 0).

    ``row_seed_means`` / ``ref_seed_means``: per-seed means (n_seeds,) of the row and of the
    reference. Fewer than two finite seeds on either side, or no interval: not judged
    (``verdict`` None, NaN numbers where they cannot be computed).
    """
    a = np.asarray(row_seed_means, dtype=np.float64)
    b = np.asarray(ref_seed_means, dtype=np.float64)
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if len(a) < 2 or len(b) < 2:
        diff = float(a.mean() - b.mean()) if len(a) and len(b) else np.nan
        return Judgement(diff, diff_ci, np.nan, None)
    diff = float(a.mean() - b.mean())
    spread = float(max(np.ptp(a), np.ptp(b)))
    if diff_ci is None or not np.isfinite(diff_ci.lo) or not np.isfinite(diff_ci.hi):
        return Judgement(diff, diff_ci, spread, None)
    beyond_interval = diff_ci.lo > 0.0 or diff_ci.hi < 0.0
    beyond_spread = abs(diff) > spread
    verdict = VERDICT_DIFFERS if beyond_interval and beyond_spread else VERDICT_NOISE
    return Judgement(diff, diff_ci, spread, verdict)


def paired_difference_ci(
    a: pd.DataFrame, b: pd.DataFrame, n_boot: int = BOOTSTRAP_N, seed: int = BOOTSTRAP_SEED,
    alpha: float = BOOTSTRAP_ALPHA, averaging: str = "sequence",
) -> CI:
    """Mean of ``a`` minus mean of ``b`` over the sequences both have a finite value for,
    with its object-stratified paired bootstrap interval: each resample draws sequences once
    and takes both means on them, so what the two rows share (the sequences' difficulty)
    cancels. ``a`` / ``b``: results rows (several seeds' rows average per sequence, as in a
    seeded cell); ``averaging="pooled"`` weights each sequence by its frames, per row.
    ``n_nan`` counts the sequences of either side left out.
    """
    per = pooled_per_sequence if averaging == "pooled" else per_sequence
    pa, pb = per(a), per(b)
    if averaging != "pooled":
        pa, pb = pa.assign(weight=1.0), pb.assign(weight=1.0)
    keys = list(SEQUENCE_KEYS)
    m = pa.merge(pb, on=keys, how="outer", suffixes=("_a", "_b"), sort=True)
    va, vb = m["value_a"].to_numpy(np.float64), m["value_b"].to_numpy(np.float64)
    wa, wb = m["weight_a"].to_numpy(np.float64), m["weight_b"].to_numpy(np.float64)
    ok = np.isfinite(va) & np.isfinite(vb) & (wa > 0) & (wb > 0)
    n, n_nan = int(ok.sum()), int((~ok).sum())
    if n == 0:
        return CI(np.nan, np.nan, np.nan, 0, n_nan)
    va, vb, wa, wb = va[ok], vb[ok], wa[ok], wb[ok]
    strata = m["object"].to_numpy()[ok]
    mean = float((va * wa).sum() / wa.sum() - (vb * wb).sum() / wb.sum())
    order, idx = stratified_draws(strata, (vb, va), n_boot, seed)
    va, vb, wa, wb = va[order], vb[order], wa[order], wb[order]
    boots = ((va[idx] * wa[idx]).sum(axis=1) / wa[idx].sum(axis=1)
             - (vb[idx] * wb[idx]).sum(axis=1) / wb[idx].sum(axis=1))
    lo, hi = np.quantile(boots, [alpha / 2, 1 - alpha / 2])
    return CI(mean, float(lo), float(hi), n, n_nan)


def _metric_info(
    metric: str | None, registry: Registry[MetricSpec] | None, data_units: Iterable[str]
) -> tuple[str, bool | None, str]:
    """(unit, higher_is_better, display name) from the metric registry, else from the data."""
    if metric is not None and registry is not None and metric in registry:
        m = registry.get(metric)
        return m.unit, m.higher_is_better, m.name
    units = sorted(set(data_units))
    return (units[0] if len(units) == 1 else ""), None, metric or ""


def default_metric_registry() -> Registry[MetricSpec] | None:
    """The suite's metric registry, or ``None`` while it is not available."""
    try:
        from ...metrics.registry import METRICS
    except ImportError:
        return None
    return METRICS


class _Index:
    """Results grouped once by (method, metric, perturbation), so each cell filters a few rows."""

    def __init__(self, df: pd.DataFrame):
        self.df = df
        self.groups = {k: g for k, g in df.groupby(["method", "metric", "perturbation"],
                                                   sort=False)}
        self.seeds = seed_labels(df["method"].unique()) if len(df) else {}

    def seeded(self, flt: dict) -> list[pd.DataFrame]:
        """The rows of ``flt`` for its method's first seed, then for each further seed
        (``<method>@seed<N>``), empty selections left out."""
        labels = [flt["method"], *self.seeds.get(flt["method"], [])]
        return [r for r in (self.select({**flt, "method": m}) for m in labels) if len(r)]

    def select(self, flt: dict) -> pd.DataFrame:
        parts = [g for (m, me, p), g in self.groups.items()
                 if m == flt["method"] and me == flt["metric"]
                 and flt.get("perturbation", p) == p]
        if not parts:
            return self.df.iloc[:0]
        rows = pd.concat(parts) if len(parts) > 1 else parts[0]
        for key in ("dataset", "split"):
            if key in flt:
                rows = rows[rows[key] == flt[key]]
        if flt["hand"] != MEAN_HAND:
            rows = rows[rows["hand"] == flt["hand"]]
        return rows


def _results_cell(
    index: _Index,
    flt: dict,
    col: ColumnSpec,
    registry: Registry[MetricSpec] | None,
    n_boot: int,
    seed: int,
    averaging: str = "sequence",
) -> Cell:
    rows = index.select(flt)
    unit, hib, _ = _metric_info(flt["metric"], registry, rows["unit"])
    ci = sequence_ci(rows, n_boot=n_boot, seed=seed, averaging=averaging) if len(rows) else None
    before, bflt = None, {**flt, **(col.before or {})}
    if col.before is not None:
        brows = index.select(bflt)
        before = (sequence_ci(brows, n_boot=n_boot, seed=seed, averaging=averaging)
                  if len(brows) else None)
    return Cell(ci=ci, before=before, paired=col.before is not None,
                before_method=bflt["method"] if col.before is not None else None,
                metric=flt["metric"],
                unit=unit, higher_is_better=hib, decimals=_decimals(col), filters=flt)


def _seeded_ci(parts: list[pd.DataFrame], n_boot: int, seed: int,
               averaging: str) -> tuple[CI | None, tuple[float, ...]]:
    """(CI of the seed mean, per-seed means) of a cell's per-seed rows: the rows of every
    seed average per sequence (each seed weighs the same where every seed has the
    sequence), then the mean over sequences with its bootstrap interval."""
    if not parts:
        return None, ()
    ci = sequence_ci(pd.concat(parts) if len(parts) > 1 else parts[0], n_boot=n_boot,
                     seed=seed, averaging=averaging)
    means = tuple(sequence_ci(r, n_boot=1, seed=seed, averaging=averaging).mean
                  for r in parts)
    return ci, means


def _seeded_cell(
    index: _Index,
    flt: dict,
    col: ColumnSpec,
    registry: Registry[MetricSpec] | None,
    n_boot: int,
    seed: int,
    averaging: str = "sequence",
) -> Cell:
    """A cell of a seeded table: the mean over seeds, its interval, the per-seed means."""
    parts = index.seeded(flt)
    unit, hib, _ = _metric_info(flt["metric"], registry,
                                pd.concat(parts)["unit"] if parts else [])
    ci, means = _seeded_ci(parts, n_boot, seed, averaging)
    before, bflt = None, {**flt, **(col.before or {})}
    if col.before is not None:
        before, _ = _seeded_ci(index.seeded(bflt), n_boot, seed, averaging)
    return Cell(ci=ci, before=before, paired=col.before is not None,
                before_method=bflt["method"] if col.before is not None else None,
                metric=flt["metric"], unit=unit, higher_is_better=hib, decimals=_decimals(col),
                filters=flt, seed_means=means)


def _judged_rows(rows: list[Row], cell_rows: list[list[pd.DataFrame | None]], ref: int,
                 n_boot: int, seed: int, averaging: str,
                 headers: Sequence[Column]) -> list[Row]:
    """Rows with each cell judged against row ``ref``'s (:func:`judge`) and a verdict text:
    "reference", "within noise", "differs: <columns> (worse / better)" or "–" (none judged).

    ``cell_rows[i][j]``: the results rows (all seeds) of cell (i, j), None when empty.
    """
    out = []
    for i, row in enumerate(rows):
        if i == ref:
            out.append(replace(row, verdict=VERDICT_REFERENCE))
            continue
        cells, differs, judged = [], [], 0
        for j, cell in enumerate(row.cells):
            a, b = cell_rows[i][j], cell_rows[ref][j]
            if a is None or b is None:
                cells.append(cell)
                continue
            diff_ci = paired_difference_ci(a, b, n_boot=n_boot, seed=seed, averaging=averaging)
            jd = judge(cell.seed_means, rows[ref].cells[j].seed_means, diff_ci)
            cells.append(replace(cell, judged=jd))
            judged += jd.verdict is not None
            if jd.verdict == VERDICT_DIFFERS:
                differs.append(f"{headers[j].group} {headers[j].label}".strip()
                               + _direction_word(jd.diff, cell.higher_is_better))
        text = (f"{VERDICT_DIFFERS}: {', '.join(differs)}" if differs
                else VERDICT_NOISE if judged else "–")
        out.append(replace(row, cells=tuple(cells), verdict=text))
    return out


def _direction_word(diff: float, higher_is_better: bool | None) -> str:
    if higher_is_better is None:
        return " (higher)" if diff > 0 else " (lower)"
    return " (better)" if (diff > 0) == higher_is_better else " (worse)"


def seeds_note(n_seeds: int) -> str:
    """The note of a seeded table: what its numbers are."""
    return (f"Seeds: each trained method's cell is the mean over its {n_seeds} training "
            "seeds ([run] seeds; further seeds' rows are <method>@seed<N> in results.csv); "
            "[lo, hi] is the 95% bootstrap interval over test sequences of the per-sequence "
            "values averaged over seeds; {min–max} is the range of the per-seed means.")


def verdict_note(label: str) -> str:
    """The note of a judged table: the rule of its verdict column."""
    return (f"Verdict vs {label}: \"differs\" only when the difference of seed means exceeds "
            "both the seed spread (the larger max - min over seeds of the two rows) and its "
            "95% paired bootstrap interval over test sequences (the interval excludes 0), "
            "per column; otherwise \"within noise\"; \"–\" where a row has fewer than two "
            "seeds.")


def _decimals(col: ColumnSpec) -> int:
    return REPORT_DECIMALS if col.decimals is None else col.decimals


def _column_header(
    spec: TableSpec, col: ColumnSpec, registry: Registry[MetricSpec] | None
) -> Column:
    """Header of a column; unit and arrow only when the column fixes the metric."""
    metric = {**spec.defaults, **col.filters}.get("metric")
    if spec.source == "runtime":
        unit, hib, name = col.unit or "", col.higher_is_better, col.field
    elif metric is not None:
        unit, hib, name = _metric_info(metric, registry, [])
    else:
        unit, hib, name = None, None, ""
    hand = {**spec.defaults, **col.filters}.get("hand")
    label = col.label if col.label is not None else HAND_LABELS.get(hand, hand or "")
    return Column(group=col.group or name or "", label=label, unit=unit,
                  higher_is_better=hib, paired=col.before is not None)


def _shown(c: Cell) -> float | None:
    """A cell's value as displayed, signed so that larger is better; None when unranked."""
    if c.ci is None or np.isnan(c.ci.mean) or c.higher_is_better is None:
        return None
    return round(c.ci.mean, c.decimals) * (1 if c.higher_is_better else -1)


def best_values(rows: Sequence[Row]) -> tuple[dict, set]:
    """The best shown value per (column, metric) among the ranked rows (not reference, not
    control), and the keys where a control row scores as well or better: there the column
    cannot tell a method from a trivial hand, and nothing is marked best."""
    best: dict[tuple[int, str | None], float] = {}
    for row in rows:
        for j, c in enumerate(row.cells):
            v = None if row.reference or row.control else _shown(c)
            if v is not None:
                best[(j, c.metric)] = max(best.get((j, c.metric), -np.inf), v)
    tied = {(j, c.metric) for row in rows if row.control and not row.reference
            for j, c in enumerate(row.cells)
            if _shown(c) is not None and (j, c.metric) in best
            and _shown(c) >= best[(j, c.metric)]}
    return best, tied


def mark_best(rows: list[Row]) -> list[Row]:
    """Bold the best shown value per (column, metric) among ranked rows; ties all bold.

    Values are compared as displayed (rounded), so two cells that read the same are both
    bold. Paired cells compare their "after" value. Reference and control rows are never
    bold, and a column where a control row reads as well as the best method marks none
    (:func:`best_values`).
    """
    best, tied = best_values(rows)
    out = []
    for row in rows:
        cells = []
        for j, c in enumerate(row.cells):
            v = None if row.reference or row.control else _shown(c)
            key = (j, c.metric)
            cells.append(replace(c, best=v is not None and key not in tied and v == best[key]))
        out.append(replace(row, cells=tuple(cells)))
    return out


TIED_NOTE = ("Bold: the best value of each column among the methods, and every method the "
             "best does not beat: their per-sequence difference has a paired 95% bootstrap "
             "interval (sequences resampled within each object, seeded) that includes 0.")


def mark_tied(rows: list[Row], cell_results: Callable[[Cell], pd.DataFrame | None],
              n_boot: int = BOOTSTRAP_N, seed: int = BOOTSTRAP_SEED,
              averaging: str = "sequence") -> list[Row]:
    """``Cell.tied`` on the ranked cells that the best cell of their (column, metric) does
    not beat on the same sequences (:func:`paired_difference_ci` of the two includes 0).

    Unpaired intervals overlap for most methods (the sequences' difficulty dominates them);
    the paired difference cancels that, so a tie here means the data cannot order the two.
    ``cell_results(cell)``: the results rows a cell was computed from (None or empty: not
    compared). Reference and control rows are never tied, as they are never best.
    """
    best: dict[tuple[int, str | None], Cell] = {}
    for row in rows:
        for j, c in enumerate(row.cells):
            if c.best:
                best.setdefault((j, c.metric), c)
    refs: dict[tuple[int, str | None], pd.DataFrame | None] = {}
    out = []
    for row in rows:
        cells = list(row.cells)
        for j, c in enumerate(cells):
            key = (j, c.metric)
            if row.reference or row.control or c.best or key not in best or _shown(c) is None:
                continue
            if key not in refs:
                refs[key] = cell_results(best[key])
            mine, ref = cell_results(c), refs[key]
            if mine is None or ref is None or not len(mine) or not len(ref):
                continue
            d = paired_difference_ci(mine, ref, n_boot=n_boot, seed=seed, averaging=averaging)
            cells[j] = replace(c, tied=bool(d.n > 0 and d.lo <= 0.0 <= d.hi))
        out.append(replace(row, cells=tuple(cells)))
    return out


def _row_group_info(
    spec: TableSpec, row: RowSpec, registry: Registry[MetricSpec] | None
) -> tuple[str | None, bool | None]:
    """Unit and direction for a row's section heading when the row fixes the metric."""
    metric = row.filters.get("metric")
    if metric is None or any("metric" in c.filters for c in spec.columns):
        return None, None
    unit, hib, _ = _metric_info(metric, registry, [])
    return unit, hib


def compute_table(
    spec: TableSpec,
    results: pd.DataFrame | None = None,
    runtime: pd.DataFrame | None = None,
    *,
    dataset: str | None = None,
    metrics_registry: Registry[MetricSpec] | None = None,
    n_boot: int = BOOTSTRAP_N,
    seed: int = BOOTSTRAP_SEED,
    averaging: str = "sequence",
) -> TableData:
    """Fill ``spec`` from validated results (or runtime) frames; missing cells stay empty.

    ``averaging``: "sequence" (every sequence weighs the same) or "pooled" (weighted by its
    evaluated frames, as GRIP's code); results tables state it in their last note."""
    registry = metrics_registry if metrics_registry is not None else default_metric_registry()
    columns = tuple(_column_header(spec, c, registry) for c in spec.columns)
    n_seeds, verdict_header = 1, None
    if spec.source == "runtime":
        rows = _runtime_rows(spec, runtime, n_boot=n_boot, seed=seed)
    else:
        index = _Index(_empty_results() if results is None else results)
        n_seeds = _table_seeds(spec, index)
        if n_seeds > 1:
            rows, verdict_header = _seeded_rows(spec, index, dataset, registry, n_boot, seed,
                                                averaging, columns)
        else:
            rows = _results_rows(spec, results, dataset, registry, n_boot, seed, averaging)
    notes = spec.notes
    if spec.source != "runtime":
        notes = (*notes, AVERAGING_NOTES[averaging])
    if n_seeds > 1:
        notes = (*notes, seeds_note(n_seeds))
        if verdict_header is not None:
            notes = (*notes, verdict_note(verdict_header.removeprefix("Verdict vs ")))
    gates = check_gates(spec, rows, registry)
    notes = (*notes, *(f"Sanity gate {gate_line(*g)}" for g in gates))
    rows = mark_best(rows)
    if spec.source != "runtime":
        rows = mark_tied(rows, lambda c: _cell_results(index, c), n_boot, seed, averaging)
        notes = (*notes, TIED_NOTE)
    return TableData(id=spec.id, title=spec.title, version=spec.version,
                     description=spec.description, row_header=spec.row_header,
                     columns=columns, rows=tuple(rows), notes=tuple(notes),
                     n_seeds=n_seeds, verdict_header=verdict_header, gates=gates)


def check_gates(spec: TableSpec, rows: Sequence[Row], registry: Registry[MetricSpec] | None
                ) -> tuple[tuple[str, bool | None, str], ...]:
    """(check, passed, measured) of each of ``spec.gates`` on the computed ``rows`` (one
    per row spec, in order); passed is None (not checked) when a row it names has no value
    (the run did not evaluate that method: a profile without the table's controls)."""
    out = []
    for g in spec.gates:
        j = _metric_column(spec, g.metric)
        value = {r.label: (r.cells[j].ci.mean if r.cells[j].ci is not None else np.nan)
                 for r in rows}
        unit, _, name = _metric_info(g.metric, registry, [])
        v = value.get(g.row, np.nan)
        named = [v, *(value.get(x, np.nan) for x in g.between or ())]
        if not np.isfinite(named).all():
            missing = [r for r, x in zip([g.row, *(g.between or ())], named, strict=True)
                       if not np.isfinite(x)]
            out.append((g.describe(name, unit), None, f"no value for {', '.join(missing)}"))
            continue
        if g.between is not None:
            a, b = sorted(named[1:])
            ok, got = bool(a < v < b), f"{v:.1f} against {a:.1f} and {b:.1f}"
        else:
            ok = bool(v >= g.min) if g.min is not None else bool(v <= g.max)
            got = f"{v:.1f} {unit}"
        out.append((g.describe(name, unit), ok, got))
    return tuple(out)


def gate_line(name: str, ok: bool | None, got: str) -> str:
    """One checked gate as printed under its table and in the run log: PASS, FAIL or NOT
    CHECKED (a gate whose rows have no value), the check, the measured value."""
    if ok is None:
        return f"NOT CHECKED: {name} ({got})"
    return f"{'PASS' if ok else 'FAIL'}: {name} (measured {got})"


def _empty_results() -> pd.DataFrame:
    return pd.DataFrame({c: [] for c in ("method", "metric", "perturbation", "dataset",
                                         "split", "hand", "unit", "value")})


def _table_seeds(spec: TableSpec, index: _Index) -> int:
    """The most seeds any row method of ``spec`` has in the results (1: not seeded)."""
    methods = {spec.cell_filters(r, c).get("method") for r in spec.rows for c in spec.columns}
    return 1 + max((len(index.seeds.get(m, [])) for m in methods if m), default=0)


def _seeded_rows(
    spec: TableSpec,
    index: _Index,
    dataset: str | None,
    registry: Registry[MetricSpec] | None,
    n_boot: int,
    seed: int,
    averaging: str,
    columns: Sequence[Column],
) -> tuple[list[Row], str | None]:
    """Rows of a seeded table and, with ``compare_to``, their verdicts and its header."""
    rows, cell_rows = [], []
    for r in spec.rows:
        cells, raw = [], []
        for c in spec.columns:
            flt = spec.cell_filters(r, c)
            if dataset is not None:
                flt["dataset"] = dataset
            cells.append(_seeded_cell(index, flt, c, registry, n_boot, seed, averaging))
            parts = index.seeded(flt)
            raw.append(pd.concat(parts) if parts else None)
        unit, hib = _row_group_info(spec, r, registry)
        rows.append(Row(label=r.label, cells=tuple(cells), group=r.group, group_unit=unit,
                        group_higher_is_better=hib, reference=r.reference))
        cell_rows.append(raw)
    if spec.compare_to is None:
        return rows, None
    ref = next(i for i, r in enumerate(spec.rows)
               if spec.cell_filters(r, spec.columns[0]).get("method") == spec.compare_to)
    rows = _judged_rows(rows, cell_rows, ref, n_boot, seed, averaging, columns)
    return rows, f"Verdict vs {spec.rows[ref].label}"


def _cell_results(index: _Index, cell: Cell) -> pd.DataFrame | None:
    """The results rows behind a computed cell (every seed's, for a seeded table)."""
    if not cell.filters:
        return None
    parts = index.seeded(cell.filters)
    return pd.concat(parts) if len(parts) > 1 else (parts[0] if parts else None)


def _results_rows(
    spec: TableSpec,
    results: pd.DataFrame | None,
    dataset: str | None,
    registry: Registry[MetricSpec] | None,
    n_boot: int,
    seed: int,
    averaging: str = "sequence",
) -> list[Row]:
    if results is None:
        results = pd.DataFrame({c: [] for c in ("method", "metric", "perturbation", "dataset",
                                                "split", "hand", "unit", "value")})
    index = _Index(results)
    rows = []
    for r in spec.rows:
        cells = []
        for c in spec.columns:
            flt = spec.cell_filters(r, c)
            if dataset is not None:
                flt["dataset"] = dataset
            cells.append(_results_cell(index, flt, c, registry, n_boot, seed, averaging))
        unit, hib = _row_group_info(spec, r, registry)
        rows.append(Row(label=r.label, cells=tuple(cells), group=r.group, group_unit=unit,
                        group_higher_is_better=hib, reference=r.reference))
    return rows


def _runtime_keys(runtime: pd.DataFrame, row: RowSpec) -> list[tuple]:
    sel = runtime[runtime["method"] == row.filters.get("method")]
    if row.mode is not None:
        sel = sel[sel["mode"] == row.mode]
    return sorted(set(zip(sel["mode"], sel["device"], sel["batch"], strict=True)))


def _runtime_rows(
    spec: TableSpec, runtime: pd.DataFrame | None, n_boot: int, seed: int
) -> list[Row]:
    """One row per (listed method) x (mode, device, batch) present; "–" when absent.

    Repeated measurements give a mean and a bootstrap interval over the repeats.
    """
    if runtime is None:
        runtime = pd.DataFrame({c: [] for c in ("method", "mode", "device", "batch")})
    rows = []
    for r in spec.rows:
        keys = _runtime_keys(runtime, r) or [None]
        for key in keys:
            label = r.label if key is None else f"{r.label} ({key[0]}, {key[1]}, batch {key[2]})"
            sel = runtime.iloc[:0]
            if key is not None:
                m = ((runtime["method"] == r.filters.get("method")) & (runtime["mode"] == key[0])
                     & (runtime["device"] == key[1]) & (runtime["batch"] == key[2]))
                sel = runtime[m]
            where = {"method": r.filters.get("method")}
            if key is not None:
                where.update(mode=key[0], device=key[1], batch=key[2])
            cells = tuple(_runtime_cell(sel, c, where, n_boot, seed) for c in spec.columns)
            rows.append(Row(label=label, cells=cells, group=r.group, reference=r.reference))
    return rows


def _runtime_cell(sel: pd.DataFrame, col: ColumnSpec, where: dict, n_boot: int,
                  seed: int) -> Cell:
    ci = None
    if len(sel):
        ci = bootstrap_ci(sel[col.field].to_numpy(dtype=np.float64), n_boot=n_boot, seed=seed)
    return Cell(ci=ci, metric=col.field, unit=col.unit or "",
                higher_is_better=col.higher_is_better, decimals=_decimals(col),
                filters={**where, "field": col.field})
