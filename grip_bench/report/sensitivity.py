"""The geometry-sensitivity table: methods ranked on the counterfactual split's pairs
(docs/counterfactual.md; the scores are ``metrics.sensitivity``).

A table over pairs, not over sequences, so the TOML tables (``report/tables``), whose cells
select per-sequence result rows, cannot express it; this module builds it from a
counterfactual dataset folder (its ``pairs.json``) and prediction folders in GRAB layout
(the dataset's relative file names, as ``grip-bench predict`` writes them).

Each pair is scored on its grasping hand (``pairs.json`` ``side``); the other hand is idle.
Two reference predictors need no method and are always scored: ``gt`` (the ground truth)
and ``same-hands`` (A's ground-truth hands copied to B: a method blind to the object at its
best). They are the sanity gate printed with the table: ``gt`` must reproduce 100 % of the
change with a 0 mm aperture error and ``same-hands`` 0 %.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.constants import BOOTSTRAP_N, BOOTSTRAP_SEED, CF_SPLIT
from ..core.errors import InputError
from ..core.io import atomic_write_text
from ..metrics.sensitivity import pair_scores
from ..results.stats import bootstrap_ci

REFERENCES = ("gt", "same-hands")
SCORE_COLUMNS = ("reproduced", "aperture_error", "gt_aperture_change", "mpvpe_a", "mpvpe_b",
                 "mpvpe", "n_frames")
GATE_TOL = 1e-9  # share / m; the reference rows are exact by construction
TABLE_VERSION = 2  # 2: a seeds section when the run has several training seeds
SEED_COMPARE_TO = "grip"  # further seeds' rows are judged against this method (as Table 2)
SEED_SCORES = (("reproduced", "Change reproduced", "%", 100.0, 1),
               ("aperture_error", "Aperture-change error", "mm", 1000.0, 2))


# --- reading ------------------------------------------------------------------------------
def read_pairs_doc(data_dir: str | os.PathLike) -> dict:
    """``DATA/pairs.json`` of a counterfactual dataset as written (its ``pairs`` a list,
    possibly empty when every twin was rejected)."""
    path = Path(data_dir) / "pairs.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as e:
        raise InputError("no pairs.json: not a counterfactual dataset", path) from e
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"not readable JSON ({e})", path) from e
    if not isinstance(doc, dict) or not isinstance(doc.get("pairs"), list):
        raise InputError("holds no list of pairs", path)
    return doc


def read_pairs(data_dir: str | os.PathLike) -> list[dict]:
    """The pairs of a counterfactual dataset (``DATA/pairs.json``), checked."""
    path = Path(data_dir) / "pairs.json"
    pairs = read_pairs_doc(data_dir)["pairs"]
    if not pairs:
        raise InputError("holds no pairs", path)
    for k, p in enumerate(pairs):
        missing = [key for key in ("id", "a", "b", "side", "family") if key not in p]
        if missing:
            raise InputError(f"pair {k} lacks {missing}", path)
        if p["side"] not in ("right", "left"):
            raise InputError(f"pair {p['id']}: side {p['side']!r}", path)
    return pairs


@dataclass
class _Member:
    """One ground-truth member of a pair, posed: vertices (T, V, 3), tips (T, 5, 3), held (T,)."""

    seq: object
    pair: object
    verts: np.ndarray
    tips: np.ndarray
    held: np.ndarray


def _member(data_dir: Path, rel: str, side: str, library, options) -> _Member:
    from ..data.grab_io import read_grab
    from ..metrics.evaluate import SequencePair
    from ..metrics.intersection import FailureCounter

    seq = read_grab(data_dir / rel)
    sp = SequencePair(seq, seq, library, options, FailureCounter())
    tr = sp.track("gt", side)
    return _Member(seq, sp, tr.verts, tr.joints[:, 16:21], sp.held(side))


def _posed(member: _Member, seq, side: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (T, V, 3) and fingertips (T, 5, 3) of ``seq``'s hand ``side``, posed with the
    ground truth's hand model (as the evaluation does)."""
    if seq.n_frames != member.seq.n_frames:
        raise InputError(f"{seq.n_frames} frames, the ground truth has {member.seq.n_frames}",
                         str(seq.source or seq.name))
    v, j = member.pair.poser.pose(side, seq.hand_params(side))
    return v, j[:, 16:21]


