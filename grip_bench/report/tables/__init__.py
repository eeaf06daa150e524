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
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ...core.constants import BOOTSTRAP_N, BOOTSTRAP_SEED, REPORT_DECIMALS
from ...core.errors import InputError
from ...core.registry import Registry
from ...results.stats import AVERAGING_NOTES, CI, bootstrap_ci, sequence_ci

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
    "rows": list,
    "columns": list,
}
_TABLE_REQUIRED = ("id", "version", "title", "description", "rows", "columns")
_ROW_KEYS = {"label": str, "group": str, "reference": bool, "mode": str,
             **{k: str for k in FILTER_KEYS}}
_COLUMN_KEYS = {"label": str, "group": str, "decimals": int, "before": dict, "field": str,
                "unit": str, "higher_is_better": bool, **{k: str for k in FILTER_KEYS}}


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
    )
    _check_cells(spec, where)
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
    metric: str | None = None
    unit: str = ""
    higher_is_better: bool | None = None
    decimals: int = 2
    filters: dict = field(default_factory=dict)


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


def mark_best(rows: list[Row]) -> list[Row]:
    """Bold the best shown value per (column, metric) among non-reference rows; ties all bold.

    Values are compared as displayed (rounded), so two cells that read the same are both
    bold. Paired cells compare their "after" value.
    """
    best: dict[tuple[int, str | None], float] = {}
    for row in rows:
        for j, c in enumerate(row.cells):
            if row.reference or c.ci is None or np.isnan(c.ci.mean) or c.higher_is_better is None:
                continue
            v = round(c.ci.mean, c.decimals) * (1 if c.higher_is_better else -1)
            key = (j, c.metric)
            best[key] = max(best.get(key, -np.inf), v)
    out = []
    for row in rows:
        cells = []
        for j, c in enumerate(row.cells):
            ok = (not row.reference and c.ci is not None and not np.isnan(c.ci.mean)
                  and c.higher_is_better is not None)
            v = round(c.ci.mean, c.decimals) * (1 if c.higher_is_better else -1) if ok else None
            cells.append(replace(c, best=ok and v == best[(j, c.metric)]))
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
    if spec.source == "runtime":
        rows = _runtime_rows(spec, runtime, n_boot=n_boot, seed=seed)
    else:
        rows = _results_rows(spec, results, dataset, registry, n_boot, seed, averaging)
    notes = spec.notes
    if spec.source != "runtime":
        notes = (*notes, AVERAGING_NOTES[averaging])
    return TableData(id=spec.id, title=spec.title, version=spec.version,
                     description=spec.description, row_header=spec.row_header,
                     columns=columns, rows=tuple(mark_best(rows)), notes=tuple(notes))


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
