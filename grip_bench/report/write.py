"""A run's report from its folder alone: tables, figures and leaderboards.

``grip-bench report OUT`` and the end of ``grip-bench run`` call :func:`write_report`, so
both write the same bytes. Reads ``OUT/results.csv``, ``OUT/runtime.csv``, the figure data
under ``OUT/figures/``, ``OUT/sensitivity_pairs.csv`` (the counterfactual split's pairs,
when the run scored them) and the report options saved in ``OUT/manifest.json``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..core import constants as C
from ..core.errors import InputError
from ..results.layout import CLEAN, MAIN_SPLIT

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .tables import TableData

# figure data (written by ``run`` from the metric units, read by ``write_figures``)
HEATMAP_DATA = "heatmap_data.npz"
DEPTH_DATA = "penetration_depths.npz"
DEPTH_FORMAT = 1
HEATMAP_PNG = "contact_heatmaps.png"
CDF_PNG = "penetration_cdf.png"
BAR_METRICS = ("mpvpe", "iv")  # per_object_<metric>.png
# the counterfactual split's per-pair scores (written by ``run``, docs/counterfactual.md) and
# the table drawn from them in OUT/tables/
SENSITIVITY_PAIRS = "sensitivity_pairs.csv"
SENSITIVITY_TABLE = "geometry_sensitivity"
SENSITIVITY_FORMATS = ("md", "csv", "html")


def figure_methods(settings: dict) -> list[str]:
    """Methods of the heatmaps and the CDF: gt first, then ``[run] figure_methods`` (empty:
    ``constants.RUN_FIGURE_METHODS``); those without figure data are left out later."""
    chosen = list(settings.get("figure_methods") or C.RUN_FIGURE_METHODS)
    return ["gt", *dict.fromkeys(m for m in chosen if m != "gt")]


def read_depth_data(path: Path) -> dict[str, np.ndarray]:
    """``{method: (N,) mm}`` of ``penetration_depths.npz``."""
    from ..metrics.aggregate import read_npz

    d = read_npz(path)
    if int(d["format"][0]) != DEPTH_FORMAT:
        raise InputError(f"penetration depth format {int(d['format'][0])}, expected {DEPTH_FORMAT}",
                         path)
    off = d["offsets"]
    return {m: d["depths"][off[i]:off[i + 1]] for i, m in enumerate(d["methods"].tolist())}


def write_figures(out: Path, results: pd.DataFrame, options: dict) -> list[Path]:
    """Figures under ``OUT/figures/`` from saved results and figure data (report.figures).

    Contact heatmaps (``heatmap_data.npz``), penetration CDF (``penetration_depths.npz``)
    and per-object bars of :data:`BAR_METRICS` on the clean main split (``results``). A
    figure without data (or whose data does not fit, e.g. a hand template of another vertex
    count) is skipped and an older PNG of it removed. Returns the PNG paths (embedded in
    leaderboard.html).
    """
    from . import figures as F

    figs = out / "figures"
    drawn: list[Path] = []
    jobs = []
    if (figs / HEATMAP_DATA).is_file():
        jobs.append((HEATMAP_PNG, lambda p: F.contact_heatmap(
            F.read_heatmap_data(figs / HEATMAP_DATA), p,
            title="Contact frequency over grasp frames (clean test split)")))
    if (figs / DEPTH_DATA).is_file():
        jobs.append((CDF_PNG, lambda p: F.penetration_cdf(
            read_depth_data(figs / DEPTH_DATA), p,
            title="Penetration depth per grasp frame (clean test split)")))
    main = results[(results["split"] == options.get("split", MAIN_SPLIT))
                   & (results["perturbation"] == CLEAN)]
    for metric in BAR_METRICS:
        present = set(main.loc[main["metric"] == metric, "method"])
        # the heatmaps' methods (gt first): twenty methods side by side are unreadable
        bar_methods = [m for m in figure_methods(options) if m in present]
        if bar_methods:
            jobs.append((f"per_object_{metric}.png", lambda p, metric=metric, ms=bar_methods:
                         F.per_object_bars(main, metric, p, methods=ms,
                                           n_boot=options["bootstrap_n"],
                                           seed=options["bootstrap_seed"])))
    names = {HEATMAP_PNG, CDF_PNG, *(f"per_object_{m}.png" for m in BAR_METRICS)}
    for name, draw in jobs:
        try:
            drawn.append(draw(figs / name))
            names.discard(name)
        except InputError:
            pass
    for name in sorted(names):  # stale figures of an earlier run
        if (figs / name).exists():
            (figs / name).unlink()
    return drawn


def _seed_notes(seeds: pd.DataFrame | None) -> tuple[str, ...]:
    """One note per judged row of ``report.sensitivity.seed_judgements``."""
    if seeds is None or not len(seeds):
        return ()
    from .sensitivity import SEED_COMPARE_TO, SEED_SCORES

    names = {col: (title, unit, dec) for col, title, unit, _, dec in SEED_SCORES}
    out = []
    for _, r in seeds[seeds["verdict"] != ""].iterrows():
        title, unit, dec = names[r["score"]]
        out.append(f"Seeds {r['seed_labels']}: {r['method']} minus {SEED_COMPARE_TO}, "
                   f"{title.lower()}: {r['diff']:+.{dec}f} {unit} [{r['diff_lo']:+.{dec}f}, "
                   f"{r['diff_hi']:+.{dec}f}], seed spread {r['spread']:.{dec}f}: "
                   f"{r['verdict']}.")
    return tuple(out)


def sensitivity_table_data(summary: pd.DataFrame, gate: list[tuple[str, bool, str]],
                           n_pairs: int, seeds: pd.DataFrame | None = None) -> TableData:
    """The geometry-sensitivity table (``report.sensitivity.summarize``) as a
    :class:`~report.tables.TableData` for the HTML pages: methods, then the reference rows;
    the best method per column in bold (references excluded); the gate in the notes."""
    from ..results.stats import CI
    from .sensitivity import TABLE_VERSION
    from .tables import Cell, Column, Row, TableData

    spec = (("Change reproduced", "", "reproduced", "%", True, 1),
            ("Aperture-change error", "", "aperture_error", "mm", False, 2),
            ("MPVPE", "A", "mpvpe_a", "mm", False, 2), ("MPVPE", "B", "mpvpe_b", "mm", False, 2))
    methods = summary[~summary["reference"].astype(bool)]
    best = {}
    for _, _, col, _, hib, _ in spec:
        v = methods[col].to_numpy(float)
        best[col] = (np.nanmax(v) if hib else np.nanmin(v)) if np.isfinite(v).any() else None
    rows = []
    for _, r in summary.iterrows():
        ref = bool(r["reference"])
        cells = tuple(Cell(ci=CI(float(r[col]), float(r[col + "_lo"]), float(r[col + "_hi"]),
                                 int(r["pairs"]), 0),
                           unit=unit, higher_is_better=hib, decimals=dec,
                           best=not ref and best[col] is not None and r[col] == best[col])
                      for _, _, col, unit, hib, dec in spec)
        label = r["method"] + (f" ({r['pairs']}/{r['pairs_total']} pairs)"
                               if r["pairs"] != r["pairs_total"] else "")
        rows.append(Row(label=label, cells=cells, reference=ref,
                        group="Reference rows (sanity gate)" if ref else "Methods"))
    notes = ("Pairs share body, wrist and object motion; only the object's shape differs. "
             "Scored on the grasping hand, on frames held in both members; mean over pairs, "
             "95 % bootstrap interval over pairs stratified by object family.",
             "Change reproduced: 1 - |d_m - d_gt| / |d_gt| (clipped to [0, 1]), d = hands_B "
             "- hands_A; 0 for a method blind to the object (docs/counterfactual.md).",
             *_seed_notes(seeds),
             *(f"Sanity gate: {'PASS' if ok else 'FAIL'}: {name} ({got})"
               for name, ok, got in gate))
    columns = tuple(Column(group, label, unit, hib) for group, label, _, unit, hib, _ in spec)
    return TableData(id=SENSITIVITY_TABLE,
                     title=f"Geometry sensitivity (counterfactual split, {n_pairs} pairs)",
                     version=TABLE_VERSION, row_header="Method", columns=columns,
                     rows=tuple(rows), notes=notes,
                     description="each method on pairs of test sequences whose objects "
                                 "differ only in shape")


def write_sensitivity_report(out: str | os.PathLike) -> tuple[list[Path], TableData | None]:
    """``OUT/tables/geometry_sensitivity.{md,csv,html}`` from ``OUT/sensitivity_pairs.csv``
    (``report.sensitivity``; the sanity gate in each) and the table for the leaderboard page.
    Without that file (no counterfactual split in the run) the tables of an earlier run are
    removed; a split without pairs gets a Markdown note only."""
    from ..core.io import atomic_write_text
    from .render import to_html
    from .sensitivity import (
        read_pairs_csv,
        sanity_gate,
        seed_judgements,
        summarize,
        write_sensitivity,
    )

    out = Path(out)
    tables = out / "tables"
    stale = {tables / f"{SENSITIVITY_TABLE}.{fmt}" for fmt in SENSITIVITY_FORMATS}
    stale.add(tables / f"{SENSITIVITY_TABLE}_seeds.csv")  # runs with several seeds only
    rows = read_pairs_csv(out / SENSITIVITY_PAIRS) if (out / SENSITIVITY_PAIRS).is_file() \
        else None
    written, data = [], None
    if rows is not None and not len(rows):
        written = [atomic_write_text(tables / f"{SENSITIVITY_TABLE}.md",
                                     "## Geometry sensitivity (counterfactual split, 0 pairs)\n\n"
                                     "The split holds no pairs (every twin was rejected): "
                                     "nothing to score.\n")]
    elif rows is not None:
        written, _ = write_sensitivity(out, rows, tables, pairs_file=False)
        data = sensitivity_table_data(summarize(rows), sanity_gate(rows),
                                      int(rows["pair"].nunique()), seed_judgements(rows))
        written.append(atomic_write_text(tables / f"{SENSITIVITY_TABLE}.html", to_html(data)))
    for path in sorted(stale - set(written)):
        if path.exists():
            path.unlink()
    return written, data


def write_leaderboards(out: Path, results: pd.DataFrame, options: dict,
                       figures: list[Path], links: dict | None = None,
                       extra_tables: tuple[TableData, ...] = ()) -> list[Path]:
    """``leaderboard.{csv,md,html}`` of the clean main split (one set per dataset); the HTML
    links each method to its viewer pages (``links``, :func:`report.viewer.viewer_links`)
    and shows ``extra_tables`` below the leaderboard (the geometry-sensitivity table).
    Rows of further training seeds (``<method>@seed<N>``) are left out: the leaderboard is
    the first seed's, as in a single-seed run."""
    from ..methods.api import predicted_hands, variants
    from .leaderboard import (
        leaderboard,
        write_leaderboard_csv,
        write_leaderboard_html,
        write_leaderboard_md,
    )
    from .tables import is_seed_label

    main = results[results["split"] == options.get("split", MAIN_SPLIT)]
    main = main[~main["method"].isin(variants())]  # ablations: in their own tables
    # further training seeds ([run] seeds): in the seeded tables, not one line per seed
    main = main[~main["method"].map(is_seed_label).astype(bool)] if len(main) else main
    datasets = sorted(main["dataset"].unique()) or [None]
    hands = predicted_hands()
    written = []
    for ds in datasets:
        df = main if ds is None else main[main["dataset"] == ds]
        lb = leaderboard(df, seed=options["bootstrap_seed"], n_boot=options["bootstrap_n"],
                         hands=hands, averaging=options.get("averaging", "sequence"))
        stem = "leaderboard" if len(datasets) == 1 else f"leaderboard.{ds}"
        written += [write_leaderboard_csv(lb, out / f"{stem}.csv"),
                    write_leaderboard_md(lb, out / f"{stem}.md", results=df)]
        if not lb.empty:
            written.append(write_leaderboard_html(lb, out / f"{stem}.html", figures=figures,
                                                  links=links, extra_tables=extra_tables,
                                                  results=df))
    return written