def score_pairs(data_dir: str | os.PathLike,
                predictions: dict[str, str | os.PathLike] | None = None,
                model_path: str | None = None, workers: int = 1) -> pd.DataFrame:
    """One row per (method, pair): the ``SCORE_COLUMNS`` (SI: m, shares) and the pair's id,
    family, variant, side and grasp kind. ``predictions``: method -> prediction folder (GRAB
    layout, the dataset's relative names); the references (``REFERENCES``) come first.
    ``workers`` > 1 scores the pairs in the evaluation's process pool
    (``metrics.aggregate.map_tasks``): the same rows, in the same order."""
    from ..metrics.aggregate import map_tasks
    from ..metrics.evaluate import EvalOptions

    data_dir = Path(data_dir)
    pairs = read_pairs(data_dir)
    predictions = {k: str(v) for k, v in (predictions or {}).items()}
    clash = sorted(set(predictions) & set(REFERENCES))
    if clash:
        raise InputError(f"{clash} name reference rows; name the method otherwise", "--pred")
    for name, folder in predictions.items():
        if not Path(folder).is_dir():
            raise InputError("no such prediction folder", f"{name}={folder}")
    options = EvalOptions(iv=False, physics=False, model_path=model_path)
    jobs = [(str(data_dir), p, predictions, options) for p in pairs]
    parts = map_tasks(_pair_rows, jobs, data_dir, max(1, int(workers)), False)
    return pd.DataFrame([row for part in parts for row in part])


def _pair_rows(job: tuple) -> list[dict]:
    """The rows of one pair (references first, then each method), in an evaluation worker."""
    from ..data.grab_io import read_grab
    from ..metrics.aggregate import worker_library

    data_dir, p, predictions, options = job
    data_dir, library, side = Path(data_dir), worker_library(), p["side"]
    a = _member(data_dir, p["a"], side, library, options)
    b = _member(data_dir, p["b"], side, library, options)
    if a.seq.n_frames != b.seq.n_frames:
        raise InputError(f"members have {a.seq.n_frames} and {b.seq.n_frames} frames",
                         f"pairs.json: {p['id']}")
    preds = {"gt": ((a.verts, a.tips), (b.verts, b.tips)),
             "same-hands": ((a.verts, a.tips), _posed(b, a.seq, side))}
    for name, folder in predictions.items():
        pa = read_grab(Path(folder) / p["a"])
        pb = read_grab(Path(folder) / p["b"])
        preds[name] = (_posed(a, pa, side), _posed(b, pb, side))
    rows = []
    for name, ((va, ta), (vb, tb)) in preds.items():
        s = pair_scores(a.verts, b.verts, va, vb, (a.tips, b.tips, ta, tb), a.held, b.held)
        rows.append({"method": name, "pair": p["id"], "family": p["family"],
                     "variant": p.get("variant", ""), "side": side,
                     "grasp_kind": p.get("grasp_kind", ""), **s})
    return rows


