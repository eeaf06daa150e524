"""The perceptual study (grip_bench/report/study.py): pair planning (deterministic, balanced,
catch trials), broken sequences, the key files, and scoring against answers with a known
preference (percentages, intervals, a participant dropped for failing catch trials)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from grip_bench.core.errors import InputError
from grip_bench.report import study as S

SEQS = [f"s{k}/obj{j}_lift_1" for k in (1, 2) for j in range(3)]


def test_plan_is_deterministic_and_counts_are_right():
    a = S.plan_pairs(SEQS, ["GRIP", "TOCH"], 20, 4, seed=7)
    b = S.plan_pairs(list(reversed(SEQS)), ["GRIP", "TOCH"], 20, 4, seed=7)
    c = S.plan_pairs(SEQS, ["GRIP", "TOCH"], 20, 4, seed=8)
    assert a == b and a != c
    assert len(a) == 24 and sum(p.is_catch for p in a) == 4
    assert [p.pair_id for p in a] == [f"p{i:03d}" for i in range(1, 25)]
    # 3 conditions, 20 pairs: 7, 7, 6
    conds = [frozenset((p.left, p.right)) for p in a if not p.is_catch]
    assert sorted(conds.count(c) for c in set(conds)) == [6, 7, 7]
    assert set(conds) == {frozenset(c) for c in (("GRIP", S.GT), ("TOCH", S.GT),
                                                 ("GRIP", "TOCH"))}
    assert {p.sequence for p in a} <= set(SEQS)


def test_sides_are_balanced():
    pairs = S.plan_pairs(SEQS, ["GRIP", "TOCH"], 30, 6, seed=1)
    for cond in ({"GRIP", S.GT}, {"TOCH", S.GT}, {"GRIP", "TOCH"}):
        sub = [p for p in pairs if {p.left, p.right} == cond]
        a = sorted(cond)[0]
        left = sum(p.left == a for p in sub)
        assert abs(left - (len(sub) - left)) <= 1
    catch = [p for p in pairs if p.is_catch]
    assert sum(p.expected == "left" for p in catch) == 3
    for p in catch:
        assert getattr(p, p.expected) == S.GT
        broken = p.right if p.expected == "left" else p.left
        assert broken in {S.CATCH_PREFIX + k for k in S.CATCH_KINDS}
    assert {p.right if p.expected == "left" else p.left for p in catch} == {
        S.CATCH_PREFIX + k for k in S.CATCH_KINDS}


def test_each_condition_cycles_through_the_sequences():
    pairs = S.plan_pairs(SEQS, ["GRIP"], 12, 0, seed=3)
    counts = pd.Series([p.sequence for p in pairs]).value_counts()
    assert (counts == 2).all() and len(counts) == len(SEQS)


def test_plan_rejects_bad_input():
    with pytest.raises(InputError, match="no sequences"):
        S.plan_pairs([], ["GRIP"], 4, 0, 0)
    with pytest.raises(InputError, match="--pairs >= 0"):
        S.plan_pairs(SEQS, ["GRIP"], -1, 0, 0)


@pytest.fixture(scope="module")
def study_dirs(tmp_path_factory):
    from tests.grab_fixtures import write_dataset

    root = tmp_path_factory.mktemp("study")
    specs = [("s1", "mug", "lift"), ("s1", "cup", "pass"), ("s2", "mug", "pass")]
    dirs = {}
    for name in ("gt", "A", "B"):
        write_dataset(root / name, specs, T=6)
        dirs[name] = root / name
    (dirs["B"] / "grab" / "s2" / "mug_pass_1.npz").unlink()  # B lacks one sequence
    return dirs


def test_broken_sequences(study_dirs):
    from grip_bench.data.grab_io import read_grab

    seq = read_grab(study_dirs["gt"] / "grab" / "s1" / "mug_lift_1.npz")
    up = np.array([0.0, 1.0, 0.0])
    d = S.broken_sequence(seq, "displaced", up)
    for side in ("right", "left"):
        shift = d.hand_params(side)["transl"] - seq.hand_params(side)["transl"]
        assert np.allclose(shift, S.CATCH_OFFSET * up, atol=1e-6)
    f = S.broken_sequence(seq, "frozen", up)
    for key in ("global_orient", "hand_pose", "transl"):
        a = f.hand_params("right")[key]
        assert (a == a[0]).all() and np.array_equal(a[0], seq.hand_params("right")[key][0])
    assert np.array_equal(f.object["transl"], seq.object["transl"])
    with pytest.raises(InputError, match="unknown catch kind"):
        S.broken_sequence(seq, "melted", up)


def test_make_study_writes_a_deterministic_key(study_dirs, tmp_path):
    preds = {"A": study_dirs["A"], "B": study_dirs["B"]}
    for out in (tmp_path / "one", tmp_path / "two"):
        pairs = S.make_study(study_dirs["gt"], preds, out, 9, seed=5, n_catch=2, render=False)
    one, two = ((tmp_path / d / "key.csv").read_bytes() for d in ("one", "two"))
    assert one == two
    key = pd.read_csv(tmp_path / "one" / "key.csv", keep_default_na=False)
    assert list(key.columns) == list(S.KEY_COLUMNS) and len(key) == 11 == len(pairs)
    assert key["is_catch"].sum() == 2
    assert set(key["sequence"]) <= {"s1/mug_lift_1", "s1/cup_pass_1"}  # those all folders share
    assert (key["video"] == "").all()
    template = pd.read_csv(tmp_path / "one" / "answers_template.csv", keep_default_na=False)
    assert list(template.columns) == list(S.ANSWER_COLUMNS)
    assert list(template["pair_id"]) == list(key["pair_id"])
    assert (template["participant"] == "").all() and (template["choice"] == "").all()
    with pytest.raises(InputError, match="reserved"):
        S.make_study(study_dirs["gt"], {S.GT: study_dirs["A"]}, tmp_path / "x", 2, 0,
                     render=False)


def _key() -> pd.DataFrame:
    rows = [("p1", "GRIP", S.GT, 0, ""), ("p2", S.GT, "GRIP", 0, ""),
            ("p3", "GRIP", "TOCH", 0, ""), ("p4", "TOCH", "GRIP", 0, ""),
            ("p5", S.GT, "catch:frozen", 1, "left"), ("p6", "catch:displaced", S.GT, 1, "right")]
    key = pd.DataFrame(rows, columns=["pair_id", "left", "right", "is_catch", "expected"])
    key["sequence"], key["video"] = "s1/mug_lift_1", ""
    key["is_catch"] = key["is_catch"].astype(bool)
    return key


def _answers() -> pd.DataFrame:
    """P1..P4 pass the catch trials; P5 fails one. Choices, by pair:
    GRIP vs GT: P1 GRIP, GRIP; P2 GRIP, GT; P3 GT, GT; P4 GRIP, GRIP -> 5 of 8 GRIP.
    GRIP vs TOCH: every kept participant picks GRIP both times -> 8 of 8. P5 picks the other
    side everywhere, so keeping P5 would change both rows."""
    choice = {"P1": "left right left right", "P2": "left left left right",
              "P3": "right left left right", "P4": "left right left right",
              "P5": "right left right left"}
    catch = {"P1": "left right", "P2": "left right", "P3": "left right", "P4": "left right",
             "P5": "right right"}
    rows = []
    for p in choice:
        for pid, c in zip(("p1", "p2", "p3", "p4", "p5", "p6"),
                          choice[p].split() + catch[p].split(), strict=True):
            rows.append((p, pid, c))
    return pd.DataFrame(rows, columns=list(S.ANSWER_COLUMNS))


def test_aggregate_known_preference_drops_the_catch_failure():
    res = S.aggregate(_key(), _answers(), min_catch=1.0, seed=0, n_boot=500)
    assert res.dropped == ["P5"] and res.kept == ["P1", "P2", "P3", "P4"]
    t = res.table.set_index(["method_a", "method_b"])
    # GRIP is not the focus: rows vs the ground truth put it last, others sort alphabetically
    assert list(t.index) == [("GRIP", S.GT), ("GRIP", "TOCH")]
    gt = t.loc[("GRIP", S.GT)]
    assert gt["prefer_a_pct"] == pytest.approx(62.5) and gt["prefer_b_pct"] == pytest.approx(37.5)
    assert gt["n_answers"] == 8 and gt["n_participants"] == 4
    assert gt["prefer_a_lo"] <= 62.5 <= gt["prefer_a_hi"]
    assert gt["prefer_b_lo"] == pytest.approx(100 - gt["prefer_a_hi"])
    # per-participant shares 1, .5, 0, 1: the bootstrap interval is wide but inside [0, 100]
    assert 0 <= gt["prefer_a_lo"] < 40 and 85 < gt["prefer_a_hi"] <= 100
    toch = t.loc[("GRIP", "TOCH")]
    assert toch["prefer_a_pct"] == 100 and toch["prefer_a_lo"] == 100  # every resample: 100%
    # keeping everyone (threshold 0.5: P5 got half right) changes the numbers
    all_in = S.aggregate(_key(), _answers(), min_catch=0.5, n_boot=500)
    assert all_in.dropped == []
    row = all_in.table.set_index(["method_a", "method_b"]).loc[("GRIP", S.GT)]
    assert row["prefer_a_pct"] == pytest.approx(50.0) and row["n_participants"] == 5


def test_aggregate_is_seeded_and_focus_orients_rows():
    a = S.aggregate(_key(), _answers(), seed=3, n_boot=300).table
    b = S.aggregate(_key(), _answers(), seed=3, n_boot=300).table
    pd.testing.assert_frame_equal(a, b)
    f = S.aggregate(_key(), _answers(), n_boot=300, focus="TOCH").table
    assert (f["method_a"].iloc[0], f["method_b"].iloc[0]) == ("TOCH", "GRIP")
    assert f["prefer_a_pct"].iloc[0] == 0.0


def test_wilson_interval():
    lo, hi = S.wilson(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-4) and hi == pytest.approx(0.9433, abs=1e-4)
    assert S.wilson(0, 5)[0] == 0.0 and np.isnan(S.wilson(0, 0)[0])
    res = S.aggregate(_key(), _answers(), ci="wilson")
    row = res.table.set_index(["method_a", "method_b"]).loc[("GRIP", S.GT)]
    lo, hi = S.wilson(5, 8)
    assert row["prefer_a_lo"] == pytest.approx(100 * lo) and row["prefer_a_hi"] == pytest.approx(
        100 * hi)


def test_markdown_and_csv(tmp_path):
    res = S.aggregate(_key(), _answers(), n_boot=200)
    md, csv = S.write_result(res, tmp_path / "table.md")
    text = md.read_text()
    assert "| GRIP vs ground_truth | 62.5 [" in text and "dropped" in text and "P5" in text
    back = pd.read_csv(csv)
    assert list(back.columns) == list(S.TABLE_COLUMNS) and len(back) == 2


def test_answer_file_checks(tmp_path):
    key_path = tmp_path / "key.csv"
    S.key_frame([S.Pair("p1", "s1/a", "GRIP", S.GT, False),
                 S.Pair("p2", "s1/a", S.GT, "catch:frozen", True, "left")]).to_csv(
        key_path, index=False)
    key = S.read_key(key_path)
    assert key["is_catch"].tolist() == [False, True]

    def answers(text):
        p = tmp_path / "answers.csv"
        p.write_text("participant,pair_id,choice\n" + text)
        return p

    ok = S.read_answers(answers("P1,p1,Left\nP1,p2,\n"), key)
    assert len(ok) == 1 and ok["choice"].iloc[0] == "left"  # blank skipped, case folded
    for text, msg in (("P1,p1,up\n", "left or right"), ("P1,p9,left\n", "not in the key"),
                      ("P1,p1,left\nP1,p1,right\n", "twice"), (",p1,left\n", "no participant")):
        with pytest.raises(InputError, match=msg):
            S.read_answers(answers(text), key)
    (tmp_path / "bad.csv").write_text("participant,pair\nP1,p1\n")
    with pytest.raises(InputError, match="missing column"):
        S.read_answers(tmp_path / "bad.csv", key)
