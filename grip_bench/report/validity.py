"""The metric-validity report: a table and a figure of each metric's response to controlled
degradations of ground truth (computed by ``grip_bench.metrics.validity``).

Reads ``OUT/validity.csv`` (columns of ``metric_validity``) and writes
``OUT/tables/metric_validity.{md,csv}`` and ``OUT/figures/metric_validity.png``.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.io import atomic_write_bytes, atomic_write_text

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


def validity_markdown(df: pd.DataFrame) -> str:
    """One section per degradation: each metric's value per level, the claim and its verdict."""
    from ..metrics.validity import DEGRADATIONS, check_validity

    claims = _claims(df)
    lines = ["### Metric validity: responses to controlled degradations of ground truth", ""]
    for deg, g in df.groupby("degradation", sort=False):
        d = DEGRADATIONS[deg]
        levels = sorted(g["level"].unique())
        lines += [f"**{d.label}** (levels in {d.unit})", "",
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
              f"- Broken claims: {len(broken)}" + ("." if not broken else ": "
                                                   + "; ".join(broken) + ".")]
    return "\n".join(lines) + "\n"


def validity_figure(df: pd.DataFrame, out_png: str | os.PathLike) -> Path:
    """One panel per degradation; each metric's response scaled by its largest magnitude over
    all degradations, so a flat response stays flat (claimed metrics solid, the rest dotted)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..metrics.validity import DEGRADATIONS

    degs = list(dict.fromkeys(df["degradation"]))
    metrics = list(dict.fromkeys(df["metric"]))
    cmap = plt.get_cmap("tab20")
    colour = {m: cmap(i % 20) for i, m in enumerate(metrics)}
    scales = df.groupby("metric")["value"].apply(lambda v: np.nanmax(np.abs(v)) if
                                                 np.isfinite(v).any() else 0.0)
    cols = min(4, len(degs))
    rows = int(np.ceil(len(degs) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.8 * rows + 0.9), squeeze=False)
    for ax, deg in zip(axes.flat, degs, strict=False):
        g = df[df["degradation"] == deg]
        for metric, gm in g.groupby("metric", sort=False):
            gm = gm.sort_values("level")
            v = gm["value"].to_numpy(dtype=np.float64)
            scale = float(scales[metric])
            y = v / scale if scale > 0 else np.zeros_like(v)
            claimed = bool(gm["expected"].iloc[0])
            ax.plot(gm["level"], y, "-o" if claimed else ":", ms=3, lw=1.4 if claimed else 0.9,
                    color=colour[metric], label=metric)
        d = DEGRADATIONS[deg]
        ax.set_title(d.label, fontsize=9)
        ax.set_xlabel(d.unit, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_ylim(-0.05, 1.05)
    for ax in list(axes.flat)[len(degs):]:
        ax.axis("off")
    handles = [plt.Line2D([], [], color=colour[m], lw=1.4) for m in metrics]
    fig.legend(handles, metrics, loc="lower center", ncol=min(7, len(metrics)), fontsize=7,
               frameon=False)
    fig.suptitle("Metric responses to degraded ground truth (each metric scaled to its largest "
                 "value over all panels; solid = claimed)", fontsize=9)
    fig.tight_layout(rect=(0, 0.08, 1, 0.96))
    buf = io.BytesIO()
    fig.savefig(buf, dpi=120, format="png", metadata={"Software": None})  # no varying metadata
    plt.close(fig)
    return atomic_write_bytes(out_png, buf.getvalue())


def write_validity(out: str | os.PathLike) -> list[Path]:
    """The table and figure of ``OUT/validity.csv``; nothing when it does not exist."""
    out = Path(out)
    src = out / "validity.csv"
    if not src.is_file():
        return []
    df = pd.read_csv(src, keep_default_na=True).fillna({"expected": ""})
    tables = out / "tables"
    tables.mkdir(parents=True, exist_ok=True)
    written = [atomic_write_text(tables / "metric_validity.md", validity_markdown(df)),
               atomic_write_text(tables / "metric_validity.csv", df.to_csv(index=False))]
    written.append(validity_figure(df, out / "figures" / "metric_validity.png"))
    return written