# --- the table ------------------------------------------------------------------------------
def summarize(rows: pd.DataFrame, n_boot: int = BOOTSTRAP_N,
              seed: int = BOOTSTRAP_SEED) -> pd.DataFrame:
    """Per method: the mean over pairs of each score with a 95 % bootstrap interval over
    pairs (stratified by object family), in report units (%, mm). Methods are ranked by the
    share of the change reproduced (then aperture error); the references come last."""
    out = []
    for method, g in rows.groupby("method", sort=False):
        rec = {"method": method, "reference": method in REFERENCES,
               "pairs": int(np.isfinite(g["reproduced"]).sum()), "pairs_total": len(g)}
        for col, scale in (("reproduced", 100.0), ("aperture_error", 1000.0),
                           ("mpvpe_a", 1000.0), ("mpvpe_b", 1000.0)):
            ci = bootstrap_ci(g[col].to_numpy(float) * scale, g["family"].to_numpy(),
                              n_boot=n_boot, seed=seed)
            rec[col], rec[col + "_lo"], rec[col + "_hi"] = ci.mean, ci.lo, ci.hi
        rec["gt_aperture_change_abs"] = float(np.nanmean(np.abs(g["gt_aperture_change"]))) * 1000
        out.append(rec)
    df = pd.DataFrame(out)
    methods = df[~df["reference"]].sort_values(["reproduced", "aperture_error"],
                                               ascending=[False, True], na_position="last")
    return pd.concat([methods, df[df["reference"]]], ignore_index=True)


def seed_judgements(rows: pd.DataFrame, compare_to: str = SEED_COMPARE_TO,
                    n_boot: int = BOOTSTRAP_N, seed: int = BOOTSTRAP_SEED) -> pd.DataFrame:
    """Seeds of the run (``<method>@seed<N>`` rows, ``report.tables.seed_label``): per
    method with two or more seeds and per score of ``SEED_SCORES`` (report units), the
    per-seed means over pairs, their mean and, for a method other than ``compare_to``, the
    difference of seed means to it with its paired 95 % bootstrap interval over the pairs
    both have (each pair's seed-averaged score, stratified by object family) and the
    verdict of ``report.tables.judge`` (real only beyond the seed spread and the interval).
    Empty when no method has several seeds."""
    from .tables import judge, seed_labels, split_seed_label

    labels = list(dict.fromkeys(rows["method"]))
    found = {m: [m, *extra] for m, extra in seed_labels(labels).items() if m in labels}
    # a fixed order (the reference, then by name): the pairs' row order differs between the
    # scoring unit and a re-read pairs file, and the section must not
    seeded = {m: found[m] for m in sorted(found, key=lambda m: (m != compare_to, m))}

    def per_pair(method: str, col: str, scale: float) -> pd.Series:
        g = rows[rows["method"].isin(seeded[method])]
        return g.groupby("pair")[col].mean() * scale  # NaN seeds drop out of a pair's mean

    family = rows.drop_duplicates("pair").set_index("pair")["family"]
    out = []
    for method, members in seeded.items():
        for col, _, _, scale, _ in SEED_SCORES:
            means = [float(np.nanmean(rows.loc[rows["method"] == m, col].to_numpy(float))
                           * scale) for m in members]
            rec = {"method": method, "score": col, "seeds": len(members),
                   "seed_labels": " ".join(str(split_seed_label(m)[1] or 0) for m in members),
                   "mean": float(np.mean(means)), "seed_min": min(means), "seed_max": max(means),
                   "diff": np.nan, "diff_lo": np.nan, "diff_hi": np.nan, "spread": np.nan,
                   "verdict": ""}
            if method != compare_to and compare_to in seeded:
                ref_means = [float(np.nanmean(rows.loc[rows["method"] == m, col].to_numpy(float))
                                   * scale) for m in seeded[compare_to]]
                d = (per_pair(method, col, scale) - per_pair(compare_to, col, scale)).dropna()
                ci = bootstrap_ci(d.to_numpy(float), family.loc[d.index].to_numpy(),
                                  n_boot=n_boot, seed=seed) if len(d) else None
                j = judge(means, ref_means, ci)
                rec.update(diff=j.diff, spread=j.spread, verdict=j.verdict or "",
                           diff_lo=ci.lo if ci else np.nan, diff_hi=ci.hi if ci else np.nan)
            out.append(rec)
    return pd.DataFrame(out)


