"""Stratified bootstrap: exact cases, stratification, NaN handling, determinism, coverage."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from grip_bench.core.errors import InputError
from grip_bench.results import stats
from grip_bench.results.stats import bootstrap_ci, bootstrap_means, per_sequence, sequence_ci


def test_constant_sample_has_zero_width_interval():
    ci = bootstrap_ci([0.1] * 7, ["a", "b"] * 3 + ["a"])
    assert ci.mean == ci.lo == ci.hi == 0.1 and ci.n == 7 and ci.n_nan == 0


def test_nan_excluded_and_counted():
    ci = bootstrap_ci([1.0, np.nan, 3.0, np.nan], ["a", "a", "b", "b"])
    assert ci.mean == 2.0 and ci.n == 2 and ci.n_nan == 2
    empty = bootstrap_ci([np.nan, np.nan])
    assert np.isnan(empty.mean) and np.isnan(empty.lo) and empty.n == 0 and empty.n_nan == 2


def test_deterministic_by_seed_and_order_free():
    rng = np.random.default_rng(0)
    v, s = rng.normal(size=40), np.repeat(list("abcd"), 10)
    assert bootstrap_ci(v, s, seed=3) == bootstrap_ci(v, s, seed=3)
    assert bootstrap_ci(v, s, seed=3) != bootstrap_ci(v, s, seed=4)
    perm = rng.permutation(40)
    assert bootstrap_ci(v[perm], s[perm], seed=3) == bootstrap_ci(v, s, seed=3)


def test_stratification_keeps_stratum_sizes():
    # stratum a: 3 zeros, stratum b: 7 ones -> every resample has exactly 3 a's and 7 b's
    v = [0.0] * 3 + [1.0] * 7
    s = ["a"] * 3 + ["b"] * 7
    means = bootstrap_means(v, s, n_boot=500, seed=1)
    assert np.allclose(means, 0.7)
    # unstratified resampling of the same values does vary
    assert np.ptp(bootstrap_means(v, None, n_boot=500, seed=1)) > 0.2
    # stratum b (constant 10, two sequences) always contributes exactly 2 draws
    means = bootstrap_means([0.0, 1.0, 10.0, 10.0], ["a", "a", "b", "b"], n_boot=300, seed=2)
    k = np.round(means * 4 - 20, 9)
    assert set(np.unique(k)) == {0.0, 1.0, 2.0}


def test_chunking_does_not_change_draws(monkeypatch):
    rng = np.random.default_rng(5)
    v, s = rng.normal(size=33), rng.integers(0, 4, size=33)
    full = bootstrap_means(v, s, n_boot=257, seed=9)
    monkeypatch.setattr(stats, "BOOTSTRAP_CHUNK", 100)  # 3 resamples per chunk
    assert np.array_equal(full, bootstrap_means(v, s, n_boot=257, seed=9))


def test_bad_inputs():
    with pytest.raises(InputError, match="strata"):
        bootstrap_ci([1.0, 2.0], ["a"])
    with pytest.raises(InputError, match="infinite"):
        bootstrap_ci([1.0, np.inf])
    with pytest.raises(InputError, match="alpha"):
        bootstrap_ci([1.0, 2.0], alpha=1.5)


def _coverage(reps: int, n_per: int, n_boot: int) -> float:
    """Share of intervals containing the true stratified mean (3 strata, different means)."""
    rng = np.random.default_rng(123)
    centres = np.array([0.0, 2.0, 5.0])
    strata = np.repeat(np.arange(3), n_per)
    truth = centres.mean()
    hits = 0
    for r in range(reps):
        v = centres[strata] + rng.normal(size=strata.size)
        ci = bootstrap_ci(v, strata, n_boot=n_boot, seed=r)
        hits += ci.lo <= truth <= ci.hi
    return hits / reps


def test_coverage_roughly_95_percent():
    # percentile intervals under-cover a little at n = 30 (about 92-94%)
    assert 0.88 <= _coverage(reps=300, n_per=10, n_boot=1000) <= 0.99


@pytest.mark.slow
def test_coverage_close_to_95_percent_large_n():
    assert 0.92 <= _coverage(reps=1000, n_per=40, n_boot=2000) <= 0.975


def test_per_sequence_averages_rows_and_keeps_all_nan():
    df = pd.DataFrame({"dataset": "d", "split": "test", "object": ["o", "o", "o", "o"],
                       "sequence": ["a", "a", "b", "b"], "value": [1.0, 3.0, np.nan, np.nan]})
    seq = per_sequence(df)
    assert seq["value"].iloc[0] == 2.0 and np.isnan(seq["value"].iloc[1])
    ci = sequence_ci(df)
    assert ci.mean == 2.0 and ci.n == 1 and ci.n_nan == 1


def _rows(values, frames, objects, seqs):
    return pd.DataFrame({"dataset": "d", "split": "test", "sequence": seqs, "object": objects,
                         "value": values, "n_frames": frames, "hand": "right"})


def test_pooled_averaging_weights_sequences_by_frames_hand_computed():
    # two sequences: 10 frames at 1.0 and 30 frames at 3.0 (one of its hands NaN, 0 frames)
    rows = _rows([1.0, 3.0, np.nan], [10, 30, 0], ["a", "b", "b"], ["s1", "s2", "s2"])
    seq = sequence_ci(rows, n_boot=200, seed=0)
    pooled = sequence_ci(rows, n_boot=200, seed=0, averaging="pooled")
    assert seq.mean == pytest.approx(2.0)  # (1 + 3) / 2
    assert pooled.mean == pytest.approx((10 * 1.0 + 30 * 3.0) / 40)  # 2.5
    assert pooled.n == 2 and pooled.lo <= pooled.mean <= pooled.hi


def test_weighted_bootstrap_matches_a_loop_and_equal_weights_match_the_plain_one():
    from grip_bench.results.stats import weighted_bootstrap_ci

    rng = np.random.default_rng(1)
    v, w = rng.normal(size=12), rng.integers(1, 20, size=12).astype(float)
    ci = weighted_bootstrap_ci(v, w, None, n_boot=400, seed=3)
    assert ci.mean == pytest.approx((v * w).sum() / w.sum())
    plain = bootstrap_ci(v, None, n_boot=400, seed=3)
    equal = weighted_bootstrap_ci(v, np.ones(12), None, n_boot=400, seed=3)
    assert equal.mean == pytest.approx(plain.mean) and equal.lo < equal.mean < equal.hi
    # a naive loop of the same resampling gives an interval of the same width (within noise)
    boots = []
    for _ in range(400):
        i = rng.integers(0, 12, size=12)
        boots.append((v[i] * w[i]).sum() / w[i].sum())
    lo, hi = np.quantile(boots, [0.025, 0.975])
    assert abs((ci.hi - ci.lo) - (hi - lo)) < 0.35 * (hi - lo)


def test_unknown_averaging_is_an_input_error():
    with pytest.raises(InputError, match="unknown averaging"):
        sequence_ci(_rows([1.0], [3], ["a"], ["s"]), averaging="median")


def test_one_sequence_strata_are_resampled_together():
    # one sequence per object: a stratified bootstrap that kept them apart would give a
    # zero-width interval; collapsed, it is the plain bootstrap of the same values
    rng = np.random.default_rng(2)
    v = rng.normal(size=8)
    objects = [f"o{k}" for k in range(8)]
    ci = bootstrap_ci(v, objects, seed=4)
    assert ci == bootstrap_ci(v, None, seed=4) and ci.hi - ci.lo > 0.5
    # objects a (3 x 0.0) kept; b (10) and c (20) resampled together: every resample has
    # three a's and two of {b, c}, so the means are (0 + {20, 30, 40}) / 5 exactly
    means = bootstrap_means([0.0, 0.0, 0.0, 10.0, 20.0], list("aaabc"), n_boot=400, seed=1)
    assert set(np.round(means, 9)) == {4.0, 6.0, 8.0}
    # a lone one-sequence object joins the smallest other stratum: c (6) with a (0, 0),
    # b (1, 1, 1) apart -> (3 + 6 k) / 6 for k = 0..3 draws of c
    means = bootstrap_means([0.0, 0.0, 1.0, 1.0, 1.0, 6.0], list("aabbbc"), n_boot=600, seed=1)
    assert set(np.round(means, 9)) == {0.5, 1.5, 2.5, 3.5}


def test_stratum_codes_follow_the_labels_not_the_row_order():
    from grip_bench.results.stats import stratum_codes

    assert stratum_codes(list("aabbbc")).tolist() == [0, 0, 1, 1, 1, 0]
    assert stratum_codes(list("cbbbaa")).tolist() == [0, 1, 1, 1, 0, 0]
    assert stratum_codes(list("abcc")).tolist() == [0, 0, 1, 1]
    assert stratum_codes(list("abc")).tolist() == [0, 0, 0]
    assert stratum_codes([]).size == 0
