"""``grip-bench validity`` end to end on smoke-sized data, and ``report`` picking it up."""

from __future__ import annotations

import shutil

import pandas as pd
import pytest

from grip_bench.cli.main import main
from tests.eval_fixtures import grasp_dataset


@pytest.mark.slow  # 34 s; its claims on this data: tests/unit/test_metric_validity.py
def test_validity_command_writes_table_and_figure_and_report_keeps_them(tmp_path, capsys):
    data = tmp_path / "data"
    grasp_dataset(data, T=40)
    out = tmp_path / "val"
    code = main(["validity", "--data", str(data), "--out", str(out), "--sequences", "2",
                 "--max-iv-frames", "2"])
    text = capsys.readouterr().out
    # the one claim this data breaks, as tests/unit/test_metric_validity.py's
    # test_every_claim_holds_on_smoke_data measures it (fingers closed through the mug's
    # wall); a broken claim makes the command exit 1 and print it
    assert code == 1, text
    assert "1 broken claim(s)" in text and "  pen_depth under close: not up" in text
    df = pd.read_csv(out / "validity.csv")
    assert {"degradation", "level", "metric", "value", "expected"} <= set(df.columns)
    md = (out / "tables" / "metric_validity.md").read_text()
    assert "PASS" in md and md.count("| FAIL |") == 1 and "Broken claims: 1: pen_depth" in md
    assert "Physics metrics not measured" in md  # its options, from validity.json
    assert (out / "validity.json").is_file()
    png = (out / "figures" / "metric_validity.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    # write_report renders the validity files from OUT alone, byte for byte
    from grip_bench.report.validity import write_validity

    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    shutil.rmtree(copy / "tables")
    write_validity(copy)
    assert (copy / "tables" / "metric_validity.md").read_text() == md
    assert (copy / "figures" / "metric_validity.png").read_bytes() == png
