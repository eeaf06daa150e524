"""Table definitions: the six built-in tables, their references, and file validation."""

from __future__ import annotations

import copy

import pytest

from grip_bench.cli.main import main
from grip_bench.core.errors import InputError
from grip_bench.metrics.registry import METRICS
from grip_bench.report.tables import TABLES, load_table, parse_table

TABLE_IDS = ["table2_ablation", "table3_perturbation", "table4_grasp", "table4_future",
             "physics", "runtime"]
METHOD_IDS = {"grip", "grip-no-ambient", "grip-no-proximity", "grip-no-consist",
              "grip-output-consist", "grip-voxel-ambient", "grip-no-rnet", "grip-future0",
              "grip-future3", "grip-future5", "grip-future10", "grabnet", "grabnet-smplx",
              "manipnet", "toch", "gt", "flat-input", "mean-pose", "nearest-neighbour",
              "perturbed-input", "grip-blind", "nearest-arm"}
PERTURBATIONS = {"none", "T0.01", "T0.02", "R0.3", "R0.5"}


def test_six_tables_in_paper_order():
    assert TABLES.names() == TABLE_IDS
    for spec in TABLES:
        line = spec.describe()
        assert isinstance(line, str) and line.startswith(spec.id) and f"v{spec.version}" in line


def test_tables_reference_known_methods_metrics_perturbations():
    for spec in TABLES:
        assert set(spec.methods()) <= METHOD_IDS, spec.id
        for row in spec.rows:
            for col in spec.columns:
                flt = spec.cell_filters(row, col)
                assert flt.get("perturbation", "none") in PERTURBATIONS
                if spec.source == "results":
                    assert flt["metric"] in METRICS, (spec.id, flt)


def test_table_shapes_match_the_paper():
    t2 = TABLES.get("table2_ablation")
    assert [r.filters["method"] for r in t2.rows] == [
        "grip-no-ambient", "grip-no-proximity", "grip-no-consist", "grip-output-consist",
        "grip-voxel-ambient", "grip-no-rnet", "grip", "grip-blind", "nearest-arm"]
    assert [r.reference for r in t2.rows] == [False] * 7 + [True] * 2  # the probes (issue #16)
    assert [(c.filters["metric"], c.filters["hand"]) for c in t2.columns][:6] == [
        ("mpvpe", "right"), ("mpvpe", "left"), ("mpjpe", "right"), ("mpjpe", "left"),
        ("cc", "right"), ("cc", "left")]
    t3 = TABLES.get("table3_perturbation")
    assert [c.filters["perturbation"] for c in t3.columns] == ["T0.01", "T0.02", "R0.3", "R0.5"]
    assert all(c.before == {"method": "perturbed-input"} for c in t3.columns)
    grasp = TABLES.get("table4_grasp")
    assert [r.reference for r in grasp.rows] == [False] * 5 + [True]
    phys = TABLES.get("physics")
    assert [c.filters["metric"] for c in phys.columns] == [
        "hold_qs", "hold_qs_mu05", "hold_qs_mu3", "hold_qs_axes", "sim_stable", "sim_disp",
        "hold_sim", "hold_sim_disp", "hold_sim_settle", "hold_sim_ruled", "hold_sim_mu05",
        "hold_sim_mu3", "hold_sim_weak", "hold_sim_strong", "hold_sim_axes"]
    assert [r.reference for r in phys.rows] == [False] * 2 + [True] * 3  # gt and two controls
    assert [(g.row, g.min, g.max, g.between) for g in phys.gates] == [
        ("Ground truth", 80.0, None, None), ("Flat hand (control)", None, 5.0, None),
        ("GRAB-T 0.01 input (control)", None, None,
         ("Flat hand (control)", "Ground truth"))] * 2  # hold_qs, then the articulated hold_sim
    assert [g.metric for g in phys.gates] == ["hold_qs"] * 3 + ["hold_sim"] * 3
    assert TABLES.get("runtime").source == "runtime"


