"""Which metrics each test set is evaluated on (``bench.plan.set_metrics``): the clean set
gets every leaderboard metric and the table-only ones where a table reads them, a perturbed
set only what a chosen table reads there for that method."""

from __future__ import annotations

from grip_bench.bench.plan import make_config, set_metrics
from grip_bench.metrics.registry import METRICS

PHYSICS = {"hold_qs", "hold_qs_mu05", "hold_qs_mu3", "hold_qs_axes", "sim_stable", "sim_disp",
           "hold_sim", "hold_sim_disp", "hold_sim_settle", "hold_sim_ruled", "hold_sim_mu05",
           "hold_sim_mu3", "hold_sim_weak", "hold_sim_strong", "hold_sim_axes"}


def test_perturbed_sets_get_only_what_a_table_reads_for_that_method(tmp_path):
    cfg = make_config("default", out=tmp_path / "out")
    assert set_metrics(cfg, "none", "grip") == sorted(METRICS.names())  # a physics table row
    # not in the physics table: the table-only metrics (the articulated hold test among them)
    # are not computed, every leaderboard metric is
    toch = set(set_metrics(cfg, "none", "toch"))
    assert toch == {m for m in METRICS.names() if METRICS.get(m).leaderboard}
    assert "hold_sim" not in toch and "hold_qs" in toch
    # Table 3 reads MPVPE and MPJPE of the refiners and (its "before") of the input
    for method in ("grip", "toch"):
        for label in ("T0.01", "T0.02", "R0.3", "R0.5"):
            assert set_metrics(cfg, label, method) == ["mpjpe", "mpvpe"], (method, label)
    # the physics table's GRAB-T 0.01 control row reads its columns of the input alone
    assert set(set_metrics(cfg, "T0.01", "perturbed-input")) == PHYSICS | {"mpjpe", "mpvpe"}
    assert set_metrics(cfg, "T0.02", "perturbed-input") == ["mpjpe", "mpvpe"]
    # an ablation variant: only its tables' metrics, on the clean set
    variant = set(set_metrics(cfg, "none", "grip-no-rnet"))
    assert PHYSICS <= variant and "jitter" not in variant


def test_metrics_a_profile_names_go_to_every_method(tmp_path):
    cfg = make_config("default", out=tmp_path / "out")
    cfg.settings["metrics"] = ["hold_sim", "mpvpe"]
    assert set_metrics(cfg, "none", "toch") == ["hold_sim", "mpvpe"]
    assert set_metrics(cfg, "T0.02", "perturbed-input") == ["mpvpe"]
