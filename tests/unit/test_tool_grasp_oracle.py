"""tools/grasp_oracle.py: the summary's counts, and the oracle attached to SynthGRAB's tiny
profile (slow): every one-handed search is tested, the generator is restored afterwards
(docs/physics_hold.md, "Measured in s43")."""

from __future__ import annotations

import pytest

from tools.grasp_oracle import main, summarise


def test_counts_per_kind():
    rows = [{"kind": "power", "picked_held": False, "top_held": 2},
            {"kind": "power", "picked_held": True, "top_held": 0},
            {"kind": "tripod", "picked_held": False, "top_held": 0}]
    s = summarise(rows)
    assert (s["n_searches"], s["picked_held"], s["any_held"]) == (3, 1, 2)
    assert s["per_kind"]["power"] == {"n_searches": 2, "picked_held": 1, "any_held": 2}
    assert s["per_kind"]["tripod"] == {"n_searches": 1, "picked_held": 0, "any_held": 0}
    assert "candidates_qs" not in s  # rows without the quasi-static counts


def test_quasi_static_counts_add_up():
    keys = ("candidates", "candidates_qs", "top", "top_held", "top_qs", "top_qs_held",
            "top_sq", "top_sq_held")
    power, tripod = (10, 9, 8, 2, 7, 2, 3, 1), (3, 3, 3, 1, 3, 1, 1, 1)
    rows = [{"kind": "power", "picked_held": False, **dict(zip(keys, power, strict=True))},
            {"kind": "tripod", "picked_held": True, **dict(zip(keys, tripod, strict=True))}]
    s = summarise(rows)
    assert [s[k] for k in keys] == [13, 12, 11, 3, 10, 3, 4, 2]
    assert s["per_kind"]["tripod"]["candidates_qs"] == 3


@pytest.mark.slow  # ~15 s: the tiny profile generated with a hold test per candidate
def test_every_one_handed_search_is_tested_and_the_generator_restored():
    from grip_bench.data.synth import grasp
    from tools.grasp_oracle import probe

    before = grasp.GraspSynthesizer._pick
    res = probe("tiny", seed=0, top=2)
    assert grasp.GraspSynthesizer._pick is before
    assert res["n_searches"] == len(res["searches"]) > 0
    for r in res["searches"]:
        assert r["kind"] != "bimanual"
        assert r["top"] == min(2, r["candidates"]) > 0  # a search that picked has a valid one
        assert 0 <= r["top_held"] <= r["top"]
        assert r["candidates_qs"] <= r["candidates"]
        assert r["top_qs_held"] <= r["top_qs"] <= r["top"]
        assert r["top_sq_held"] <= min(r["top_sq"], r["top_held"])
        # the tool's copy of _pick's validity and score agrees with the generator's choice
        assert r["picked_valid"] and 0.0 <= r["picked_below_best"] <= 0.3
    assert res["picked_held"] <= res["any_held"] <= res["n_searches"]


def test_an_unknown_profile_is_one_error_line(capsys):
    assert main(["--profile", "nope"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: profile: unknown profile 'nope'") and err.count("\n") == 1
