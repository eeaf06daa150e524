"""``grip-bench bench`` (grip_bench.bench.perf): goal and ratio logic on made-up numbers, the
GEMM FLOP count against torch's own counter, and a quick floors-only run through the CLI
(rates only checked to be positive: timings are for benchmarks, never assertions)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import torch

from grip_bench.bench import perf
from grip_bench.bench.perf import Floor, Goal, Row, Sample, gemm_flops, row_from
from grip_bench.cli.main import main


def test_ratio_is_floor_time_over_stage_time():
    r = Row("s", time=2.0, unit="ms/frame", floor=1.5)
    assert r.ratio == pytest.approx(0.75)
    assert Row("s", time=2.0, unit="ms").ratio is None  # no floor defined


@pytest.mark.parametrize("goal,row,met", [
    (Goal("min_ratio", 0.88, ""), Row("a", 1.0, "ms", floor=0.9), True),
    (Goal("min_ratio", 0.88, ""), Row("a", 1.0, "ms", floor=0.87), False),
    (Goal("max_time", 0.1, ""), Row("a", 0.1, "ms/frame"), True),
    (Goal("max_time", 0.1, ""), Row("a", 0.376, "ms/frame"), False),
    (Goal("min_rate", 300, ""), Row("a", 3.0, "ms/pair", rate=333.3), True),
    (Goal("min_rate", 300, ""), Row("a", 5.0, "ms/pair", rate=200.0), False),
    (Goal("min_ratio", 0.5, ""), Row("a", 1.0, "ms"), None),  # no floor: cannot be judged
])
def test_goal_met(goal, row, met):
    row.goal = goal
    assert row.met is met


class _FakePipe:
    """The four GripPipeline methods _grip_parts times, each sleeping a known time (s)."""

    def arms_and_wrists_many(self):
        time.sleep(0.020)

    def _cnet_inputs(self):
        time.sleep(0.010)

    def _run_cnet(self):
        time.sleep(0.030)

    def refine_many(self):
        self._cnet_inputs()  # a timed part inside another is counted once, in the outer one
        time.sleep(0.005)


def test_grip_parts_split_one_call_and_restore_the_pipeline():
    pipe = _FakePipe()

    def run():
        pipe.arms_and_wrists_many()
        pipe._cnet_inputs()
        pipe._run_cnet()
        pipe.refine_many()
        time.sleep(0.004)  # "other"

    flops = {"anet": 1e9, "cnet": 2e9, "rnet": 5e8}
    parts = perf._grip_parts(pipe, run, 10, flops, 1e11)  # 10 frames, 100 GFLOP/s
    names = [name for name, _, _ in perf._GRIP_PARTS]
    assert list(parts) == [*names, "other (FK of the hands, array work)"]
    sleeps = {names[0]: 2.0, names[1]: 1.0, names[2]: 3.0, names[3]: 1.5}  # ms per frame
    for name, least in sleeps.items():
        assert parts[name][0] >= least  # sleeps last at least this long
    assert parts[names[3]][0] < parts[names[2]][0]  # the nested call stayed in refine_many
    assert parts[names[0]][1] == pytest.approx(10.0)  # 1e9 FLOP / 1e11 FLOP/s / 10, in ms
    assert parts[names[1]][1] is None and parts[names[2]][1] == pytest.approx(20.0)
    assert "arms_and_wrists_many" not in vars(pipe)  # the class's methods again
    row = Row("GRIP offline fp32, 1 x 10 frames", 8.0, "ms/frame", parts=parts)
    table = perf.format_parts([row, Row("sensors", 0.08, "ms/frame")]).splitlines()
    assert table[0] == "| stage | part | time | share | floor | ratio |"
    assert len(table) == 2 + len(parts)  # the row without parts adds nothing
    assert table[2].startswith("| GRIP offline fp32, 1 x 10 frames | ANet recursion")
    assert perf.format_parts([Row("sensors", 0.08, "ms/frame")]) == ""


def test_row_from_per_unit_time_rate_and_spread():
    # 3 repeats of 300 frames taking 0.3, 0.6 and 0.45 s
    r = row_from("x", Sample([0.3, 0.6, 0.45], "s"), 300, "ms/frame", "frames/s",
                 floor=1.0, goal=Goal("min_ratio", 0.88, ">= 88 %"))
    assert r.time == pytest.approx(1.5)  # median 0.45 s / 300 frames, in ms
    assert r.rate == pytest.approx(300 / 0.45)
    assert r.spread == pytest.approx((0.6 - 0.3) / 0.45)
    assert r.ratio == pytest.approx(1.0 / 1.5) and r.met is False
    d = r.as_dict()
    assert d["ratio"] == pytest.approx(2 / 3) and d["met"] is False
    assert d["goal"] == {"kind": "min_ratio", "value": 0.88, "text": ">= 88 %"}


def test_tables_show_dash_where_no_floor_or_goal():
    rows = [Row("gemm stage", 1.0, "ms/frame", floor=0.5, floor_name="f",
                goal=Goal("min_ratio", 0.88, ">= 88 %")),
            Row("physics", 16.0, "ms/test", rate=62.5, rate_unit="tests/s")]
    text = perf.format_rows(rows).splitlines()
    assert text[0] == "| stage | time | floor | ratio | goal | met? |"
    assert "| 50% | >= 88 % | **no** |" in text[2]
    assert text[3].endswith("| — | — | — | — |")
    floors = {"g": Floor("g", "GEMV", Sample([8.0, 10.0, 9.0], "GB/s"), {"how": "mv"})}
    assert "| GEMV | 9 GB/s | 22% | mv |" in perf.format_floors(floors)


def test_best_sgemm_takes_the_fastest_of_a_precision():
    f = lambda k, v: Floor(k, k, Sample([v], "GFLOP/s"))  # noqa: E731
    floors = {k: f(k, v) for k, v in [("sgemm_fp32_1seq", 80.0), ("sgemm_fp32_square", 120.0),
                                      ("sgemm_bf16_1seq", 300.0), ("gemv_fp32", 9.0)]}
    assert perf.best_sgemm(floors, "fp32").key == "sgemm_fp32_square"
    assert perf.best_sgemm(floors, "bf16").key == "sgemm_bf16_1seq"


@pytest.mark.parametrize("m,k,n", [(300, 1024, 2048), (1024, 2048, 1024), (7, 5, 3)])
def test_gemm_flops_match_torch_flop_counter(m, k, n):
    """The count behind every sgemm floor equals torch's independent count of the same addmm."""
    from torch.utils.flop_counter import FlopCounterMode

    x, w, b = torch.randn(m, k), torch.randn(n, k), torch.randn(n)
    with FlopCounterMode(display=False) as counter:
        torch.addmm(b, x, w.T)
    assert gemm_flops(m, k, n) == counter.get_total_flops() == 2 * m * k * n