def report_options(out: Path) -> dict:
    """Rendering options saved by ``run`` in ``manifest.json`` (defaults without one)."""
    defaults = {"bootstrap_seed": C.BOOTSTRAP_SEED, "bootstrap_n": C.BOOTSTRAP_N,
                "figure_methods": list(C.RUN_FIGURE_METHODS), "split": MAIN_SPLIT,
                "averaging": "sequence"}
    path = Path(out) / "manifest.json"
    if not path.is_file():
        return defaults
    from ..results.manifest import read_manifest

    saved = (read_manifest(path).get("config") or {}).get("report") or {}
    return {**defaults, **saved}


def run_tables(out: Path) -> list[str] | None:
    """The table ids the run in ``out`` chose (``manifest.json`` ``config.tables``); None
    (every registered table) without a manifest or without that entry."""
    path = Path(out) / "manifest.json"
    if not path.is_file():
        return None
    from ..results.manifest import read_manifest

    tables = (read_manifest(path).get("config") or {}).get("tables")
    return list(tables) if tables else None


def _drop_unrequested_tables(tables_dir: Path, keep: list[str] | None) -> None:
    """Remove files of registered tables the run did not choose (an earlier report's, or
    rendered before reports followed ``config.tables``): a table folder holds only the run's
    tables. Only ``<registered id>.<format>`` names are touched, in the folder and in its
    per-dataset subfolders."""
    if keep is None or not tables_dir.is_dir():
        return
    from .render import FORMATS
    from .tables import TABLES

    names = {f"{spec.id}.{fmt}" for spec in TABLES if spec.id not in keep for fmt in FORMATS}
    for folder in (tables_dir, *(d for d in tables_dir.iterdir() if d.is_dir())):
        for name in names:
            (folder / name).unlink(missing_ok=True)