def test_ls_tables_lists_six(capsys):
    assert main(["ls", "tables"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "tables (6):"
    assert [line.split()[0] for line in out[1:]] == TABLE_IDS


GOOD = {"id": "t", "version": 1, "title": "T", "description": "d",
        "defaults": {"split": "test"},
        "rows": [{"label": "GRIP", "method": "grip"}],
        "columns": [{"metric": "mpvpe", "hand": "right"}]}


def _bad(change):
    data = copy.deepcopy(GOOD)
    change(data)
    return data


@pytest.mark.parametrize("change, where, needle", [
    (lambda d: d.update(colour="red"), "t.toml", "unknown key 'colour'"),
    (lambda d: d.pop("title"), "t.toml", "missing required field 'title'"),
    (lambda d: d["rows"][0].pop("label"), "t.toml: rows[0]", "missing required field 'label'"),
    (lambda d: d["rows"][0].update(methd="x"), "t.toml: rows[0]", "unknown key 'methd'"),
    (lambda d: d["columns"][0].pop("metric"), "t.toml: rows[0] x columns[0]",
     "missing required field 'metric'"),
    (lambda d: d["columns"][0].update(method="toch"), "t.toml: rows[0] x columns[0]",
     "disagree on 'method'"),
    (lambda d: d.update(version="1"), "t.toml", "'version' must be int"),
    (lambda d: d["columns"][0].update(before={"methd": "x"}), "t.toml: columns[0].before",
     "unknown key"),
    (lambda d: d["defaults"].update(hands="x"), "t.toml: defaults", "unknown key 'hands'"),
    (lambda d: d.update(source="sql"), "t.toml", "'source' must be one of"),
    (lambda d: d.update(columns=[]), "t.toml: columns", "at least one column"),
    (lambda d: d.update(gates=[{"row": "GRIP", "metric": "mpvpe"}]), "t.toml: gates[0]",
     "exactly one of 'min', 'max', 'between'"),
    (lambda d: d.update(gates=[{"row": "GT", "metric": "mpvpe", "min": 1.0}]),
     "t.toml: gates[0]", "no row labelled 'GT'"),
    (lambda d: d.update(gates=[{"row": "GRIP", "metric": "cc", "max": 1}]),
     "t.toml: gates[0]", "no column of metric 'cc'"),
    (lambda d: d.update(gates=[{"row": "GRIP", "metric": "mpvpe", "between": ["GRIP"]}]),
     "t.toml: gates[0]", "'between' must name two rows"),
    (lambda d: d.update(gates=[{"row": "GRIP", "metric": "mpvpe", "min": "80"}]),
     "t.toml: gates[0]", "'min' must be float"),
])
def test_validation_names_file_and_field(change, where, needle):
    with pytest.raises(InputError) as e:
        parse_table(_bad(change), "t.toml")
    assert e.value.where == where and needle in e.value.what


def test_load_table_file_errors(tmp_path):
    p = tmp_path / "other.toml"
    p.write_text('id = "t"\nversion = 1\ntitle = "T"\ndescription = "d"\nrows = []\n'
                 'columns = [{metric = "mpvpe", hand = "right", method = "grip"}]\n')
    with pytest.raises(InputError, match="must match the file name"):
        load_table(p)
    bad = tmp_path / "t.toml"
    bad.write_text("id = ")
    with pytest.raises(InputError, match="not valid TOML") as e:
        load_table(bad)
    assert e.value.where == str(bad)
    spec = load_table(_write_good(tmp_path))
    assert spec.id == "t" and spec.rows[0].label == "GRIP"


def _write_good(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text('id = "t"\nversion = 2\ntitle = "T"\ndescription = "d"\n'
                 '[[rows]]\nlabel = "GRIP"\nmethod = "grip"\n'
                 '[[columns]]\nmetric = "mpvpe"\nhand = "right"\n')
    return p


def test_runtime_columns_need_a_field():
    data = {"id": "r", "version": 1, "title": "R", "description": "d", "source": "runtime",
            "rows": [{"label": "GRIP", "method": "grip"}], "columns": [{"unit": "s"}]}
    with pytest.raises(InputError, match="missing required field 'field'"):
        parse_table(data, "r.toml")
    data["columns"] = [{"field": "flops"}]
    with pytest.raises(InputError, match="'field' must be one of"):
        parse_table(data, "r.toml")


def test_ls_methods_lists_the_tables_the_table_files_name(capsys):
    """The table files are the one home of which tables show a method: ``ls methods``
    reads them (checked here against a plain walk of the TOML text)."""
    import tomllib
    from importlib import resources

    from grip_bench.cli.main import main

    def methods_in(node) -> set[str]:
        if isinstance(node, dict):
            found = {node["method"]} if isinstance(node.get("method"), str) else set()
            return found.union(*(methods_in(v) for v in node.values()))
        if isinstance(node, list):
            return set().union(*(methods_in(v) for v in node))
        return set()

    expected: dict[str, set[str]] = {}
    for path in resources.files("grip_bench.report.tables").iterdir():
        if path.name.endswith(".toml"):
            table = tomllib.loads(path.read_text(encoding="utf-8"))
            for method in methods_in(table):
                expected.setdefault(method, set()).add(table["id"])
    assert main(["ls", "methods"]) == 0
    listed = {}
    for line in capsys.readouterr().out.splitlines()[1:]:
        name, tables = line.split()[0], line.split("tables=")[1].split()[0]
        listed[name] = set() if tables == "-" else set(tables.split(","))
    for name, tables in listed.items():
        assert tables == expected.get(name, set()), name
    assert expected.keys() <= listed.keys() | {"grip-future10"}
