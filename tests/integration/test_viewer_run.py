"""``grip-bench run`` writes viewer pages (``[run] viewer_sequences``) into ``OUT/viewer/``
with an ``index.json``; the HTML report links each method to them, ``grip-bench report``
re-renders the same bytes, and ``viewer_sequences = 0`` removes them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from grip_bench.cli.main import main
from tests.run_fixtures import tiny_run_profile

VIEWER_RUN = {"methods": ["gt", "mean-pose"], "metrics": ["mpjpe", "mpvpe", "contact_ratio"],
              "per_frame": True, "bootstrap_n": 50, "runtime_sequences": 0, "physics_frames": 0}


def _profile(path, n: int):
    return tiny_run_profile(path, **VIEWER_RUN, viewer_sequences=n)


@pytest.fixture(scope="module")
def run_out(tmp_path_factory):
    root = tmp_path_factory.mktemp("viewer_run")
    for n in (2, 0):
        _profile(root / f"p{n}.toml", n)
    out = root / "out"
    assert main(["run", "--profile", str(root / "p2.toml"), "--out", str(out), "--workers", "1",
                 "--quiet"]) == 0
    return root, out


def _html(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes()
            for p in sorted(out.rglob("*.html")) if "cache" not in p.parts}


def test_run_writes_pages_and_index(run_out):
    _, out = run_out
    index = json.loads((out / "viewer" / "index.json").read_text())
    pages = index["pages"]
    # gt is on every page, so only mean-pose gets pages; the tiny test split has one
    # sequence, which is both the worst and the median
    assert [p["method"] for p in pages] == ["mean-pose"]
    (page,) = pages
    assert page["why"] == ["worst", "median"] and page["metric"] == "mpvpe"
    assert page["unit"] == "mm" and page["value"] > 0
    path = out / "viewer" / page["page"]
    assert path.is_file() and path.stat().st_size == page["bytes"] < 5e6
    text = path.read_text()
    assert page["sequence"] in text and "mpvpe right (mm)" in text  # results.csv values
    assert '"mpvpe right (mm)":[' in text  # per-frame values from frames.csv
    assert "viewer:" in (out / "run.log").read_text()


def test_report_links_methods_and_rerenders_the_same_bytes(run_out):
    _, out = run_out
    (page,) = json.loads((out / "viewer" / "index.json").read_text())["pages"]
    lb = (out / "leaderboard.html").read_text()
    assert f'<a href="viewer/{page["page"]}">worst, median</a>' in lb
    # no paper table lists mean-pose (tests/unit/test_viewer.py links a table's rows)
    assert not any("[3D:" in p.read_text() for p in (out / "tables").glob("*.*"))
    before = _html(out)
    assert main(["report", str(out)]) == 0
    assert _html(out) == before


def test_viewer_sequences_zero_removes_pages_and_links(run_out):
    root, out = run_out
    assert main(["run", "--profile", str(root / "p0.toml"), "--out", str(out), "--workers",
                 "1", "--quiet"]) == 0
    assert not (out / "viewer").exists()
    assert "viewer/" not in (out / "leaderboard.html").read_text()


def test_negative_viewer_sequences_is_an_input_error(run_out, capsys):
    root, out = run_out
    bad = root / "bad.toml"
    _profile(bad, -1)
    assert main(["run", "--profile", str(bad), "--out", str(out), "--quiet"]) == 1
    assert "viewer_sequences is too small" in capsys.readouterr().err
