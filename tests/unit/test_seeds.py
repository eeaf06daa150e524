"""Several training seeds ([run] seeds): planning, the seeded tables and their verdicts.

The verdict rule is tested on hand-made numbers (``judge``), the paired interval on an
analytic case, the tables on a small synthetic results frame of two seeds, the plan on the
tiny run profile (nothing is built: planning needs no data).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from grip_bench.bench.cache import Cache
from grip_bench.bench.plan import build_plan, make_config, run_seeds, run_settings
from grip_bench.core.errors import InputError
from grip_bench.report.render import SEED_CSV_COLUMNS, table_html, to_csv, to_latex, to_markdown
from grip_bench.report.tables import (
    VERDICT_DIFFERS,
    VERDICT_NOISE,
    compute_table,
    is_seed_label,
    judge,
    paired_difference_ci,
    parse_table,
    seed_label,
    seed_labels,
    split_seed_label,
)
from grip_bench.results.stats import CI
from tests.run_fixtures import TINY_RUN, tiny_run_profile


# --- labels ----------------------------------------------------------------------------------
def test_seed_labels_round_trip():
    assert seed_label("grip", 1) == "grip@seed1"
    assert split_seed_label("grip@seed12") == ("grip", 12)
    assert split_seed_label("grip-no-rnet") == ("grip-no-rnet", None)
    assert split_seed_label("odd@seedx") == ("odd@seedx", None)
    assert is_seed_label("grip-future0@seed2") and not is_seed_label("grip")
    assert seed_labels(["grip", "grip@seed2", "grip@seed1", "gt", "nn@seed3"]) == {
        "grip": ["grip@seed1", "grip@seed2"], "nn": ["nn@seed3"]}


# --- the verdict rule on hand-made numbers ----------------------------------------------------
def _ci(lo: float, hi: float) -> CI:
    return CI((lo + hi) / 2, lo, hi, 30, 0)


def test_judge_differs_only_beyond_spread_and_interval():
    ref = [4.0, 4.1, 4.2]  # range 0.2
    # difference 1.0: beyond the range 0.2 and the interval [0.8, 1.2] excludes 0
    j = judge([5.0, 5.1, 5.2], ref, _ci(0.8, 1.2))
    assert j.verdict == VERDICT_DIFFERS
    assert j.diff == pytest.approx(1.0) and j.spread == pytest.approx(0.2)
    # the same difference, but the interval reaches 0: within noise
    assert judge([5.0, 5.1, 5.2], ref, _ci(-0.1, 2.1)).verdict == VERDICT_NOISE
    # a clear interval, but the seeds spread wider than the difference: within noise
    j = judge([4.0, 4.4, 5.0], [4.0, 4.05, 4.1], _ci(0.2, 0.3))
    assert j.diff == pytest.approx(4.4666667 - 4.05) and j.spread == pytest.approx(1.0)
    assert j.verdict == VERDICT_NOISE
    # the larger of the two ranges counts: the reference's here
    assert judge([5.0, 5.0, 5.0], [4.0, 4.0, 5.5], _ci(0.1, 0.9)).verdict == VERDICT_NOISE
    # a negative difference (the variant better) is judged the same way
    assert judge([3.0, 3.1, 3.2], ref, _ci(-1.2, -0.8)).verdict == VERDICT_DIFFERS
    # equal to the spread is not beyond it
    assert judge([4.2, 4.3, 4.4], [4.0, 4.1, 4.2], _ci(0.1, 0.3)).verdict == VERDICT_NOISE


def test_judge_needs_two_seeds_on_both_rows_and_an_interval():
    assert judge([5.0], [4.0, 4.1], _ci(0.8, 1.2)).verdict is None
    assert judge([5.0, 5.1], [4.0, np.nan], _ci(0.8, 1.2)).verdict is None
    assert judge([5.0, 5.1], [4.0, 4.1], None).verdict is None
    assert judge([5.0, 5.1], [4.0, 4.1], CI(np.nan, np.nan, np.nan, 0, 3)).verdict is None
    assert np.isnan(judge([], [4.0], None).diff)


# --- the paired interval ----------------------------------------------------------------------
def _rows(method: str, values: dict[str, float], metric: str = "mpvpe",
          hand: str = "right") -> pd.DataFrame:
    return pd.DataFrame([{"method": method, "dataset": "synthgrab", "split": "test",
                          "perturbation": "none", "sequence": seq, "object": seq.split("_")[0],
                          "hand": hand, "metric": metric, "value": v, "unit": "mm",
                          "n_frames": 10} for seq, v in values.items()])


def test_paired_difference_of_a_constant_shift_is_exact():
    base = {f"obj{i % 3}_s{i}": float(v) for i, v in
            enumerate(np.random.default_rng(0).uniform(2, 9, 12))}
    a = _rows("a", {k: v + 0.5 for k, v in base.items()})
    b = _rows("b", base)
    ci = paired_difference_ci(a, b, n_boot=500, seed=0)
    # every resample's difference is 0.5 although the values spread 2-9 mm: paired
    assert ci.mean == pytest.approx(0.5) and ci.lo == pytest.approx(0.5)
    assert ci.hi == pytest.approx(0.5) and (ci.n, ci.n_nan) == (12, 0)
    # a sequence missing on one side is left out and counted
    ci = paired_difference_ci(a, b.iloc[1:], n_boot=200, seed=0)
    assert (ci.n, ci.n_nan) == (11, 1)
    # naive reference: the mean of the per-sequence differences
    noisy = _rows("a", {k: v + 0.5 + 0.1 * np.sin(i) for i, (k, v) in enumerate(base.items())})
    ci = paired_difference_ci(noisy, b, n_boot=500, seed=1)
    naive = np.mean([0.5 + 0.1 * np.sin(i) for i in range(12)])
    assert ci.mean == pytest.approx(naive) and ci.lo < naive < ci.hi


# --- seeded tables ----------------------------------------------------------------------------
TABLE = {
    "id": "seeded_test", "version": 1, "title": "t", "description": "d",
    "compare_to": "full",
    "defaults": {"split": "test", "perturbation": "none", "metric": "mpvpe"},
    "rows": [{"label": "Variant far", "method": "far"}, {"label": "Variant near",
                                                         "method": "near"},
             {"label": "Full", "method": "full"}, {"label": "Fixed", "method": "fixed",
                                                   "reference": True}],
    "columns": [{"group": "MPVPE", "hand": "right"}],
}


def _seeded_results() -> pd.DataFrame:
    rng = np.random.default_rng(3)
    seqs = [f"obj{i % 4}_s{i}" for i in range(24)]
    difficulty = rng.uniform(3, 8, len(seqs))
    parts = []
    for method, shift in (("full", 0.0), ("far", 2.0), ("near", 0.05)):
        for k, seed_shift in enumerate((0.0, 0.3, -0.2)):  # seed spread 0.5 mm
            label = method if k == 0 else seed_label(method, k)
            parts.append(_rows(label, {s: d + shift + seed_shift for s, d in
                                       zip(seqs, difficulty, strict=True)}))
    parts.append(_rows("fixed", dict(zip(seqs, difficulty + 1.0, strict=True))))
    return pd.concat(parts, ignore_index=True)


def test_seeded_table_cells_verdicts_and_renderings():
    spec = parse_table(TABLE, "seeded_test")
    data = compute_table(spec, _seeded_results(), n_boot=300, seed=0)
    assert data.n_seeds == 3 and data.verdict_header == "Verdict vs Full"
    far, near, full, fixed = data.rows
    # the cell is the mean over seeds (per-seed means: shift + 0, + 0.3, - 0.2)
    m_full = full.cells[0].seed_means
    assert len(m_full) == 3 and m_full[1] - m_full[0] == pytest.approx(0.3)
    assert full.cells[0].ci.mean == pytest.approx(np.mean(m_full))
    assert far.cells[0].ci.mean - full.cells[0].ci.mean == pytest.approx(2.0)
    # 2 mm beyond a 0.5 mm seed range and a paired interval at 2 mm: differs (worse)
    assert far.cells[0].judged.verdict == VERDICT_DIFFERS
    assert far.verdict == "differs: MPVPE R-Hand (worse)"
    # 0.05 mm: the paired interval excludes 0 (constant shift) but the seeds spread 0.5 mm
    assert near.cells[0].judged.verdict == VERDICT_NOISE and near.verdict == VERDICT_NOISE
    assert full.verdict == "reference"
    # a fixed method has one seed: shown without a range, not judged
    assert fixed.cells[0].seed_means == (pytest.approx(full.cells[0].seed_means[0] + 1.0),)
    assert fixed.verdict == "–"
    md = to_markdown(data)
    assert "Verdict vs Full" in md and "differs: MPVPE R-Hand (worse)" in md
    assert f"{{{m_full[2]:.2f}–{m_full[1]:.2f}}}" in md  # the seed range, min-max
    assert "Seeds: each trained method's cell is the mean over its 3 training seeds" in md
    csv_text = to_csv(data)
    header = csv_text.splitlines()[0].split(",")
    assert header[-len(SEED_CSV_COLUMNS):] == list(SEED_CSV_COLUMNS)
    far_line = csv_text.splitlines()[1].split(",")
    assert far_line[header.index("verdict")] == VERDICT_DIFFERS
    assert far_line[header.index("n_seeds")] == "3"
    assert "Verdict vs Full" in table_html(data) and "Verdict vs Full" in to_latex(data)


def test_single_seed_tables_render_as_before():
    """Without seed rows the table computes on the old path: no ranges, no verdicts, no
    seed columns, and the same cells as a table without compare_to."""
    results = _seeded_results()
    single = results[~results["method"].map(is_seed_label)]
    spec = parse_table(TABLE, "seeded_test")
    plain = parse_table({k: v for k, v in TABLE.items() if k != "compare_to"}, "seeded_test")
    data, ref = (compute_table(s, single, n_boot=300, seed=0) for s in (spec, plain))
    assert data.n_seeds == 1 and data.verdict_header is None
    assert all(c.seed_means == () and c.judged is None for r in data.rows for c in r.cells)
    assert all(r.verdict is None for r in data.rows)
    for render in (to_markdown, to_csv, to_latex, table_html):
        assert render(data) == render(ref)
    assert "{" not in to_markdown(data) and "verdict" not in to_csv(data)


def test_compare_to_must_name_a_row_method():
    with pytest.raises(InputError, match="compare_to 'nobody'"):
        parse_table({**TABLE, "compare_to": "nobody"}, "seeded_test")


# --- settings and plan ------------------------------------------------------------------------
def test_run_seeds_puts_seed_first_and_checks_the_list():
    assert run_seeds({"seed": 0, "seeds": []}) == (0,)
    assert run_seeds({"seed": 0}) == (0,)
    assert run_seeds({"seed": 1, "seeds": [0, 1, 2]}) == (1, 0, 2)
    for bad, msg in (([1, 2], "must include seed"), ([0, 0, 1], "twice"),
                     ([0, -1], "integers >= 0"), ([0, 1.5], "integers >= 0"),
                     ([0, True], "integers >= 0")):
        with pytest.raises(InputError, match=msg):
            run_seeds({"seed": 0, "seeds": bad})


def test_run_settings_checks_capture_noise():
    base = {"run": dict(TINY_RUN)}
    assert run_settings(base, "p")["capture_noise"] == "none"
    with pytest.raises(InputError, match="capture_noise must be one of"):
        run_settings({"run": {**TINY_RUN, "capture_noise": "vicon"}}, "p")
    with pytest.raises(InputError, match="applies to generated SynthGRAB"):
        run_settings({"run": {**TINY_RUN, "capture_noise": "grab", "data": "grab"}}, "p")


RUN = {"methods": ["gt", "nearest-neighbour"], "tables": ["table4_grasp"]}


def _plan(tmp_path, name: str, **overrides):
    path = tiny_run_profile(tmp_path / f"{name}.toml", **{**RUN, **overrides})
    cfg = make_config(str(path), out=tmp_path / "out", progress=False)
    return cfg, build_plan(cfg, Cache(tmp_path / "out" / "cache"))


def test_two_seeds_plan_a_unit_per_method_and_seed(tmp_path):
    _, one = _plan(tmp_path, "one")
    cfg, two = _plan(tmp_path, "two", seeds=[0, 7])
    assert cfg.seeds == (0, 7)
    # the first seed's units are exactly those of the single-seed plan
    assert {u.key for u in one.units} <= {u.key for u in two.units}
    new = [u for u in two.units if u.key not in {v.key for v in one.units}]
    # the trainable method trains, predicts and is evaluated once more; gt does not
    assert sorted((u.kind, u.label) for u in new) == [
        ("checkpoint", "train nearest-neighbour (seed 7)"),
        ("metrics", "evaluate nearest-neighbour@seed7 @ none"),
        ("prediction", "predict nearest-neighbour @ none (seed 7)")]
    ckpt = next(u for u in new if u.kind == "checkpoint")
    pred = next(u for u in new if u.kind == "prediction")
    met = next(u for u in new if u.kind == "metrics")
    assert ckpt.params["inputs"]["seed"] == 7 and ckpt.params["seed"] == 7
    assert pred.params["inputs"]["seed"] == 7 and pred.params["checkpoint"] == ckpt.key
    assert met.params["labels"]["method"] == "nearest-neighbour@seed7"
    assert met.params["prediction"] == pred.key
    # the runtime stage times the first seed only
    assert len(two.of("runtime")) == len(one.of("runtime"))


def test_empty_seeds_and_no_noise_leave_every_key_unchanged(tmp_path):
    """A profile written before these keys existed plans the same units as one with their
    defaults (`seeds = []`, `capture_noise = "none"`)."""
    run = {k: v for k, v in TINY_RUN.items() if k not in ("seeds", "capture_noise")}
    old = tmp_path / "old.toml"
    old.write_text("[run]\n" + "\n".join(f"{k} = {v!r}".replace("'", '"').replace(
        "False", "false") for k, v in {**run, **RUN}.items()) + "\n", encoding="utf-8")
    cfg = make_config(str(old), out=tmp_path / "out", progress=False)
    before = build_plan(cfg, Cache(tmp_path / "out" / "cache"))
    _, now = _plan(tmp_path, "now", seeds=[], capture_noise="none")
    assert [u.key for u in before.units] == [u.key for u in now.units]
    (data,) = now.of("dataset")
    assert "capture_noise" not in data.params["inputs"]


def test_capture_noise_enters_only_the_noisy_dataset_key(tmp_path):
    _, clean = _plan(tmp_path, "clean")
    _, noisy = _plan(tmp_path, "noisy", capture_noise="grab")
    (c,), (n,) = clean.of("dataset"), noisy.of("dataset")
    assert c.key != n.key and n.params["inputs"]["capture_noise"]["model"] == "grab"
    assert n.params["inputs"]["capture_noise"]["penetration_mean"] == pytest.approx(0.00325)
    assert n.params["inputs"]["code"] != c.params["inputs"]["code"]  # + stages.capture
    assert "capture_noise=grab" in n.label


def test_the_runner_runs_a_further_seed_with_its_own_seed(tmp_path):
    from grip_bench.bench.runner import with_unit_seed

    cfg, plan = _plan(tmp_path, "wrap", seeds=[0, 7])
    seen = []

    def stage(st, unit, tmp):
        seen.append((unit.label, st.cfg.seed, st.cfg.settings["seed"]))
        return {}

    st = dataclasses.make_dataclass("S", [("cfg", object)])(cfg)
    for unit in plan.of("checkpoint") + plan.of("prediction"):
        with_unit_seed(stage, st, unit, tmp_path)
    assert ("train nearest-neighbour (seed 7)", 7, 7) in seen
    assert ("predict nearest-neighbour @ none (seed 7)", 7, 7) in seen
    assert ("train nearest-neighbour", 0, 0) in seen
    assert cfg.seed == 0  # the run's own configuration is not changed


def test_leaderboard_leaves_further_seeds_out(tmp_path):
    from grip_bench.report.write import write_leaderboards

    results = _seeded_results()
    written = write_leaderboards(tmp_path, results, {"bootstrap_seed": 0, "bootstrap_n": 50},
                                 [])
    text = next(p for p in written if p.suffix == ".csv").read_text(encoding="utf-8")
    assert "full," in text and "@seed" not in text