def render_seeds(judged: pd.DataFrame, compare_to: str = SEED_COMPARE_TO) -> list[str]:
    """The seeds section of the Markdown table (:func:`seed_judgements`); none when empty."""
    if not len(judged):
        return []
    lines = ["", f"Seeds: mean over seeds {{range of the per-seed means}}; against "
             f"{compare_to}: difference of seed means [paired 95 % interval over pairs], seed "
             "spread, verdict (real only when it exceeds both; docs/seeds_and_noise.md).", "",
             "| Method | Seeds | Score | Mean {min–max} | Difference [95 % CI] | Spread | "
             "Verdict |", "|---|---|---|---|---|---|---|"]
    names = {col: (title, unit, dec) for col, title, unit, _, dec in SEED_SCORES}
    for _, r in judged.iterrows():
        title, unit, dec = names[r["score"]]
        diff = "—" if not np.isfinite(r["diff"]) else (
            f"{r['diff']:+.{dec}f} [{r['diff_lo']:+.{dec}f}, {r['diff_hi']:+.{dec}f}]")
        spread = "—" if not np.isfinite(r["spread"]) else f"{r['spread']:.{dec}f}"
        lines.append(f"| {r['method']} | {r['seed_labels']} | {title} ({unit}) | "
                     f"{r['mean']:.{dec}f} {{{r['seed_min']:.{dec}f}–{r['seed_max']:.{dec}f}}} "
                     f"| {diff} | {spread} | {r['verdict'] or '—'} |")
    return lines


def sanity_gate(rows: pd.DataFrame) -> list[tuple[str, bool, str]]:
    """The gate: (check, passed, measured) for ``gt`` (every pair reproduces 1 and has a 0 m
    aperture error) and ``same-hands`` (every pair reproduces 0). Pairs whose change is NaN
    fail the gate: every pair of the split must be scoreable."""
    checks = []
    for method, want in (("gt", 1.0), ("same-hands", 0.0)):
        r = rows.loc[rows["method"] == method, "reproduced"].to_numpy(float)
        ok = bool(r.size) and bool(np.all(np.abs(r - want) <= GATE_TOL))
        got = f"min {np.min(r):.6f}, max {np.max(r):.6f} over {r.size} pairs" if r.size else "none"
        checks.append((f"{method}: change reproduced = {want:g} on every pair", ok, got))
    e = rows.loc[rows["method"] == "gt", "aperture_error"].to_numpy(float)
    ok = bool(e.size) and bool(np.all(np.abs(e) <= GATE_TOL))
    checks.append(("gt: aperture-change error = 0 mm on every pair", ok,
                   f"max {np.max(e) * 1000:.6f} mm" if e.size else "none"))
    return checks


def _cell(rec: pd.Series, col: str, decimals: int) -> str:
    if not np.isfinite(rec[col]):
        return "n/a"
    return (f"{rec[col]:.{decimals}f} [{rec[col + '_lo']:.{decimals}f}, "
            f"{rec[col + '_hi']:.{decimals}f}]")


def render_markdown(summary: pd.DataFrame, gate: list[tuple[str, bool, str]],
                    pairs: int, seeds: pd.DataFrame | None = None) -> str:
    """The table, its notes and the gate as Markdown."""
    lines = [
        f"## Geometry sensitivity (counterfactual split, {pairs} pairs, v{TABLE_VERSION})",
        "",
        "| Method | Change reproduced (%) ↑ | Aperture-change error (mm) ↓ | "
        "MPVPE A (mm) ↓ | MPVPE B (mm) ↓ | Pairs |",
        "|---|---|---|---|---|---|",
    ]
    for _, r in summary.iterrows():
        label = f"{r['method']} (reference)" if r["reference"] else r["method"]
        lines.append(f"| {label} | {_cell(r, 'reproduced', 1)} | {_cell(r, 'aperture_error', 2)} "
                     f"| {_cell(r, 'mpvpe_a', 2)} | {_cell(r, 'mpvpe_b', 2)} "
                     f"| {r['pairs']}/{r['pairs_total']} |")
    gt = summary.loc[summary["method"] == "gt", "gt_aperture_change_abs"]
    lines += [
        "",
        "Pairs share body, wrist and object motion; only the object's shape differs. Scored "
        "on the grasping hand, on frames held in both members; mean over pairs, 95 % "
        "bootstrap interval over pairs stratified by object family.",
        "Change reproduced: 1 - |d_m - d_gt| / |d_gt| (clipped to [0, 1]), d = hands_B - "
        "hands_A over held frames and vertices. Aperture: mean thumb-index / thumb-middle tip "
        "distance.",
    ]
    if len(gt) and np.isfinite(gt.iloc[0]):
        lines.append(f"Mean |ground-truth aperture change|: {gt.iloc[0]:.2f} mm.")
    lines += render_seeds(seeds) if seeds is not None else []
    lines += ["", "Sanity gate:"]
    lines += [f"- {'PASS' if ok else 'FAIL'}: {name} ({got})" for name, ok, got in gate]
    return "\n".join(lines) + "\n"


