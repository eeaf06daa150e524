"""Leaderboard: columns, per-sequence averaging, direction, writers, embedded figures."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from grip_bench.core.errors import InputError
from grip_bench.report.leaderboard import (
    LEADERBOARD_COLUMNS,
    leaderboard,
    write_leaderboard_csv,
    write_leaderboard_html,
    write_leaderboard_md,
)
from grip_bench.results import schema as R
from grip_bench.results.schema import ResultRow

from .test_bench_results import synthetic_results


def _rows(spec):
    """[(method, sequence, object, metric, value, unit)] -> validated frame (right hand)."""
    return R.validate(R.to_frame(
        ResultRow(m, "d", "test", "none", s, o, "right", met, v, u, 30)
        for m, s, o, met, v, u in spec))


def test_columns_and_counts():
    lb = leaderboard(synthetic_results(), n_boot=200)
    assert list(lb.columns) == [*LEADERBOARD_COLUMNS, "n_nan"]
    assert len(lb) == 3 * 2 * 2  # methods x metrics x hands
    assert (lb["n_sequences"] == 6).all() and (lb["ci_low"] <= lb["value"]).all()
    assert (lb["value"] <= lb["ci_high"]).all()


def test_mean_over_sequences_not_frames():
    df = _rows([("a", "s1", "o1", "mpvpe", 1.0, "mm"), ("a", "s2", "o2", "mpvpe", 3.0, "mm")])
    df.loc[0, "n_frames"] = 10
    df.loc[1, "n_frames"] = 1000
    assert leaderboard(df, n_boot=100)["value"].iloc[0] == 2.0


def test_direction_and_order():
    df = _rows([("a", "s", "o", "mpvpe", 5.0, "mm"), ("b", "s", "o", "mpvpe", 3.0, "mm"),
                ("a", "s", "o", "contact_ratio", 90.0, "%"),
                ("b", "s", "o", "contact_ratio", 99.0, "%")])
    lb = leaderboard(df, n_boot=50)
    cr = lb[lb["metric"] == "contact_ratio"]
    mp = lb[lb["metric"] == "mpvpe"]
    assert cr["method"].tolist() == ["b", "a"] and cr["higher_is_better"].tolist() == [True] * 2
    assert mp["method"].tolist() == ["b", "a"] and mp["higher_is_better"].tolist() == [False] * 2


def test_nan_counted_and_perturbation_filter():
    df = synthetic_results(methods=("grip",), perturbations=("none", "T0.01"), metrics=("cc",))
    df.loc[(df["perturbation"] == "none") & (df["sequence"] == "s00_mug"), "value"] = np.nan
    lb = leaderboard(df, n_boot=50)
    assert (lb["n_sequences"] == 5).all() and (lb["n_nan"] == 1).all()
    assert (leaderboard(df, n_boot=50, perturbation=None)["n_nan"] == 0).all()


def test_hands_a_method_does_not_predict_are_left_out():
    df = synthetic_results()  # both hands for every method
    methods = sorted(df["method"].unique())
    one = methods[0]
    lb = leaderboard(df, n_boot=20, hands={one: ("right",)})
    mine = lb[lb["method"] == one]
    assert set(mine["hand"]) == {"right"} and len(mine) == 2  # 2 metrics, right hand only
    others = lb[lb["method"] != one]
    assert set(others["hand"]) == {"right", "left"}  # methods not in the map keep both
    assert len(leaderboard(df, n_boot=20)) == len(lb) + 2


def test_registered_single_hand_models():
    from grip_bench.methods.api import predicted_hands

    hands = predicted_hands()
    assert hands["grabnet"] == ("right",) and hands["manipnet"] == ("right",)
    assert hands["grip"] == ("right", "left") and hands["grabnet-smplx"] == ("right", "left")


def test_unit_mismatch_with_registry_is_an_error():
    df = _rows([("a", "s", "o", "mpvpe", 0.005, "m")])
    with pytest.raises(InputError, match="registered in 'mm'"):
        leaderboard(df, n_boot=10)


def test_unknown_metric_has_no_direction(tmp_path):
    df = _rows([("a", "s", "o", "my_metric", 1.0, "px")])
    lb = leaderboard(df, n_boot=10)
    assert lb["higher_is_better"].iloc[0] is None
    text = write_leaderboard_csv(lb, tmp_path / "lb.csv").read_text()
    assert text.splitlines()[1] == "a,my_metric,right,1.0,1.0,1.0,px,,1"


def test_seeded():
    df = synthetic_results()
    pd.testing.assert_frame_equal(leaderboard(df, seed=1, n_boot=100),
                                  leaderboard(df, seed=1, n_boot=100))
    assert not leaderboard(df, seed=1, n_boot=100).equals(leaderboard(df, seed=2, n_boot=100))


def _png(path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1, 1), dpi=20)
    ax.plot([0, 1], [0, 1])
    fig.savefig(path)
    plt.close(fig)
    return path


def test_writers(tmp_path):
    lb = leaderboard(synthetic_results(), n_boot=100)
    csv_text = write_leaderboard_csv(lb, tmp_path / "leaderboard.csv").read_text()
    assert csv_text.splitlines()[0] == ",".join(LEADERBOARD_COLUMNS)
    back = pd.read_csv(tmp_path / "leaderboard.csv")
    assert back["value"].tolist() == lb["value"].tolist()  # round-trip floats
    md = write_leaderboard_md(lb, tmp_path / "leaderboard.md").read_text()
    assert "| Method | MPVPE R-Hand (mm) ↓" in md and "**" in md
    fig = _png(tmp_path / "penetration_cdf.png")
    page = write_leaderboard_html(lb, tmp_path / "leaderboard.html", figures=[fig]).read_text()
    assert '<table class="sortable">' in page and "<script>" in page
    assert "data:image/png;base64," in page and "penetration cdf" in page
    assert "http://" not in page and "https://" not in page and "src=\"http" not in page
    # gt is a reference row: never bold even where it is lowest
    assert '<tr class="reference"><th scope="row">gt</th>' in page


def test_html_rejects_non_png(tmp_path):
    bad = tmp_path / "fig.png"
    bad.write_text("not an image")
    lb = leaderboard(synthetic_results(), n_boot=10)
    with pytest.raises(InputError, match="not a PNG"):
        write_leaderboard_html(lb, tmp_path / "x.html", figures=[bad])
    with pytest.raises(InputError, match="cannot read figure"):
        write_leaderboard_html(lb, tmp_path / "x.html", figures=[tmp_path / "missing.png"])
