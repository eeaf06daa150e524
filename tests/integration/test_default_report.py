"""The physics table's sanity gates, asserted on the default data (issue #15 asks for it):
the committed report `reports/default` is recomputed from its own results.csv, the gates
printed under its physics table must be what those results say, and the gates that the
suite meets must pass. The articulated test's ground-truth gate is not met on SynthGRAB
2.5 (40.9 %; 37.6 % on 2.4 since s49's wedge rule, 40.8 % before; 31.1 % on 2.3,
docs/physics_hold.md): it is a strict xfail, so the day it passes this file says so."""

from __future__ import annotations

from pathlib import Path

import pytest

from grip_bench.report.tables import TABLES, compute_table, gate_line
from grip_bench.results.schema import read_results

REPORT = Path(__file__).resolve().parents[2] / "reports" / "default"


@pytest.fixture(scope="module")
def gates() -> dict[tuple[str, str], tuple[str, bool | None, str]]:
    """(metric, row) -> (check, passed, measured) of every physics gate on the report."""
    spec = TABLES.get("physics")
    data = compute_table(spec, read_results(REPORT / "results.csv"), n_boot=20)
    return {(g.metric, g.row): got for g, got in zip(spec.gates, data.gates, strict=True)}


def test_the_printed_gates_are_what_the_results_say(gates):
    printed = (REPORT / "tables" / "physics.md").read_text()
    for check in gates.values():
        assert f"- Sanity gate {gate_line(*check)}\n" in printed


@pytest.mark.parametrize("metric, row", [
    ("hold_qs", "Ground truth"), ("hold_qs", "Flat hand (control)"),
    ("hold_qs", "GRAB-T 0.01 input (control)"),
    ("hold_sim", "Flat hand (control)"), ("hold_sim", "GRAB-T 0.01 input (control)"),
])
def test_the_gates_the_suite_meets_pass(gates, metric, row):
    check, passed, measured = gates[(metric, row)]
    assert passed is True, f"{check}: {measured}"


@pytest.mark.xfail(strict=True, reason="issue #15: SynthGRAB 2.5's grasps hold 40.9 % of "
                   "the tested frames in the articulated test (docs/physics_hold.md)")
def test_ground_truth_passes_the_articulated_hold_gate(gates):
    check, passed, measured = gates[("hold_sim", "Ground truth")]
    assert passed is True, f"{check}: {measured}"


def test_ground_truth_ranks_best_on_the_articulated_hold_displacement():
    """``hold_sim_disp`` v2 (s50) counts a frame the depth, settle or wedge rule fails at the
    10 cm cap. On v1 a sunk or wedged hand barely moved the object: CNet's 39 mm beat ground
    truth's 57 mm in the physics table, and fingers closed 0.1 rad into the object lowered
    ground truth's 64 mm to 10 mm in the validity report. On the committed report ground
    truth's per-sequence medians are the lowest of the table's rows, and no degradation of
    ground truth at any level scores below the undegraded value by more than the validity
    report's tie tolerance but one: 1 mm of temporal jitter (SynthGRAB 2.5: 67.4 against
    72.1 mm; two grasps that fall as ground truth, a wine glass's friction-limited grasp
    and a medium cube's, hold some jittered frames; docs/physics_hold.md, "Landed in
    s60"). On 2.4 that level was a tie (s53: 76.681 against 76.682 mm)."""
    import pandas as pd

    from grip_bench.metrics import validity as V

    phys = pd.read_csv(REPORT / "tables" / "physics.csv")
    disp = phys[phys.metric == "hold_sim_disp"].set_index("row").value
    assert disp["Ground truth"] == disp.min() and (disp.drop("Ground truth") > disp.min()).all()
    val = pd.read_csv(REPORT / "validity.csv")
    val = val[val.metric == "hold_sim_disp"]
    clean = val[val.level == 0].value
    assert clean.nunique() == 1  # every degradation's level 0 is ground truth itself
    tie = V.tolerance("mm", clean.iloc[0])
    below = val[(val.level > 0) & (val.value < clean.iloc[0] - tie)]
    assert list(zip(below.degradation, below.level, strict=True)) == [("jitter", 1.0)]


def test_the_validity_report_judges_the_articulated_test():
    """Since s51 the validity report holds ``hold_sim`` and ``hold_sim_disp`` to the
    quasi-static check's claims; since s57 on the same 8 frames a hand (one frame of one
    sequence under the 1-point tolerance). On the committed report the responses carry
    those claims and the broken ones are the known ones (docs/contract.md, "Metric
    validity"; docs/physics_hold.md, "Landed in s57"): the strict contact ratio under
    closing by 0.4 rad (a banana's index and middle fingers through its thin end), and
    ``hold_sim`` and ``hold_sim_disp`` under 1 mm of wrist jitter, which holds more frames
    than the ground truth and moves them less (SynthGRAB 2.5: a wine glass's
    friction-limited grasp and two medium cubes', which fall as ground truth, hold 25-75 %
    of their frames jittered, in three jitter draws; on 2.4 the cubes alone, and the
    displacement's claim held), so ground truth is not those metrics' best row there. No
    other degraded level scores above the ground truth."""
    import pandas as pd

    from grip_bench.metrics import validity as V

    val = pd.read_csv(REPORT / "validity.csv")
    val["expected"] = val["expected"].fillna("")
    for m in ("hold_sim", "hold_sim_disp"):
        judged = set(val[(val.metric == m) & (val.expected != "")].degradation)
        assert judged == {d for d, mm in V.EXPECTED if mm == m}
    assert (val["expected"] == [V.claim(d, m) for d, m in
                                zip(val.degradation, val.metric, strict=True)]).all()
    broken = V.check_validity(val)
    assert sorted(b.split(":")[0] for b in broken) == [
        "contact_ratio_strict under close", "hold_sim", "hold_sim under jitter",
        "hold_sim_disp", "hold_sim_disp under jitter"], broken
    held = val[val.metric == "hold_sim"]
    above = held[(held.level > 0) & (held.value > held[held.level == 0].value.iloc[0])]
    assert list(zip(above.degradation, above.level, strict=True)) == [("jitter", 1.0)]