PAIR_COLUMNS = ("method", "pair", "family", "variant", "side", "grasp_kind", *SCORE_COLUMNS,
                "split")  # sensitivity_pairs.csv


def write_pairs_csv(path: str | os.PathLike, rows: pd.DataFrame | None) -> Path:
    """``sensitivity_pairs.csv``: :func:`score_pairs`' rows (SI units, 9 significant
    digits) with the split label; ``None`` or no rows: the header alone."""
    frame = pd.DataFrame(columns=list(PAIR_COLUMNS)) if rows is None or not len(rows) \
        else rows.assign(split=CF_SPLIT)
    return atomic_write_text(Path(path), frame.to_csv(index=False, float_format="%.9g"))


def read_pairs_csv(path: str | os.PathLike) -> pd.DataFrame:
    """The rows of a ``sensitivity_pairs.csv`` (as :func:`score_pairs` returned them, to 9
    significant digits), without the split column."""
    try:
        df = pd.read_csv(path, dtype={c: str for c in PAIR_COLUMNS[:6]},
                         keep_default_na=False, na_values=["nan", "NaN", ""])
    except (OSError, UnicodeDecodeError, pd.errors.ParserError) as e:
        raise InputError(f"not a readable CSV ({e})", path) from e
    missing = [c for c in PAIR_COLUMNS[:-1] if c not in df.columns]
    if missing:
        raise InputError(f"lacks columns {missing}", path)
    return df.drop(columns=["split"], errors="ignore")


def write_sensitivity(out_dir: str | os.PathLike, rows: pd.DataFrame,
                      tables_dir: str | os.PathLike | None = None,
                      pairs_file: bool = True) -> tuple[list[Path], bool]:
    """``OUT/sensitivity_pairs.csv`` (every pair, SI units; not with ``pairs_file=False``,
    when ``rows`` were read from it), ``geometry_sensitivity.csv`` and ``.md`` (the table,
    report units) in ``tables_dir`` (default ``OUT``). Returns the paths written and whether
    the gate passed."""
    out = Path(out_dir)
    tables = Path(tables_dir) if tables_dir is not None else out
    tables.mkdir(parents=True, exist_ok=True)
    summary = summarize(rows)
    gate = sanity_gate(rows)
    n_pairs = rows["pair"].nunique() if len(rows) else 0
    paths = [out / "sensitivity_pairs.csv", tables / "geometry_sensitivity.csv",
             tables / "geometry_sensitivity.md"]
    if pairs_file:
        write_pairs_csv(paths[0], rows)
    atomic_write_text(paths[1], summary.to_csv(index=False, float_format="%.6g"))
    seeds = seed_judgements(rows) if len(rows) else pd.DataFrame()
    atomic_write_text(paths[2], render_markdown(summary, gate, n_pairs, seeds))
    if len(seeds):
        paths.append(tables / "geometry_sensitivity_seeds.csv")
        atomic_write_text(paths[-1], seeds.to_csv(index=False, float_format="%.6g"))
    return paths if pairs_file else paths[1:], all(ok for _, ok, _ in gate)
