"""Leaderboard: one line per (method, metric, hand) with a 95% bootstrap interval.

Columns: docs/contract.md, "Results".

Values are averaged per sequence first (repeats and, for ``hand = "mean"`` tables, hands),
then over sequences; the interval resamples sequences within each object (stratified,
seeded). ``n_sequences`` counts the sequences with a finite value; ``n_nan`` (an extra
column of the returned frame, not of ``leaderboard.csv``) counts those that gave NaN.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ..core.constants import BOOTSTRAP_N, BOOTSTRAP_SEED
from ..core.errors import InputError
from ..core.io import atomic_write_text
from ..results.schema import format_float
from ..results.stats import AVERAGING_NOTES, CI, sequence_ci

if TYPE_CHECKING:
    from ..core.registry import Registry
    from ..metrics.registry import MetricSpec
from .tables import (
    HAND_LABELS,
    TIED_NOTE,
    Cell,
    Column,
    Row,
    TableData,
    best_values,
    default_metric_registry,
    mark_best,
    mark_tied,
)

LEADERBOARD_COLUMNS = ("method", "metric", "hand", "value", "ci_low", "ci_high", "unit",
                       "higher_is_better", "n_sequences")
_HAND_ORDER = {"right": 0, "left": 1, "both": 2}


def _unit(rows: pd.DataFrame, metric: str, registry: Registry[MetricSpec] | None) -> str:
    """The one report unit of a metric; a mismatch with the registry is a unit bug."""
    units = sorted(set(rows["unit"]))
    if len(units) != 1:
        raise InputError(f"metric '{metric}' has several units in the results: "
                         f"{', '.join(units)}")
    if registry is not None and metric in registry and registry.get(metric).unit != units[0]:
        raise InputError(f"metric '{metric}' is reported in '{units[0]}' but registered in "
                         f"'{registry.get(metric).unit}'")
    return units[0]


def _direction(metric: str, registry: Registry[MetricSpec] | None) -> bool | None:
    return registry.get(metric).higher_is_better if registry is not None and metric in registry \
        else None


def unpredicted(df: pd.DataFrame, hands: Mapping[str, Sequence[str]]) -> pd.Series:
    """Rows of a hand (right / left) that their method does not predict."""
    side = df["hand"].isin(("right", "left"))
    allowed = df["method"].map(lambda m: tuple(hands.get(m, ("right", "left"))))
    return side & pd.Series([h not in a for h, a in zip(df["hand"], allowed, strict=True)],
                            index=df.index)


def _rank_key(lb: pd.DataFrame) -> pd.Series:
    """Best first within a (metric, hand): negate when higher is better; NaN last."""
    sign = lb["higher_is_better"].map(lambda h: -1.0 if h is True else 1.0)
    return (lb["value"] * sign).fillna(np.inf)


def leaderboard(results_df: pd.DataFrame,
                metrics_registry: Registry[MetricSpec] | None = None,
                seed: int = BOOTSTRAP_SEED, *,
                n_boot: int = BOOTSTRAP_N, perturbation: str | None = "none",
                hands: Mapping[str, Sequence[str]] | None = None,
                averaging: str = "sequence") -> pd.DataFrame:
    """Leaderboard frame: :data:`LEADERBOARD_COLUMNS` plus ``n_nan``.

    ``results_df`` is a validated results frame (one dataset: the leaderboard does not pool
    datasets for you, pass one at a time). ``perturbation`` selects the clean runs by
    default; ``None`` keeps all rows. ``hands`` maps a method to the hands it predicts
    (``MethodSpec.hands``): rows of a side it does not predict are dropped, because that
    hand is the method's input (on the clean split, the ground truth) and would score 0.
    Metrics registered with ``leaderboard=False`` (a table's sensitivity columns) are left
    out. Rows are ordered by metric, hand, then best first. ``averaging`` as in
    :func:`grip_bench.results.stats.sequence_ci`; kept in ``lb.attrs["averaging"]``.
    """
    registry = metrics_registry if metrics_registry is not None else default_metric_registry()
    df = results_df if perturbation is None else \
        results_df[results_df["perturbation"] == perturbation]
    df = df[~unpredicted(df, hands or {})]
    if registry is not None:  # table-only metrics (MetricSpec.leaderboard False) stay off
        shown = {m for m in set(df["metric"]) if m not in registry or registry.get(m).leaderboard}
        df = df[df["metric"].isin(shown)]
    records = []
    for (method, metric, hand), rows in df.groupby(["method", "metric", "hand"], sort=True):
        ci = sequence_ci(rows, n_boot=n_boot, seed=seed, averaging=averaging)
        records.append({"method": method, "metric": metric, "hand": hand, "value": ci.mean,
                        "ci_low": ci.lo, "ci_high": ci.hi, "unit": _unit(rows, metric, registry),
                        "higher_is_better": _direction(metric, registry),
                        "n_sequences": ci.n, "n_nan": ci.n_nan})
    lb = pd.DataFrame.from_records(records, columns=[*LEADERBOARD_COLUMNS, "n_nan"])
    if not lb.empty:
        lb["_hand"] = lb["hand"].map(lambda h: _HAND_ORDER.get(h, 9))
        lb["_rank"] = _rank_key(lb)
        lb = lb.sort_values(["metric", "_hand", "hand", "_rank", "method"], kind="mergesort")
        lb = lb.drop(columns=["_hand", "_rank"]).reset_index(drop=True)
    lb.attrs.update(averaging=averaging, bootstrap_seed=seed, bootstrap_n=n_boot,
                    perturbation=perturbation)
    return lb


# --- writers --------------------------------------------------------------------------------
def leaderboard_csv_text(lb: pd.DataFrame) -> str:
    """``leaderboard.csv`` text (docs/contract.md, "Results"): round-trip floats,
    true/false/empty."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(LEADERBOARD_COLUMNS)
    for r in lb.itertuples(index=False):
        hib = "" if r.higher_is_better is None or pd.isna(r.higher_is_better) else \
            ("true" if r.higher_is_better else "false")
        w.writerow([r.method, r.metric, r.hand, format_float(r.value), format_float(r.ci_low),
                    format_float(r.ci_high), r.unit, hib, int(r.n_sequences)])
    return buf.getvalue()


def write_leaderboard_csv(lb: pd.DataFrame, path: str | os.PathLike) -> Path:
    return atomic_write_text(path, leaderboard_csv_text(lb))


def _metric_order(lb: pd.DataFrame, registry: Registry[MetricSpec] | None) -> list[str]:
    """Registry order first (docs/contract.md, "Definitions"), unknown metrics alphabetically
    after."""
    known = registry.names() if registry is not None else []
    present = set(lb["metric"])
    return [m for m in known if m in present] + sorted(present - set(known))


def leaderboard_table(lb: pd.DataFrame,
                      metrics_registry: Registry[MetricSpec] | None = None,
                      title: str = "Leaderboard",
                      reference_methods: Sequence[str] | None = None,
                      control_methods: Sequence[str] | None = None,
                      results: pd.DataFrame | None = None) -> TableData:
    """The leaderboard as a wide table (methods x metric/hand) for the shared renderers.

    ``results``: the results frame ``lb`` was computed from; with it, methods the best of a
    column does not beat on the same sequences are bold too (``tables.mark_tied``).

    ``reference_methods``: rows never marked best (None: the registered methods whose
    ``MethodSpec.reference`` is set); ``control_methods``: trivial controls, ranked but
    never marked best, and a column where one scores as well as the best method marks
    none (None: the registered ``MethodSpec.control`` methods)."""
    from ..methods.api import control_rows, reference_rows

    if reference_methods is None:
        reference_methods = reference_rows()
    if control_methods is None:
        control_methods = control_rows()
    registry = metrics_registry if metrics_registry is not None else default_metric_registry()
    keys = [(m, h) for m in _metric_order(lb, registry)
            for h in sorted(set(lb.loc[lb["metric"] == m, "hand"]),
                            key=lambda h: (_HAND_ORDER.get(h, 9), h))]
    by_key = {(r.method, r.metric, r.hand): r for r in lb.itertuples(index=False)}
    columns = []
    for m, h in keys:
        r = lb[(lb["metric"] == m) & (lb["hand"] == h)].iloc[0]
        name = registry.get(m).name if registry is not None and m in registry else m
        hib = None if pd.isna(r["higher_is_better"]) else bool(r["higher_is_better"])
        columns.append(Column(group=name, label=HAND_LABELS.get(h, h), unit=r["unit"],
                              higher_is_better=hib))
    rows = []
    for method in sorted(set(lb["method"])):
        cells = tuple(_lb_cell(by_key.get((method, m, h)), col)
                      for (m, h), col in zip(keys, columns, strict=True))
        rows.append(Row(label=method, cells=cells, reference=method in reference_methods,
                        control=method in control_methods))
    _, tied = best_values(rows)
    shown = [m for m in control_methods if m in set(lb["method"])]
    notes = ("Mean over sequences with a 95% bootstrap interval (resampling sequences within "
             "each object, seeded).",
             f"Reference rows ({', '.join(reference_methods)}) are never marked best.",
             *([f"Controls ({', '.join(shown)}: the input wrists with fixed fingers) are "
                "ranked but never marked best."] if shown else []),
             *([f"No best marked in {_column_names(columns, tied)}: a control scores as well "
                "as the best method there, so the column does not rank methods on this "
                "data."] if tied else []),
             "– : no value (every sequence NaN, or a hand the method does not predict: "
             "single-hand models return the other hand as given).",
             "GRIP's ablation variants are compared in Tables 2 and 4 (right) and the physics "
             "table, on those tables' metrics.",
             AVERAGING_NOTES[lb.attrs.get("averaging", "sequence")])
    rows = mark_best(rows)
    if results is not None:
        rows = mark_tied(rows, _results_lookup(results, lb.attrs),
                         n_boot=lb.attrs.get("bootstrap_n", BOOTSTRAP_N),
                         seed=lb.attrs.get("bootstrap_seed", BOOTSTRAP_SEED),
                         averaging=lb.attrs.get("averaging", "sequence"))
        notes = (*notes, TIED_NOTE)
    return TableData(id="leaderboard", title=title, version=2,
                     description="every method, metric and hand on the clean test runs",
                     row_header="Method", columns=tuple(columns), rows=tuple(rows), notes=notes)


def _results_lookup(results: pd.DataFrame, attrs: Mapping) -> Callable[[Cell], pd.DataFrame | None]:
    """A leaderboard cell's results rows: its (method, metric, hand) on the runs the
    leaderboard was computed from (``attrs["perturbation"]``, the clean ones by default)."""
    pert = attrs.get("perturbation", "none")
    df = results if pert is None else results[results["perturbation"] == pert]
    groups = dict(tuple(df.groupby(["method", "metric", "hand"], sort=False)))
    return lambda c: groups.get((c.filters.get("method"), c.filters.get("metric"),
                                 c.filters.get("hand")))


def _column_names(columns: Sequence[Column], keys: set) -> str:
    """'Contact drift R-Hand, Jitter R-Hand' for the (column index, metric) ``keys``."""
    return ", ".join(f"{columns[j].group} {columns[j].label}".strip()
                     for j in sorted({j for j, _ in keys}))


def _lb_cell(r: Any, col: Column) -> Cell:
    if r is None:
        return Cell(ci=None, higher_is_better=col.higher_is_better)
    ci = CI(r.value, r.ci_low, r.ci_high, int(r.n_sequences), int(r.n_nan))
    return Cell(ci=ci, metric=r.metric, unit=r.unit, higher_is_better=col.higher_is_better,
                filters={"method": r.method, "metric": r.metric, "hand": r.hand})


def leaderboard_tables(lb: pd.DataFrame, metrics_registry: Registry[MetricSpec] | None = None,
                       title: str = "Leaderboard",
                       results: pd.DataFrame | None = None) -> list[TableData]:
    """One leaderboard table per hand (right, left, both): each fits a page width.
    ``results``: as in :func:`leaderboard_table`."""
    hands = sorted(set(lb["hand"]), key=lambda h: (_HAND_ORDER.get(h, 9), h))
    if len(hands) <= 1:
        return [leaderboard_table(lb, metrics_registry, title, results=results)]
    return [leaderboard_table(lb[lb["hand"] == h], metrics_registry,
                              f"{title}: {_HAND_TITLES.get(h, h)}", results=results)
            for h in hands]


_HAND_TITLES = {"right": "right hand", "left": "left hand", "both": "both hands"}


def write_leaderboard_md(lb: pd.DataFrame, path: str | os.PathLike,
                         metrics_registry: Registry[MetricSpec] | None = None,
                         title: str = "Leaderboard",
                         results: pd.DataFrame | None = None) -> Path:
    from .render import to_markdown

    parts = [to_markdown(t, heading_level=2)
             for t in leaderboard_tables(lb, metrics_registry, title, results)]
    return atomic_write_text(path, "\n".join(parts))


def write_leaderboard_html(lb: pd.DataFrame, path: str | os.PathLike,
                           figures: Sequence[str | os.PathLike] = (),
                           metrics_registry: Registry[MetricSpec] | None = None,
                           title: str = "grip-bench leaderboard",
                           extra_tables: Sequence[TableData] = (),
                           links: Mapping[str, Sequence[tuple[str, str | os.PathLike]]]
                           | None = None, results: pd.DataFrame | None = None) -> Path:
    """Self-contained sortable page: the leaderboard, optional paper tables, PNG figures.

    ``links``: ``{method: [(text, viewer page path)]}``, linked (relative to the page) after
    each method's row label."""
    from .render import html_page, relative_links, table_html

    rel = relative_links(links, Path(path).parent)
    fragments = [table_html(t, rel)
                 for t in leaderboard_tables(lb, metrics_registry, "Leaderboard", results)]
    fragments += [table_html(t, rel) for t in extra_tables]
    return atomic_write_text(path, html_page(title, fragments, figures))