def write_report(out: str | os.PathLike, options: dict | None = None,
                 tables: Sequence[str] | None = None) -> list[Path]:
    """Tables, figures and leaderboard from ``OUT/results.csv`` (+ runtime.csv, figure data).

    ``tables``: the table ids to write (``run`` passes its chosen ones before it writes
    ``manifest.json``); None: those ``OUT/manifest.json`` records (``run_tables``).

    Reads only files in ``OUT``: ``grip-bench report OUT`` and the end of ``run`` call this
    same function, so they write the same bytes. When ``OUT/viewer/index.json`` exists (run's
    ``[run] viewer_sequences``), HTML rows link each method to its viewer pages. When
    ``OUT/sensitivity_pairs.csv`` exists (``[run] counterfactual_sources``), the
    geometry-sensitivity table is written to ``OUT/tables/`` and shown in
    ``leaderboard.html``.
    """
    from ..results.schema import read_results
    from .render import render_all
    from .viewer import viewer_links

    out = Path(out)
    options = options or report_options(out)
    results = read_results(out / "results.csv")
    links = viewer_links(out)  # OUT/viewer/index.json, written by run
    tables = list(tables) if tables is not None else run_tables(out)  # as --tables promises
    _drop_unrequested_tables(out / "tables", tables)
    written = render_all(out, out / "tables", n_boot=options["bootstrap_n"],
                         seed=options["bootstrap_seed"],
                         averaging=options.get("averaging", "sequence"), links=links,
                         tables=tables)
    from .validity import write_validity

    validity = write_validity(out)  # when the run measured metric validity
    figures = write_figures(out, results, options) + [p for p in validity if p.suffix == ".png"]
    written += figures + [p for p in validity if p.suffix != ".png"]
    sensitivity, table = write_sensitivity_report(out)  # when the run scored the split
    written += sensitivity
    written += write_leaderboards(out, results, options, figures, links,
                                  extra_tables=(table,) if table is not None else ())
    return written