def test_grip_block_shapes_are_the_paper_widths():
    assert perf.grip_block_shapes() == [(1024, 2048), (2048, 1024)]
    assert perf.grip_batch_rows() == {"1seq": 300, "16seq": 1024}


def test_ping_pong_is_continuous_and_in_range():
    idx = perf.ping_pong(5, 13)
    np.testing.assert_array_equal(idx, [0, 1, 2, 3, 4, 3, 2, 1, 0, 1, 2, 3, 4])
    assert np.abs(np.diff(perf.ping_pong(244, 300))).max() == 1


def test_unknown_part_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as e:
        main(["bench", "--only", "floors,gpu"])
    assert e.value.code == 2
    assert "unknown part(s) gpu" in capsys.readouterr().err


def test_quick_floors_through_the_cli(tmp_path, capsys):
    """``--quick --only floors`` writes bench.json (valid JSON, manifest, CPU info, positive
    floors) and bench.md, and prints the table; progress lines go to stderr."""
    out = tmp_path / "b"
    assert main(["bench", "--quick", "--only", "floors", "--threads", "1", "--out",
                 str(out)]) == 0
    res = json.loads((out / "bench.json").read_text())
    assert res["settings"]["threads"] == 1 and res["settings"]["quick"] is True
    assert res["rows"] == []  # floors only
    expected = {f"sgemm_{p}_{s}" for p in ("fp32", "bf16") for s in ("1seq", "16seq", "square")}
    expected |= {"gemv_fp32", "gemv_fp32_grip", "exact_distance", "manifold_boolean"}
    assert set(res["floors"]) == expected
    for f in res["floors"].values():
        assert f["value"] > 0 and all(v > 0 for v in f["samples"])
    assert res["manifest"]["platform"]["cpu"]["model"] == res["cpu"]["model"]
    assert "revision" in res["manifest"]["git"] and len(res["loadavg_before"]) == 3
    captured = capsys.readouterr()
    assert "| floor | value | spread | measured as |" in captured.out
    assert "[bench] floor sgemm fp32" in captured.err
    assert (out / "bench.md").read_text().startswith("# grip-bench bench")


def test_data_that_is_not_a_dataset_is_one_line(tmp_path, capsys):
    """``--data`` without splits.json: one error line naming the folder, exit 1, nothing run."""
    assert main(["bench", "--only", "physics", "--data", str(tmp_path), "--out",
                 str(tmp_path / "b")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(tmp_path) in err and "splits.json" in err
    assert not (tmp_path / "b").exists()


@pytest.mark.slow  # a scene and eleven simulated holds per tested frame (~40 s)
def test_dataset_hold_row_times_the_tested_frames(tmp_path, monkeypatch):
    """The --data row times an even spread of the split's tested frames (all of them when
    fewer than the quick count), against the issue's goal, and names the data and split."""
    from grip_bench.data.library import ObjectLibrary
    from tests.eval_fixtures import grasp_dataset

    monkeypatch.setattr(perf, "DATA_TESTS_QUICK", 6)  # frames enough to spread, fewer holds
    data = tmp_path / "data"
    grasp_dataset(data, T=40)  # a one-handed mug lift, a two-handed cylinder pass
    n = sum(len(f) for _, f in perf.tested_frames(data, "test", library=ObjectLibrary(data)))
    settings = perf.Settings.make(quick=True, repeats=1, threads=1, data=str(data))
    row, as_run = perf._dataset_hold(settings, "1 core", lambda s: None)
    assert 0 < n and f"({min(n, perf.DATA_TESTS_QUICK)} tested frames, 1 core)" in row.stage
    assert "data test split" in row.stage and row.rate > 0
    assert row.goal is not None and row.goal.value == 20.0
    # the run's ten tests a scene (six directions, two frictions, two grips) share its
    # build: more tests a second, no goal of its own
    assert "as a run computes them (10 a scene)" in as_run.stage and as_run.goal is None
    assert as_run.rate > row.rate
