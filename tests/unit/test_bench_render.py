"""Rendering: hand-checked tables, bold-best, before→after, LaTeX/HTML structure, determinism."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
from html.parser import HTMLParser

import numpy as np
import pandas as pd
import pytest

from grip_bench.report.render import FORMATS, render, render_all, render_table
from grip_bench.report.tables import TABLES, compute_table
from grip_bench.results import schema as R
from grip_bench.results.schema import ResultRow, write_results, write_runtime
from grip_bench.results.stats import bootstrap_ci

from .test_bench_results import UNITS, synthetic_results

OBJECTS = ("mug", "apple", "mug")  # 3 sequences, 2 objects


def _frame(cells) -> pd.DataFrame:
    """{(method, perturbation, metric, hand): value or [values per sequence]} -> results."""
    rows = []
    for (method, pert, metric, hand), vals in cells.items():
        vals = vals if isinstance(vals, list) else [vals] * len(OBJECTS)
        for k, (obj, v) in enumerate(zip(OBJECTS, vals, strict=True)):
            rows.append(ResultRow(method, "synthgrab", "test", pert, f"s{k}", obj, hand, metric,
                                  v, UNITS[metric], 30))
    return R.validate(R.to_frame(rows))


PAPER_FUTURE = {  # GRIP Table 4-right: (right, left) MPVPE per number of future frames
    "grip-future0": (9.21, 8.18), "grip-future3": (8.94, 7.78),
    "grip-future5": (8.34, 7.29), "grip": (7.88, 6.17)}


def _future_frame(override=None):
    cells = {}
    for m, (r, lft) in PAPER_FUTURE.items():
        cells[(m, "none", "mpvpe", "right")] = r
        cells[(m, "none", "mpvpe", "left")] = lft
    cells.update(override or {})
    return _frame({k: v for k, v in cells.items() if v is not None})


EXPECTED_FUTURE_MD = """\
### Number of future frames vs accuracy

`table4_future` v2: GRIP trained with 0 / 3 / 5 / 10 future frames of object motion (GRIP Table 4, right)

| # Future frames | MPVPE R-Hand (mm) ↓ | MPVPE L-Hand (mm) ↓ |
|:--|--:|--:|
| 0 | 9.21 [9.21, 9.21] | 8.18 [8.18, 8.18] |
| 3 | 8.94 [8.94, 8.94] | 7.78 [7.78, 7.78] |
| 5 | 8.34 [8.34, 8.34] | 7.29 [7.29, 7.29] |
| 10 | **7.88** [7.88, 7.88] | **6.17** [6.17, 6.17] |

