"""The metric-validity report: a table and a figure of each metric's response to controlled
degradations of ground truth (computed by ``grip_bench.metrics.validity``).

Reads ``OUT/validity.csv`` (columns of ``metric_validity``) and, when present,
``OUT/validity.json`` (its inputs, and the footnote on their frame budgets written with
them), and writes ``OUT/tables/metric_validity.{md,csv}`` and
``OUT/figures/metric_validity.png``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.io import atomic_write_text

MARK = {True: "PASS", False: "FAIL"}


def _claims(df: pd.DataFrame) -> dict[tuple[str, str], bool]:
    """(degradation, metric) -> whether its claim holds (claimed pairs only)."""
    from ..metrics.validity import check_validity

    broken = check_validity(df)
    out = {}
    for (deg, metric), g in df.groupby(["degradation", "metric"], sort=False):
        if g["expected"].iloc[0]:
            out[deg, metric] = not any(line.startswith(f"{metric} under {deg}:")
                                       for line in broken)
    return out


def sampling_note(options: dict | None) -> list[str]:
    """The footnote line on what the physics metrics and exact IV were measured on, from the
    evaluation options (``EvalOptions`` as a dict), as this code applies them; none unknown.
    :func:`write_validity_record` stores it in ``validity.json`` when the report is made, so
    a re-rendered table states what the code that ran did (s57 changed what
    ``max_sim_frames`` covers without changing the options)."""
    if not options:
        return []
    if not options.get("physics", True):
        return ["- Physics metrics not measured (`grip-bench validity --physics` adds them)."]
    k = int(options["max_physics_frames"])
    sim = k if options.get("max_sim_frames") is None else min(k, int(options["max_sim_frames"]))
    iv, seed = int(options.get("max_iv_frames", 0)), options.get("physics_seed", 0)
    return [f"- Frames: the quasi-static check and the articulated hold test on at most {k} "
            f"held frames per sequence and hand (drawn with seed {seed}); "
            f"the support test and the articulated test's friction, grip and direction "
            f"variants on at most {sim} of them; exact IV on "
            + (f"{iv} evenly spaced grasp frames." if iv else "every grasp frame.")]


UNRECORDED = ("- Frames: not recorded (`validity.json` from before s58; `grip-bench run` or "
              "`grip-bench validity` writes them).")


def validity_markdown(df: pd.DataFrame, frames: list[str] | None = None) -> str:
    """One section per degradation: each metric's value per level, the claim and its verdict;
    ``frames``: the footnote lines on the frame budgets (:func:`sampling_note`, as
    ``validity.json`` stores them)."""
    from ..metrics.validity import DEGRADATIONS, check_validity

    claims = _claims(df)
    lines = ["### Metric validity: responses to controlled degradations of ground truth", ""]
    for deg, g in df.groupby("degradation", sort=False):
        d = DEGRADATIONS.get(deg)  # None: a degradation this version no longer has
        levels = sorted(g["level"].unique())
        lines += [f"**{d.label}** (levels in {d.unit})" if d else f"**{deg}**", "",
                  "| metric | unit | " + " | ".join(f"{lv:g}" for lv in levels)
                  + " | claim | verdict |",
                  "|---|---|" + "---|" * len(levels) + "---|---|"]
        for metric, gm in g.groupby("metric", sort=False):
            vals = gm.set_index("level")["value"]
            cells = " | ".join("–" if not np.isfinite(vals.get(lv, np.nan)) else
                               f"{vals[lv]:.2f}" for lv in levels)
            claim = gm["expected"].iloc[0] or ""
            verdict = MARK[claims[deg, metric]] if (deg, metric) in claims else ""
            lines.append(f"| {metric} | {gm['unit'].iloc[0]} | {cells} | {claim} | {verdict} |")
        lines.append("")
    n = int(df["n_sequences"].max()) if len(df) else 0
    broken = check_validity(df)
    lines += [f"- Mean over {n} ground-truth test sequences (per-sequence mean of the hands); "
              "level 0 is the ground truth itself.",
              "- Claims: up / down = monotone (ties within the tolerance) with a clear change; "
              "flat = every level within the tolerance of level 0 (grip_bench.metrics.validity"
              ".TOLERANCE). Unclaimed pairs are measured, not judged.",
              *(frames or []),
              f"- Broken claims: {len(broken)}" + ("." if not broken else ": "
                                                   + "; ".join(broken) + ".")]
    return "\n".join(lines) + "\n"


def validity_figure(df: pd.DataFrame, out_png: str | os.PathLike) -> Path:
    """One small panel per (metric, degradation): rows are metrics on a shared y-axis,
    coloured by the verdict of their claim (``report.figures.metric_validity_grid``)."""
    from ..metrics.validity import DEGRADATIONS
    from .figures import metric_validity_grid

    verdicts = {k: MARK[ok] for k, ok in _claims(df).items()}
    labels = {d: f"{v.label} ({v.unit})" for d, v in DEGRADATIONS.items()}
    return metric_validity_grid(df, out_png, verdicts, labels)


def write_validity_record(out: str | os.PathLike, record: dict) -> Path:
    """``OUT/validity.json``: which inputs made ``validity.csv`` (the run's validity unit
    adds its key) and the footnote on their frame budgets (``frames``: :func:`sampling_note`
    of the inputs' options, written by the code that made the report), which
    :func:`write_validity` prints under the table."""
    from ..core.io import jsonable

    record = {**record, "frames": sampling_note(record.get("inputs", {}).get("options"))}
    return atomic_write_text(Path(out) / "validity.json",
                             json.dumps(jsonable(record), sort_keys=True, indent=1) + "\n")


def write_validity(out: str | os.PathLike) -> list[Path]:
    """The table and figure of ``OUT/validity.csv``; nothing when it does not exist."""
    out = Path(out)
    src = out / "validity.csv"
    if not src.is_file():
        return []
    df = pd.read_csv(src, keep_default_na=True).fillna({"expected": ""})
    meta = out / "validity.json"
    frames = json.loads(meta.read_text()).get("frames", [UNRECORDED]) if meta.is_file() else []
    tables = out / "tables"
    tables.mkdir(parents=True, exist_ok=True)
    written = [atomic_write_text(tables / "metric_validity.md", validity_markdown(df, frames)),
               atomic_write_text(tables / "metric_validity.csv", df.to_csv(index=False))]
    written.append(validity_figure(df, out / "figures" / "metric_validity.png"))
    return written
