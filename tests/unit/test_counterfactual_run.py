"""The counterfactual geometry split inside ``grip-bench run`` ([run] counterfactual_sources,
counterfactual_methods): planning (keys unchanged when off, the new units when on, which
methods are scored) and the report's table rebuilt from ``OUT/sensitivity_pairs.csv``.

Nothing is built here: planning needs no data, and the report test writes hand-made pair
rows whose summary is known in advance. The run itself is
``tests/integration/test_counterfactual_run.py``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from grip_bench.bench.cache import Cache
from grip_bench.bench.codehash import CodeIndex
from grip_bench.bench.plan import (
    _counterfactual_units,
    _data_unit,
    build_plan,
    counterfactual_methods,
    make_config,
    run_settings,
    stage_code,
)
from grip_bench.core import constants as C
from grip_bench.core.errors import InputError
from grip_bench.report.sensitivity import read_pairs_csv, write_pairs_csv
from grip_bench.report.write import SENSITIVITY_PAIRS, write_report, write_sensitivity_report
from grip_bench.results.layout import CLEAN
from tests.run_fixtures import TINY_RUN, tiny_run_profile

RUN = {"methods": ["gt", "mean-pose", "nearest-arm", "nearest-neighbour"],
       "tables": ["table4_grasp"]}


def _plan(tmp_path, name: str, **overrides):
    path = tiny_run_profile(tmp_path / f"{name}.toml", **{**RUN, **overrides})
    cfg = make_config(str(path), out=tmp_path / "out", progress=False)
    return cfg, build_plan(cfg, Cache(tmp_path / "out" / "cache"))


# --- settings ---------------------------------------------------------------------------------
def test_run_settings_checks_the_counterfactual_keys():
    assert run_settings({"run": dict(TINY_RUN)}, "p")["counterfactual_sources"] == 0
    for bad in (-1, 1.5, True, "3"):
        with pytest.raises(InputError, match="counterfactual_sources must be an integer"):
            run_settings({"run": {**TINY_RUN, "counterfactual_sources": bad}}, "p")
    with pytest.raises(InputError, match="counterfactual_methods must be method names"):
        run_settings({"run": {**TINY_RUN, "counterfactual_methods": ["grip", 3]}}, "p")
    with pytest.raises(InputError, match="counterfactual_methods must be method names"):
        run_settings({"run": {**TINY_RUN, "counterfactual_methods": "grip"}}, "p")


def test_profiles_list_the_keys():
    from grip_bench.profiles import NAMES, load_profile

    found = {name: (load_profile(name)["run"]["counterfactual_sources"],
                    load_profile(name)["run"]["counterfactual_methods"]) for name in NAMES}
    assert found == {"smoke": (0, []), "default": (24, []), "paper": (48, []),
                     "ablation": (24, [])}


# --- planning ---------------------------------------------------------------------------------
def test_off_leaves_every_key_unchanged(tmp_path):
    """A profile written before these keys existed plans the same units as one with them at
    their off values; neither plans a counterfactual or sensitivity unit."""
    run = {k: v for k, v in TINY_RUN.items()
           if k not in ("counterfactual_sources", "counterfactual_methods")}
    old = tmp_path / "old.toml"
    old.write_text("[run]\n" + "\n".join(f"{k} = {v!r}".replace("'", '"').replace(
        "False", "false") for k, v in {**run, **RUN}.items()) + "\n", encoding="utf-8")
    cfg = make_config(str(old), out=tmp_path / "out", progress=False)
    assert "counterfactual_sources" not in old.read_text(encoding="utf-8")
    # absent means off (profiles.OFF_WHEN_ABSENT), not the default profile's 24
    assert cfg.settings["counterfactual_sources"] == 0
    assert cfg.settings["counterfactual_methods"] == []
    before = build_plan(cfg, Cache(tmp_path / "out" / "cache"))
    _, now = _plan(tmp_path, "now", counterfactual_sources=0,
                   counterfactual_methods=["nearest-arm"])
    assert [(u.label, u.key) for u in before.units] == [(u.label, u.key) for u in now.units]
    assert not now.of("counterfactual") and not now.of("sensitivity")
    assert not [n for n in now.notes if "counterfactual" in n]


def test_on_adds_the_split_its_predictions_and_one_scoring_unit(tmp_path):
    """Every unit of the run without the split keeps its key; the split adds one dataset
    unit, a prediction per scored method and seed (clean context, no metrics unit; a
    further seed's labelled ``<method>@seed<N>``) and the sensitivity unit that reads them."""
    _, off = _plan(tmp_path, "off")
    cfg, on = _plan(tmp_path, "on", counterfactual_sources=3, seeds=[0, 5])
    _, off_seeds = _plan(tmp_path, "off_seeds", seeds=[0, 5])
    assert {u.key for u in off.units} < {u.key for u in on.units}
    old = {u.key for u in off_seeds.units}
    assert old < {u.key for u in on.units}
    new = [u for u in on.units if u.key not in old]
    assert sorted((u.kind, u.label) for u in new) == [
        ("counterfactual", "counterfactual split: synthgrab profile=tiny seed=0 sources=3"),
        ("prediction", "predict nearest-arm @ counterfactual"),
        ("prediction", "predict nearest-arm @ counterfactual (seed 5)"),
        ("prediction", "predict nearest-neighbour @ counterfactual"),
        ("prediction", "predict nearest-neighbour @ counterfactual (seed 5)"),
        ("sensitivity", "geometry sensitivity of 4 method(s)")]
    (cf,) = on.of("counterfactual")
    (data,) = on.of("dataset")
    inputs = cf.params["inputs"]
    assert (inputs["profile"], inputs["seed"], inputs["sources"]) == ("tiny", 0, 3)
    assert inputs["constants"]["variants"] == C.CF_VARIANTS
    assert inputs["constants"]["min_change"] == C.CF_MIN_CHANGE
    assert data.key not in cf.deps  # the pairs are made from profile and seed, not the files
    # the split's code is the generator's closure, not the scoring's
    closure = CodeIndex.installed().closure(["grip_bench.bench.stages.counterfactual"])
    assert "grip_bench.data.synth.counterfactual" in closure
    assert "grip_bench.report.sensitivity" not in closure
    assert inputs["code"] == stage_code("counterfactual")
    preds = [u for u in new if u.kind == "prediction"]
    ckpts = {(u.params["method"], u.params.get("seed", 0)): u.key for u in on.of("checkpoint")}
    for u in preds:
        seed = u.params.get("seed", 0)
        assert u.params["input"] == cf.key and u.params["perturbation"] == CLEAN
        assert u.params["checkpoint"] == ckpts[(u.params["method"], seed)]  # its seed's
        assert u.params["inputs"]["seed"] == seed
        assert u.params["inputs"]["train_data"] == data.key
        assert cf.key in u.deps and data.key in u.deps
    # no metrics unit reads them: nothing of the split reaches results.csv
    assert not {u.key for u in preds} & {u.params["prediction"] for u in on.of("metrics")}
    (sens,) = on.of("sensitivity")
    label = {0: "{}", 5: "{}@seed5"}
    assert sens.params["predictions"] == {
        label[u.params.get("seed", 0)].format(u.params["method"]): u.key for u in preds}
    # the first seed's units are a single-seed run's
    _, single = _plan(tmp_path, "single", counterfactual_sources=3)
    assert {u.key for u in single.of("prediction") if "counterfactual" in u.label} == {
        u.key for u in preds if "seed" not in u.params}
    assert set(sens.deps) == {cf.key, *(u.key for u in preds)}
    assert sens.params["inputs"]["min_gt_rms"] == C.CF_MIN_GT_RMS
    # the units run in stage order: the split before training, scoring after evaluation
    kinds = [u.kind for u in on.units]
    assert kinds.index("counterfactual") < kinds.index("checkpoint")
    assert kinds.index("sensitivity") > max(i for i, k in enumerate(kinds) if k == "metrics")
    assert any("not in this run, not scored" in n and "grip-blind" in n for n in on.notes)
    assert cfg.settings["counterfactual_sources"] == 3


def test_default_methods_are_table_2_and_the_learned_leaderboard_methods(tmp_path):
    cfg, _ = _plan(tmp_path, "all", methods=["gt", "mean-pose", "grip", "grip-no-rnet",
                                             "grip-blind", "nearest-arm", "toch", "manipnet"],
                   counterfactual_sources=1)
    chosen, notes = counterfactual_methods(cfg)
    # in the run's order; gt is a reference row, mean-pose and toch are not in the list
    assert chosen == ["grip", "grip-no-rnet", "grip-blind", "nearest-arm", "manipnet"]
    (note,) = notes
    assert "grabnet-smplx" in note and "nearest-neighbour" in note and "grip-no-ambient" in note
    cfg, _ = _plan(tmp_path, "named", counterfactual_sources=1,
                   counterfactual_methods=["mean-pose", "nearest-arm"])
    assert counterfactual_methods(cfg) == (["mean-pose", "nearest-arm"], [])


@pytest.mark.parametrize("names, message", [
    (["gt"], "reference row"),
    (["grip"], "not one of this run's methods"),
    (["perturbed-input"], "does not predict the clean test split"),
    (["no-such-method"], "no-such-method"),
])
def test_named_methods_are_checked(tmp_path, names, message):
    methods = RUN["methods"] + ["perturbed-input"]
    path = tiny_run_profile(tmp_path / "p.toml", **{**RUN, "methods": methods},
                            counterfactual_sources=2, counterfactual_methods=names)
    cfg = make_config(str(path), out=tmp_path / "out", progress=False)
    with pytest.raises(InputError, match=message):
        build_plan(cfg, Cache(tmp_path / "out" / "cache"))


def test_imported_data_or_no_scored_method_skips_the_split_with_a_note(tmp_path):
    """Real GRAB (or any --data) has no generator, and a run without a method to score has
    nothing to compare: no unit, a note for the log."""
    cfg, _ = _plan(tmp_path, "grab", counterfactual_sources=4)
    units = []
    data = _data_unit(cfg, units)
    on_import = dataclasses.replace(cfg, data=tmp_path)
    notes = _counterfactual_units(on_import, data, {}, units)
    assert units == [data] and len(notes) == 1
    assert "counterfactual_sources = 4 skipped" in notes[0] and "no generator" in notes[0]
    no_method = dataclasses.replace(cfg, methods=("gt", "mean-pose"))
    notes = _counterfactual_units(no_method, data, {}, units)
    assert units == [data] and "none of this run's methods is scored" in notes[-1]
    with_noise = dataclasses.replace(cfg, settings={**cfg.settings, "capture_noise": "grab"})
    ckpts = {(m, 0): None for m in cfg.methods}
    notes = _counterfactual_units(with_noise, data, ckpts, units)
    assert any("without capture noise" in n for n in notes)


# --- the report from OUT alone ------------------------------------------------------------------
def _rows() -> pd.DataFrame:
    """Two pairs of two families; a sighted method reproducing 60 % and 80 % of the change,
    a blind one 0 %, and the references (exact by construction)."""
    rows = []
    for pair, family, gt_ap in (("cf1", "mug", 0.004), ("cf2", "cube", -0.002)):
        base = {"pair": pair, "family": family, "variant": "smaller", "side": "right",
                "grasp_kind": "power", "gt_aperture_change": gt_ap, "n_frames": 40.0}
        for method, rep, ap_err, ma, mb in (
                ("gt", 1.0, 0.0, 0.0, 0.0), ("same-hands", 0.0, abs(gt_ap), 0.0, 0.002),
                ("sighted", 0.6 if pair == "cf1" else 0.8, 0.001, 0.01, 0.012),
                ("blind", 0.0, abs(gt_ap), 0.02, 0.021)):
            rows.append({"method": method, **base, "reproduced": rep, "aperture_error": ap_err,
                         "mpvpe_a": ma, "mpvpe_b": mb, "mpvpe": (ma + mb) / 2})
    return pd.DataFrame(rows)


def test_the_table_is_rebuilt_from_the_pairs_file(tmp_path):
    out = tmp_path / "out"
    write_pairs_csv(out / SENSITIVITY_PAIRS, _rows())
    back = read_pairs_csv(out / SENSITIVITY_PAIRS)
    pd.testing.assert_frame_equal(back[list(_rows().columns)], _rows(), check_dtype=False)
    written, data = write_sensitivity_report(out)
    names = sorted(p.name for p in written)
    assert names == ["geometry_sensitivity.csv", "geometry_sensitivity.html",
                     "geometry_sensitivity.md"]
    md = (out / "tables" / "geometry_sensitivity.md").read_text(encoding="utf-8")
    assert md.count("- PASS:") == 3 and "FAIL" not in md
    lines = [line for line in md.splitlines() if line.startswith("| ")]
    # ranked by change reproduced, references last
    assert [line.split(" | ")[0][2:] for line in lines[1:]] == [
        "sighted", "blind", "gt (reference)", "same-hands (reference)"]
    # one pair per family: the two one-pair families are resampled together (a stratified
    # resample that kept them apart would always hold both pairs: no spread), so the share
    # reproduced spans the two pairs' 60 and 80 %; the constant columns stay points
    assert lines[1] == ("| sighted | 70.0 [60.0, 80.0] | 1.00 [1.00, 1.00] | 10.00 [10.00, "
                        "10.00] | 12.00 [12.00, 12.00] | 2/2 |")
    summary = pd.read_csv(out / "tables" / "geometry_sensitivity.csv")
    blind = summary[summary["method"] == "blind"].iloc[0]
    assert blind["reproduced"] == 0 and blind["aperture_error"] == pytest.approx(3.0)
    # the HTML table: best method cells bold, the references never, the gate in the notes
    assert [r.label for r in data.rows] == ["sighted", "blind", "gt", "same-hands"]
    assert [r.reference for r in data.rows] == [False, False, True, True]
    assert [c.best for c in data.rows[0].cells] == [True, True, True, True]
    assert not any(c.best for r in data.rows[2:] for c in r.cells)
    assert data.rows[0].cells[0].ci.mean == pytest.approx(70.0)
    assert sum("Sanity gate: PASS" in n for n in data.notes) == 3
    html = (out / "tables" / "geometry_sensitivity.html").read_text(encoding="utf-8")
    assert '<section id="geometry_sensitivity">' in html and "Sanity gate: PASS" in html
    # the same bytes again; without the pairs file the tables of an earlier run go away
    before = {p.name: p.read_bytes() for p in written}
    written, _ = write_sensitivity_report(out)
    assert {p.name: p.read_bytes() for p in written} == before
    (out / SENSITIVITY_PAIRS).unlink()
    assert write_sensitivity_report(out) == ([], None)
    assert not list((out / "tables").glob("geometry_sensitivity.*"))


def test_a_failing_gate_and_an_empty_split_are_reported(tmp_path):
    rows = _rows()
    rows.loc[(rows["method"] == "gt") & (rows["pair"] == "cf2"), "reproduced"] = 0.5
    out = tmp_path / "bad"
    write_pairs_csv(out / SENSITIVITY_PAIRS, rows)
    write_sensitivity_report(out)
    md = (out / "tables" / "geometry_sensitivity.md").read_text(encoding="utf-8")
    assert "- FAIL: gt: change reproduced = 1 on every pair (min 0.500000" in md
    empty = tmp_path / "empty"
    write_pairs_csv(empty / SENSITIVITY_PAIRS, None)
    assert len(read_pairs_csv(empty / SENSITIVITY_PAIRS)) == 0
    written, data = write_sensitivity_report(empty)
    assert data is None and [p.name for p in written] == ["geometry_sensitivity.md"]
    assert "holds no pairs" in written[0].read_text(encoding="utf-8")


def test_write_report_puts_the_table_in_the_leaderboard_page(tmp_path):
    from grip_bench.results.schema import write_results

    out = tmp_path / "out"
    res = pd.DataFrame({"method": ["gt", "gt"], "dataset": ["synthgrab"] * 2,
                        "split": ["test"] * 2, "perturbation": ["none"] * 2,
                        "sequence": ["s1/a_lift_1", "s1/b_lift_1"], "object": ["a", "b"],
                        "hand": ["right"] * 2, "metric": ["mpvpe"] * 2,
                        "value": [1.0, 2.0], "unit": ["mm"] * 2, "n_frames": [10, 10]})
    write_results(res, out / "results.csv")
    write_pairs_csv(out / SENSITIVITY_PAIRS, _rows())
    written = write_report(out)
    assert out / "tables" / "geometry_sensitivity.md" in written
    page = (out / "leaderboard.html").read_text(encoding="utf-8")
    assert page.index("Leaderboard") < page.index('<section id="geometry_sensitivity">')
    assert np.isfinite(read_pairs_csv(out / SENSITIVITY_PAIRS)["reproduced"]).all()


# --- several training seeds ----------------------------------------------------------------------
def _seed_rows(gap: float, spread: float) -> pd.DataFrame:
    """Three seeds of ``grip`` and ``blind`` on four pairs of two families: grip reproduces
    0.5 + seed * spread / 2 of the change on every pair, blind ``gap`` less (and one pair of
    blind's seed 2 NaN: it drops out of that pair's seed mean)."""
    rows = []
    for k, (pair, family) in enumerate((("a", "mug"), ("b", "mug"), ("c", "cube"), ("d", "cube"))):
        for seed in (0, 1, 2):
            for base, shift in (("grip", 0.0), ("blind", gap)):
                method = base if seed == 0 else f"{base}@seed{seed}"
                rep = 0.5 + seed * spread / 2 - shift + 0.01 * k
                if base == "blind" and seed == 2 and pair == "d":
                    rep = np.nan
                rows.append({"method": method, "pair": pair, "family": family,
                             "variant": "smaller", "side": "right", "grasp_kind": "power",
                             "reproduced": rep, "aperture_error": 0.001 * (1 + k),
                             "gt_aperture_change": 0.004, "mpvpe_a": 0.01, "mpvpe_b": 0.01,
                             "mpvpe": 0.01, "n_frames": 30.0})
    return pd.DataFrame(rows)


def test_seed_judgements_match_a_naive_computation():
    from grip_bench.report.sensitivity import seed_judgements

    rows = _seed_rows(gap=0.2, spread=0.04)
    judged = seed_judgements(rows, compare_to="grip", n_boot=200, seed=0)
    rep = judged[judged["score"] == "reproduced"].set_index("method")
    # naive: per-seed means over pairs, in %
    for base in ("grip", "blind"):
        means = []
        for seed in (0, 1, 2):
            m = base if seed == 0 else f"{base}@seed{seed}"
            means.append(100 * np.nanmean(rows.loc[rows["method"] == m, "reproduced"]))
        assert rep.loc[base, "mean"] == pytest.approx(np.mean(means))
        assert rep.loc[base, "seed_min"] == pytest.approx(min(means))
        assert rep.loc[base, "seed_max"] == pytest.approx(max(means))
        assert rep.loc[base, "seeds"] == 3 and rep.loc[base, "seed_labels"] == "0 1 2"
    # the reference row is not judged against itself
    assert rep.loc["grip", "verdict"] == "" and np.isnan(rep.loc["grip", "diff"])
    blind = rep.loc["blind"]
    grip_means = [100 * np.nanmean(rows.loc[rows["method"] == m, "reproduced"])
                  for m in ("grip", "grip@seed1", "grip@seed2")]
    blind_means = [100 * np.nanmean(rows.loc[rows["method"] == m, "reproduced"])
                   for m in ("blind", "blind@seed1", "blind@seed2")]
    assert blind["diff"] == pytest.approx(np.mean(blind_means) - np.mean(grip_means))
    assert blind["spread"] == pytest.approx(max(np.ptp(grip_means), np.ptp(blind_means)))
    # the paired interval is over pairs of seed-averaged scores: every pair is -20 points
    # (pair d: blind's two finite seeds against grip's three, -18 points), so it is narrow
    assert blind["diff_lo"] <= blind["diff"] <= blind["diff_hi"] < 0
    assert blind["verdict"] == "differs"


def test_a_gap_inside_the_seed_spread_is_noise_and_the_section_is_written(tmp_path):
    from grip_bench.report.sensitivity import seed_judgements

    rows = _seed_rows(gap=0.02, spread=0.1)  # 2 points apart, seeds 10 points apart
    judged = seed_judgements(rows, compare_to="grip", n_boot=200, seed=0)
    blind = judged[(judged["method"] == "blind") & (judged["score"] == "reproduced")].iloc[0]
    assert abs(blind["diff"]) < blind["spread"] and blind["verdict"] == "within noise"
    # the section's order does not depend on the order of the pair rows
    shuffled = rows.sample(frac=1.0, random_state=3).reset_index(drop=True)
    again = seed_judgements(shuffled, compare_to="grip", n_boot=200, seed=0)
    assert list(again["method"]) == ["grip", "grip", "blind", "blind"]
    pd.testing.assert_frame_equal(again, judged)
    out = tmp_path / "out"
    write_pairs_csv(out / SENSITIVITY_PAIRS, _seed_rows(gap=0.2, spread=0.04))
    written, data = write_sensitivity_report(out)
    assert "geometry_sensitivity_seeds.csv" in [p.name for p in written]
    md = (out / "tables" / "geometry_sensitivity.md").read_text(encoding="utf-8")
    assert "| blind | 0 1 2 | Change reproduced (%) |" in md and "| differs |" in md
    assert any(n.startswith("Seeds 0 1 2: blind minus grip, change reproduced:")
               and n.endswith("differs.") for n in data.notes)
    # one seed only: no section, no seeds file (an earlier run's is removed)
    write_pairs_csv(out / SENSITIVITY_PAIRS, _rows())
    written, _ = write_sensitivity_report(out)
    assert not (out / "tables" / "geometry_sensitivity_seeds.csv").exists()
    assert "Seeds:" not in (out / "tables" / "geometry_sensitivity.md").read_text(
        encoding="utf-8")