- 0 future frames runs in real time; n > 0 adds a latency of n frames (n / 30 s).
- 10 is the full GRIP model (its default cue), so that row is the grip run itself.
- Averaging: per sequence (each sequence's frames first, then the mean over sequences, every sequence weighing the same).
- Bold: the best value of each column among the methods, and every method the best does not beat: their per-sequence difference has a paired 95% bootstrap interval (sequences resampled within each object, seeded) that includes 0.
"""  # noqa: E501


def test_hand_checked_markdown():
    assert render_table("table4_future", _future_frame(), "md", n_boot=50) == EXPECTED_FUTURE_MD


def test_ties_at_display_precision_are_both_bold():
    df = _future_frame()
    df.loc[(df["method"] == "grip-future5") & (df["hand"] == "right"), "value"] = 7.8801
    md = render_table("table4_future", df, "md", n_boot=20)
    assert "| 5 | **7.88** [7.88, 7.88]" in md and "| 10 | **7.88** [7.88, 7.88]" in md


def _sequences_frame(values: dict, objects: list[str]) -> pd.DataFrame:
    """{method: per-sequence right-hand MPVPE values} -> results (sequence k of objects[k])."""
    rows = [ResultRow(m, "synthgrab", "test", "none", f"s{k}", obj, "right", "mpvpe", float(v),
                      UNITS["mpvpe"], 30)
            for m, vals in values.items() for k, (obj, v) in enumerate(zip(objects, vals,
                                                                             strict=True))]
    return R.validate(R.to_frame(rows))


def _naive_tied(a: np.ndarray, b: np.ndarray, objects: list[str], n_boot: int = 2000) -> bool:
    """Reference: the object-stratified paired bootstrap of mean(a - b), one loop per
    resample; tied when its 95% interval includes 0."""
    rng = np.random.default_rng(123)
    groups = [np.flatnonzero(np.asarray(objects) == o) for o in sorted(set(objects))]
    means = []
    for _ in range(n_boot):
        idx = np.concatenate([g[rng.integers(0, len(g), len(g))] for g in groups])
        means.append(float(np.mean(a[idx] - b[idx])))
    lo, hi = np.quantile(means, [0.025, 0.975])
    return bool(lo <= 0.0 <= hi)


def _shifted_and_noisy():
    rng = np.random.default_rng(0)
    objects = [f"o{k % 6}" for k in range(30)]
    base = 5.0 + 3.0 * rng.random(30)  # the sequences' difficulty: wide unpaired intervals
    return objects, {
        "grip": base,
        "grip-future0": base + 0.3,  # worse by 0.3 mm on every sequence: beaten
        "grip-future3": base + rng.choice([-0.2, 0.2], 30) + 0.01,  # noise around it: a tie
        "grip-future5": base + 0.4 + rng.choice([-0.05, 0.05], 30),  # worse, a little noise
    }


def test_a_method_the_best_does_not_beat_is_bold_too():
    objects, values = _shifted_and_noisy()
    df = _sequences_frame(values, objects)
    data = compute_table(TABLES.get("table4_future"), df, n_boot=2000)
    right = {r.label: r.cells[0] for r in data.rows}
    assert right["10"].best and not right["10"].tied
    # the unpaired intervals of the beaten rows reach the best mean: overlap alone would tie
    assert right["0"].ci.lo < right["10"].ci.mean < right["0"].ci.hi
    assert not right["0"].tied and not right["5"].tied and right["3"].tied
    label = {"0": "grip-future0", "3": "grip-future3", "5": "grip-future5"}
    for row, method in label.items():  # the same decision as a naive paired bootstrap
        assert right[row].tied == _naive_tied(values[method], values["grip"], objects), row
    md = render(data, "md")
    assert "| 3 | **" in md and "| 0 | **" not in md and "| 5 | **" not in md
    assert "paired 95% bootstrap interval" in md
    csv_rows = [line.split(",") for line in render(data, "csv").splitlines()]
    head = csv_rows[0]
    tied = {r[head.index("row")]: r[head.index("best_tied")] for r in csv_rows[1:]
            if r[head.index("hand")] == "right"}
    assert tied == {"0": "false", "3": "true", "5": "false", "10": "false"}


def test_leaderboard_marks_ties_from_its_results():
    from grip_bench.report.leaderboard import leaderboard, leaderboard_table

    objects, values = _shifted_and_noisy()
    renamed = {"grip": "grip", "toch": "grip-future0", "manipnet": "grip-future3",
               "gt": "grip-future5"}  # gt is a reference row: never best, never tied
    df = _sequences_frame({m: values[v] for m, v in renamed.items()}, objects)
    lb = leaderboard(df, n_boot=2000)
    plain = leaderboard_table(lb)
    marked = leaderboard_table(lb, results=df)
    before, after = ({r.label: r.cells[0] for r in t.rows} for t in (plain, marked))
    assert not any(c.tied for c in before.values())
    assert after["grip"].best and after["manipnet"].tied
    assert not after["toch"].tied and not after["gt"].tied
    assert any("paired 95% bootstrap" in n for n in marked.notes)


def test_missing_cells_and_nan_footnotes():
    df = _future_frame({("grip-future3", "none", "mpvpe", "left"): None,
                        ("grip-future0", "none", "mpvpe", "right"): [9.21, math.nan, 9.21]})
    md = render_table("table4_future", df, "md", n_boot=20)
    assert "| 0 | 9.21 [9.21, 9.21]¹ | 8.18" in md
    assert "| 3 | 8.94 [8.94, 8.94] | – |" in md
    assert "¹ 1 of 3 sequences gave NaN and are excluded." in md


def test_direction_and_reference_rows():
    cells = {}
    for m, iv, cr in [("grabnet", 2.65, 100.0), ("grabnet-smplx", 7.33, 87.0),
                      ("manipnet", 2.68, 98.0), ("grip-no-rnet", 3.18, 96.0),
                      ("grip", 2.38, 100.0), ("gt", 1.95, 100.0)]:
        cells[(m, "none", "iv", "right")] = iv
        cells[(m, "none", "contact_ratio", "right")] = cr
    md = render_table("table4_grasp", _frame(cells), "md", n_boot=20)
    assert "| Grasp synthesis | Penetr. (cm³) ↓ | Cont. ratio (%) ↑ |" in md
    assert "| GRIP (w/ RNet) | **2.38** [2.38, 2.38] | **100.00** [100.00, 100.00] |" in md
    assert "| GrabNet | 2.65 [2.65, 2.65] | **100.00** [100.00, 100.00] |" in md  # tie
    assert "| Ground truth | 1.95 [1.95, 1.95] | 100.00 [100.00, 100.00] |" in md  # reference


def _physics_frame(gt: float, flat: float, noisy: float) -> pd.DataFrame:
    cells = {}
    for m, pert, v in (("grip", "none", 40.0), ("grip-no-rnet", "none", 30.0),
                       ("gt", "none", gt), ("flat-input", "none", flat),
                       ("perturbed-input", "T0.01", noisy)):
        for hand in ("right", "left"):
            cells[(m, pert, "hold_qs", hand)] = v
    return _frame(cells)


def test_physics_sanity_gates_are_printed_under_the_table():
    md = render_table("physics", _physics_frame(85.0, 2.0, 30.0), "md", n_boot=20)
    assert "- Sanity gate PASS: Ground truth >= 80 % on Quasi-static hold (measured 85.0 %)" in md
    assert ("- Sanity gate PASS: Flat hand (control) <= 5 % on Quasi-static hold "
            "(measured 2.0 %)") in md
    assert ("- Sanity gate PASS: GRAB-T 0.01 input (control) between Flat hand (control) and "
            "Ground truth on Quasi-static hold (measured 30.0 against 2.0 and 85.0)") in md
    assert "| RNet (GRIP) | **40.00** [40.00, 40.00] |" in md  # the controls are not ranked
    data = compute_table(TABLES.get("physics"), _physics_frame(75.0, 6.0, 90.0), n_boot=20)
    assert [ok for _, ok, _ in data.gates] == [False, False, False, None, None, None]
    assert "- Sanity gate FAIL: Ground truth >= 80 % on Quasi-static hold (measured 75.0 %)" in \
        render(data, "md")
    missing = compute_table(TABLES.get("physics"), _physics_frame(85.0, 2.0, 30.0).query(
        "method != 'perturbed-input'"), n_boot=20)
    assert [ok for _, ok, _ in missing.gates][:3] == [True, True, None]  # a missing row: unchecked
    assert ("- Sanity gate NOT CHECKED: GRAB-T 0.01 input (control) between Flat hand (control) "
            "and Ground truth on Quasi-static hold (no value for GRAB-T 0.01 input (control))"
            ) in render(missing, "md")


def test_a_column_a_control_wins_marks_no_best():
    from grip_bench.report.leaderboard import leaderboard, leaderboard_table

    cells = {}
    for m, drift, cc in (("grip", 0.3, 13.0), ("toch", 0.6, 3.8), ("flat-input", 0.0, 60.0),
                         ("mean-pose", 0.0, 30.0), ("gt", 0.0, 0.0)):
        cells[(m, "none", "contact_drift", "right")] = drift
        cells[(m, "none", "cc", "right")] = cc
    t = leaderboard_table(leaderboard(_frame(cells)))
    best = {r.label: [c.best for c in r.cells] for r in t.rows}
    j_cc, j_drift = [c.group for c in t.columns].index("Contact consistency"), \
        [c.group for c in t.columns].index("Contact drift")
    assert best["toch"][j_cc] and not best["grip"][j_cc]  # the controls lose: toch is best
    assert not any(b[j_drift] for b in best.values())  # flat-input ties gt's 0: no best
    assert not best["flat-input"][j_cc] and not best["mean-pose"][j_drift]
    assert any("No best marked in Contact drift R-Hand: a control scores as well" in n
               for n in t.notes)
    assert any(n.startswith("Controls (flat-input, mean-pose") for n in t.notes)


def _table3_frame():
    cells = {("perturbed-input", "T0.01", "mpvpe", "right"): 16.0,
             ("perturbed-input", "T0.01", "mpvpe", "left"): 18.0,
             ("grip", "T0.01", "mpvpe", "right"): 10.3, ("grip", "T0.01", "mpvpe", "left"): 10.3,
             ("toch", "T0.01", "mpvpe", "right"): 11.8, ("toch", "T0.01", "mpvpe", "left"): 11.8,
             ("grip", "R0.3", "mpjpe", "right"): [3.0, 3.5, 4.0],
             ("grip", "none", "mpvpe", "right"): 1.0}  # clean runs must not leak in
    return _frame(cells)


def test_before_after_cells():
    md = render_table("table3_perturbation", _table3_frame(), "md", n_boot=200)
    lines = md.splitlines()
    assert "| Model | GRAB-T (0.01) | GRAB-T (0.02) | GRAB-R (0.3) | GRAB-R (0.5) |" in lines
    assert "| **MPVPE (mm) ↓** | | | | |" in lines
    mpvpe = lines[lines.index("| **MPVPE (mm) ↓** | | | | |") + 1:][:2]
    assert mpvpe[0] == "| TOCH-style | 17.00 → 11.80 [11.80, 11.80] | – | – | – |"
    assert mpvpe[1] == "| GRIP (ANet+RNet) | 17.00 → **10.30** [10.30, 10.30] | – | – | – |"
    # after without a before shows "–" before the arrow; sequences 3.0 (mug), 3.5 (apple),
    # 4.0 (mug): the apple, alone in its stratum, is resampled with the mugs, so the
    # interval is the plain bootstrap's of the three values (not the zero-spread apple's)
    plain = bootstrap_ci([3.0, 3.5, 4.0], None, n_boot=200)
    assert (plain.lo, plain.hi) == (pytest.approx(19 / 6), 4.0)
    assert "| GRIP (ANet+RNet) | – | – | – → **3.50** [3.17, 4.00] | – |" in md
    tidy = render_table("table3_perturbation", _table3_frame(), "csv", n_boot=20)
    row = [ln for ln in tidy.splitlines() if ",GRIP (ANet+RNet),false,GRAB-T,(0.01)," in ln
           and ",mpvpe," in ln][0]
    assert ",perturbed-input,17.0,17.0,17.0,3,0,true" in row


class _Balance(HTMLParser):
    VOID = {"meta", "img", "br", "hr", "input", "link"}

    def __init__(self):
        super().__init__()
        self.stack, self.errors = [], []

    def handle_starttag(self, tag, attrs):
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack.pop() != tag:
            self.errors.append(tag)


def _check_latex(tex: str, ncols: int) -> None:
    plain = tex.replace(r"\{", "").replace(r"\}", "")
    assert plain.count("{") == plain.count("}")
    pos = [tex.index(k) for k in (r"\begin{tabular}", r"\toprule", r"\midrule", r"\bottomrule",
                                  r"\end{tabular}")]
    assert pos == sorted(pos)
    env = "table*" if r"\begin{table*}" in tex else "table"
    assert tex.count(rf"\begin{{{env}}}") == tex.count(rf"\end{{{env}}}") == 1
    body = tex[tex.index(r"\midrule"):tex.index(r"\bottomrule")]
    for line in body.splitlines():
        if line.endswith(r"\\") and not line.startswith(r"\multicolumn"):
            assert len(re.findall(r"(?<!\\)&", line)) == ncols - 1, line


def test_every_table_renders_in_every_format(tmp_path):
    df = synthetic_results(
        methods=tuple(sorted({m for s in TABLES for m in s.methods()})),
        perturbations=("none", "T0.01", "T0.02", "R0.3", "R0.5"), n_seq=4,
        metrics=("mpvpe", "mpjpe", "cc", "iv", "contact_ratio", "sim_stable", "sim_disp",
                 "hold_sim", "hold_sim_disp"))
    runtime = pd.DataFrame({"method": ["grip"], "mode": ["full"], "device": ["cpu"],
                            "batch": [1], "seconds_per_frame": [0.022],
                            "frames_per_second": [45.0]})
    for spec in TABLES:
        data = compute_table(spec, df, runtime, n_boot=50)
        assert any(c.best for r in data.rows for c in r.cells), spec.id
        out = {fmt: render(data, fmt) for fmt in FORMATS}
        assert "**" in out["md"] and out["md"].count("\n|") >= len(spec.rows) + 1
        assert len(out["csv"].splitlines()) == 1 + len(data.rows) * len(spec.columns)
        _check_latex(out["tex"], len(spec.columns) + 1)
        assert r"\textbf{" in out["tex"]
        assert ("$\\downarrow$" in out["tex"]) or ("$\\uparrow$" in out["tex"])
        parser = _Balance()
        parser.feed(out["html"])
        assert not parser.errors and not parser.stack, spec.id
        assert '<table class="sortable">' in out["html"] and 'data-col="1"' in out["html"]
        assert "http" not in out["html"].replace("http-equiv", "")


def test_latex_escapes_labels():
    df = _future_frame()
    tex = render_table("table4_future", df, "tex", n_boot=20)
    assert r"\# Future frames" in tex and r"(mm) $\downarrow$" in tex
    assert r"\textbf{7.88} {\scriptsize [7.88, 7.88]}" in tex
    t3 = render_table("table3_perturbation", _table3_frame(), "tex", n_boot=20)
    assert r"17.00 $\rightarrow$ \textbf{10.30}" in t3 and r"\cmidrule(lr){2-3}" in t3


@pytest.mark.skipif(shutil.which("node") is None, reason="node not installed")
def test_html_click_to_sort_script(tmp_path):
    page = render_table("table4_future", _future_frame(), "html", n_boot=20)
    script = re.search(r"<script>(.*)</script>", page, re.S).group(1)
    (tmp_path / "sort.js").write_text(script)
    harness = """
const script = require('fs').readFileSync(process.argv[2], 'utf8');
function cell(t, v) { return {textContent: t, getAttribute: k => (k === 'data-v' && v !== undefined) ? v : null}; }
function row(l, v) { return {cells: [cell(l), cell(String(v), v === null ? undefined : String(v))],
                             classList: {contains: () => false}}; }
const tb = {rows: [row('b', 2), row('a', 3), row('c', null), row('d', 1)],
            appendChild(r) { this.rows.splice(this.rows.indexOf(r), 1); this.rows.push(r); }};
const handlers = {};
function th(col) { const a = {'data-col': String(col)};
  return {getAttribute: k => (k in a ? a[k] : null), setAttribute: (k, v) => { a[k] = v; },
          removeAttribute: k => { delete a[k]; }, addEventListener: (e, f) => { handlers[col] = f; }}; }
const table = {querySelectorAll: () => [th(0), th(1)], tBodies: [tb]};
global.document = {querySelectorAll: () => [table]};
eval(script);
const order = () => tb.rows.map(r => r.cells[0].textContent).join('');
handlers[1](); const asc = order(); handlers[1](); const desc = order(); handlers[0]();
console.log(asc + ' ' + desc + ' ' + order());
"""  # noqa: E501
    (tmp_path / "harness.js").write_text(harness)
    out = subprocess.run(["node", str(tmp_path / "harness.js"), str(tmp_path / "sort.js")],
                         capture_output=True, text=True, timeout=60, check=True).stdout
    assert out.strip() == "dbac abdc abcd"  # empty cells last in both directions


def _results_dir(tmp_path, datasets=("synthgrab",)):
    frames = [synthetic_results(methods=("grip", "grip-no-rnet", "gt", "toch",
                                         "perturbed-input"),
                                perturbations=("none", "T0.01"), n_seq=4, dataset=d,
                                metrics=("mpvpe", "iv", "sim_stable")) for d in datasets]
    res = tmp_path / "res"
    write_results(pd.concat(frames), res / "results.csv")
    write_runtime(pd.DataFrame({"method": ["grip", "grip"], "mode": ["full"] * 2,
                                "device": ["cpu"] * 2, "batch": [1, 1],
                                "seconds_per_frame": [0.02, 0.03],
                                "frames_per_second": [50.0, 33.3]}), res / "runtime.csv")
    return res


def test_render_all_is_byte_deterministic(tmp_path):
    res = _results_dir(tmp_path)
    a = render_all(res, tmp_path / "a", n_boot=100)
    b = render_all(res, tmp_path / "b", n_boot=100)
    assert len(a) == len(TABLES) * len(FORMATS)
    for pa, pb in zip(a, b, strict=True):
        assert pa.name == pb.name and pa.read_bytes() == pb.read_bytes()
    assert "GRIP (CNet + RNet) (full, cpu, batch 1)" in (tmp_path / "a" / "runtime.md").read_text()


def test_render_all_splits_datasets(tmp_path):
    res = _results_dir(tmp_path, datasets=("grab", "synthgrab"))
    written = render_all(res, tmp_path / "out", formats=("md",), n_boot=20)
    names = sorted(str(p.relative_to(tmp_path / "out")) for p in written)
    assert "grab/table2_ablation.md" in names and "synthgrab/physics.md" in names
    assert "runtime.md" in names and len(names) == 2 * (len(TABLES) - 1) + 1


def test_table_only_metrics_are_left_off_the_leaderboard():
    from grip_bench.report.leaderboard import leaderboard

    cells = {(m, "none", metric, "right"): 50.0 for m in ("grip", "gt")
             for metric in ("hold_qs", "hold_qs_mu3")}
    df = _frame({k: v for k, v in cells.items()})
    assert set(leaderboard(df)["metric"]) == {"hold_qs"}


def test_render_all_writes_only_the_chosen_tables(tmp_path):
    from grip_bench.core.errors import InputError

    res = _results_dir(tmp_path)
    written = render_all(res, tmp_path / "out", formats=("md",), n_boot=20,
                         tables=["table4_future", "table2_ablation"])
    assert sorted(p.name for p in written) == ["table2_ablation.md", "table4_future.md"]
    # the same bytes as the table rendered among all of them
    full = render_all(res, tmp_path / "all", formats=("md",), n_boot=20)
    assert {p.name for p in full} >= {"physics.md", "runtime.md"}
    for p in written:
        assert p.read_bytes() == (tmp_path / "all" / p.name).read_bytes()
    with pytest.raises(InputError, match="no_such_table"):
        render_all(res, tmp_path / "bad", formats=("md",), n_boot=20, tables=["no_such_table"])


def test_write_report_follows_the_runs_tables_and_drops_stale_ones(tmp_path):
    """A run that chose two tables gets those two in OUT/tables/: files of the other
    registered tables (an earlier report's) are removed, anything else is left alone."""
    from grip_bench.report.write import write_report
    from grip_bench.results.manifest import write_manifest

    out = _results_dir(tmp_path)
    tables = out / "tables"
    tables.mkdir()
    for name in ("physics.md", "runtime.tex", "notes.md"):
        (tables / name).write_text("stale", encoding="utf-8")
    write_manifest(out / "manifest.json", {"config": {
        "tables": ["table2_ablation", "table4_future"],
        "report": {"bootstrap_n": 20, "bootstrap_seed": 0, "figure_methods": [],
                   "split": "test", "averaging": "sequence"}}})
    write_report(out)
    names = {p.name for p in tables.iterdir()}
    assert {f"table2_ablation.{f}" for f in FORMATS} <= names
    assert {f"table4_future.{f}" for f in FORMATS} <= names
    assert not any(n.startswith(("physics.", "runtime.", "table3_", "table4_grasp."))
                   for n in names)
    assert (tables / "notes.md").read_text(encoding="utf-8") == "stale"
    assert (out / "runtime.csv").is_file()  # the run's data stays; only its table goes
