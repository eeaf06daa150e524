"""The viewer's data packing (quantization, series codecs, shared meshes, sizes), the choice
of a run's pages, the report's links to them, and ``grip-bench view``."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from grip_bench.cli.main import main
from grip_bench.data.grab_io import read_grab, write_grab
from grip_bench.data.posing import hand_poser
from grip_bench.report import viewer as V
from grip_bench.report.render import relative_links, row_method, table_html
from grip_bench.report.tables import Cell, Column, Row, TableData
from tests.eval_fixtures import grasp_dataset
from tests.grab_fixtures import write_dataset


# --- quantization and codecs ------------------------------------------------------------------
def test_quantization_error_is_at_most_half_a_step():
    rng = np.random.default_rng(0)
    for extent, precision in ((0.8, V.POSITION_PRECISION), (0.8, 1e-9), (60.0, 5e-4)):
        pts = rng.uniform(-1.0, 1.0, size=(500, 3)) * extent / 2 + 3.0
        lo, hi = pts.min(0), pts.max(0)
        step = V.quantization_step(lo, hi, precision)
        assert step == pytest.approx(max(np.max(hi - lo) / 65534, precision))
        q = V.quantize(pts, lo, step)
        assert q.dtype == np.int16
        err = np.abs(V.dequantize(q, lo, step) - pts)
        assert err.max() <= step / 2 + 1e-12
    with pytest.raises(ValueError, match="outside"):
        V.quantize(np.array([[10.0, 0, 0]]), np.zeros(3), 1e-4)


@pytest.mark.parametrize("T", [1, 2, 3, 40])
def test_series_round_trip_including_wraparound(T):
    rng = np.random.default_rng(T)
    jumps = rng.integers(-32768, 32768, size=(T, 17)).astype(np.int16)  # worst case
    jumps[:, 0] = np.int16(32767)
    jumps[::2, 1] = np.int16(-32768)
    smooth = np.cumsum(rng.integers(-3, 4, size=(T, 17)), axis=0).astype(np.int16)
    near = (smooth + rng.integers(-2, 3, size=smooth.shape)).astype(np.int16)
    for x, ref in ((jumps, None), (smooth, None), (near, smooth), (jumps, smooth)):
        data, coding = V.encode_series(x, "i16", ref, "ref" if ref is not None else None)
        assert len(data) == x.nbytes
        np.testing.assert_array_equal(V.decode_series(data, x.shape, "i16", coding, ref), x)
    c = rng.integers(0, 256, size=(T, 5)).astype(np.uint8)
    data, coding = V.encode_series(c, "u8")
    np.testing.assert_array_equal(V.decode_series(data, c.shape, "u8", coding), c)


def test_series_coding_picks_the_smallest():
    t = np.arange(200)[:, None]
    ramp = (t * np.arange(1, 31)[None, :] // 7).astype(np.int16)  # smooth: residuals win
    assert V.encode_series(ramp, "i16")[1]["order"] >= 1
    rng = np.random.default_rng(0)
    jitter = (ramp + rng.integers(-40, 41, size=ramp.shape)).astype(np.int16)
    ref = (ramp + rng.integers(-1, 2, size=ramp.shape)).astype(np.int16)
    noisy = (ref + rng.integers(-3, 4, size=ramp.shape)).astype(np.int16)
    assert V.encode_series(noisy, "i16", ref, "gt")[1] == {"order": 0, "ref": "gt"}
    assert V.encode_series(jitter, "i16", None)[1]["ref"] is None


def test_contact_codes():
    d = np.array([-1.0, V.DIST_MIN, -0.002, 0.0, 0.0045, 0.02, 1.0])
    codes = V.contact_codes(d)
    assert codes[0] == 0 and np.all(np.diff(codes.astype(int)) >= 0)
    assert V.code_distance(codes[-1]) == pytest.approx(V.DIST_MAX)
    inside = (d >= V.DIST_MIN) & (d <= V.DIST_MAX)
    assert np.abs(V.code_distance(codes) - d)[inside].max() <= V.DIST_STEP / 2 + 1e-12


def test_pick_order_and_page_names():
    assert [w for w, _ in V.pick_order(2)] == ["worst", "median"]
    assert V.pick_order(5) == [("worst", 0.0), ("median", 0.5), ("best", 1.0),
                               ("q1/4", 0.25), ("q3/4", 0.75)]
    assert V.page_name("grip", "s10/apple_pass_1") == "grip__s10_apple_pass_1.html"
    assert V.page_name("a b", "s1/x") == "a_b__s1_x.html"


def test_shown_frames():
    assert V.shown_frames(10).tolist() == list(range(10))
    assert V.shown_frames(10, 3).tolist() == [0, 3, 6, 9]
    assert len(V.shown_frames(601, 1, max_frames=300)) <= 300
    with pytest.raises(Exception, match="at least 1"):
        V.shown_frames(10, 0)


# --- packing ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A 20-frame procedural sequence (box object) and a copy with a shifted right hand."""
    root = tmp_path_factory.mktemp("viewer_small")
    (path,) = write_dataset(root / "gt", [("s1", "mug", "lift")], T=20)
    gt = read_grab(path)
    pred = read_grab(path)
    pred.rhand["transl"] = np.asarray(pred.rhand["transl"]) + np.array([0.0, 0.01, 0.0],
                                                                        np.float32)
    pred_root = root / "pred"
    write_grab(pred, pred_root / "grab" / "s1" / "mug_lift_1.npz")
    return root, gt, pred


def _array(meta, blob, name):
    a = meta["arrays"][name]
    return blob[a["offset"]:a["offset"] + a["length"]], a


def _decoded(meta, blob, name):
    data, a = _array(meta, blob, name)
    ref = a["coding"]["ref"]
    return V.decode_series(data, tuple(a["shape"]), a["dtype"], a["coding"],
                           _decoded(meta, blob, ref) if ref else None)


def test_pack_ships_the_object_once_and_decodes_within_the_bound(small):
    _, gt, pred = small
    meta, blob = V.pack([V.Track("ground truth", gt), V.Track("shifted", pred),
                         V.Track("again", pred)])
    names = set(meta["arrays"])
    # one object mesh and one faces array per hand topology, shared by every track and frame
    assert {n for n in names if "object_vertices" in n or "object_faces" in n} == \
        {"object_vertices", "object_faces"}
    assert sorted(n for n in names if n.startswith("faces_")) == ["faces_0", "faces_1"]
    assert all(a["offset"] % 4 == 0 for a in meta["arrays"].values())
    step, lo = meta["box"]["step"], np.array(meta["box"]["lo"])
    assert step == pytest.approx(V.POSITION_PRECISION)  # a metre-scale box: the floor wins
    poser = hand_poser(pred)
    for side in V.SIDES:
        q = _decoded(meta, blob, meta["tracks"][1]["hands"][side]["positions"]).reshape(20, -1, 3)
        exact = poser.vertices(side, pred.hand_params(side))
        err = np.linalg.norm(V.dequantize(q, lo, step) - exact, axis=-1)
        assert err.max() <= step * np.sqrt(3) / 2 + 1e-9
        codes = _decoded(meta, blob, meta["tracks"][1]["hands"][side]["contact"])
        assert codes.shape == (20, exact.shape[1])
    pose, _ = _array(meta, blob, meta["tracks"][0]["object_pose"])
    pose = np.frombuffer(pose, "<f4").reshape(20, 12)
    np.testing.assert_allclose(pose[:, :9].reshape(-1, 3, 3), gt.object_rotations(), atol=1e-6)
    frame = meta["tracks"][1]["frame_metrics"]
    assert np.allclose(frame["vertex error vs GT, mean (mm)"], frame[
        "vertex error vs GT, mean (mm)"][0])  # a rigid 10 mm shift of one of two hands
    assert 4.0 < frame["vertex error vs GT, mean (mm)"][0] < 6.0
    assert "vertex error vs GT, mean (mm)" not in meta["tracks"][0]["frame_metrics"]
    assert meta["same_object"] and meta["up"] == [0.0, 1.0, 0.0]


def test_contact_codes_measure_distance_to_the_object(tmp_path):
    (path,) = grasp_dataset(tmp_path, specs=(("s1", "mug", "lift", False),), T=12)
    seq = read_grab(path)
    meta, blob = V.pack([V.Track("ground truth", seq)])
    codes = _decoded(meta, blob, meta["tracks"][0]["hands"]["right"]["contact"])
    d = V.code_distance(codes)
    assert d[-1].min() < 0.0045 and d[0].min() > 0.0045  # the grasp closes onto the mug
    # against trimesh's exact distance (positive inside there) in the object's frame
    import trimesh

    from grip_bench.core.frames import world_to_object
    from grip_bench.data.posing import load_object_mesh_of

    mesh = trimesh.Trimesh(*load_object_mesh_of(seq), process=False)
    verts = hand_poser(seq).vertices("right", seq.hand_params("right"))
    for t in (0, 11):
        local = world_to_object(verts[t:t + 1], seq.object_rotations()[t:t + 1],
                                np.asarray(seq.object["transl"], float)[t:t + 1])[0]
        near = np.flatnonzero(codes[t] < codes.max())[::7]  # within the code range, a subsample
        exact = -trimesh.proximity.signed_distance(mesh, local[near])
        assert np.abs(d[t, near] - exact).max() < V.DIST_STEP / 2 + 5e-4
    held = meta["tracks"][0]["frame_metrics"]["hand vertices within 4.5 mm"]
    assert held[-1] > 0 and held[0] == 0


def test_page_is_self_contained_deterministic_and_small(small, tmp_path):
    _, gt, pred = small
    tracks = [V.Track("ground </script> truth", gt), V.Track("shifted", pred)]
    a = V.write_viewer(tmp_path / "a.html", tracks).read_bytes()
    b = V.write_viewer(tmp_path / "b.html", tracks).read_bytes()
    assert a == b
    text = a.decode("utf-8")
    assert text.count("</script>") == 4  # meta, data, three.js, app: the label is escaped
    assert "window.THREE=Object.freeze({" in text and "export{" not in text
    assert not re.search(r"(src|href)=\"(https?:)?//", text)
    assert "three@" + V.THREE_VERSION in text
    meta = json.loads(re.search(r'id="gb-meta">(.*?)</script>', text).group(1)
                      .replace("<\\/", "</"))
    assert meta["tracks"][0]["label"] == "ground </script> truth"


@pytest.mark.slow
def test_typical_page_size_300_frames(tmp_path):
    """Ground truth + one method, 300 frames, both hands grasping: under 5 MB (docs/viewer.md)."""
    (path,) = grasp_dataset(tmp_path, specs=(("s2", "cylindermedium", "pass", True),), T=300)
    gt = read_grab(path)
    pred = read_grab(path)
    rng = np.random.default_rng(0)  # a method's jitter: 2 mm wrist noise, 0.02 rad fingers
    for part in (pred.rhand, pred.lhand):
        part["transl"] = part["transl"] + rng.normal(0, 0.002, part["transl"].shape)
        part["hand_pose"] = part["hand_pose"] + rng.normal(0, 0.02, part["hand_pose"].shape)
    page = V.write_viewer(tmp_path / "p.html", [V.Track("ground truth", gt),
                                                V.Track("noisy", pred)])
    size = page.stat().st_size
    assert size < 5e6, size
    half = V.write_viewer(tmp_path / "h.html", [V.Track("ground truth", gt),
                                                V.Track("noisy", pred)], frames_step=2)
    assert half.stat().st_size < 0.7 * size


def test_three_js_is_the_vendored_version():
    js = V.three_js()
    assert js.startswith("(function(){") and "WebGLRenderer:" in js
    assert (V.VENDOR / "LICENSE").read_text().startswith("The MIT License")


# --- a run's pages ----------------------------------------------------------------------------
def _results(values: dict[str, float], metric="mpvpe", method="m") -> pd.DataFrame:
    rows = [{"method": method, "dataset": "d", "split": "test", "perturbation": "none",
             "sequence": s, "object": "o", "hand": h, "metric": metric, "value": v,
             "unit": "mm" if metric != "contact_ratio" else "%", "n_frames": 10}
            for s, v in values.items() for h in ("right", "left")]
    return pd.DataFrame(rows)


def test_choose_sequences_worst_median_best():
    df = _results({"s1/a": 5.0, "s1/b": 9.0, "s1/c": 1.0, "s1/d": 3.0, "s1/e": float("nan")})
    picks = V.choose_sequences(df, "m", 3)
    assert [(p["sequence"], p["why"]) for p in picks] == \
        [("s1/b", ["worst"]), ("s1/d", ["median"]), ("s1/c", ["best"])]
    assert picks[0]["metric"] == "mpvpe" and picks[0]["value"] == 9.0
    assert V.choose_sequences(df, "m", 0) == [] and V.choose_sequences(df, "x", 2) == []
    # higher is better: the lowest contact ratio is the worst
    hib = _results({"s1/a": 80.0, "s1/b": 20.0}, metric="contact_ratio")
    assert V.choose_sequences(hib, "m", 1)[0]["sequence"] == "s1/b"
    one = V.choose_sequences(_results({"s1/a": 2.0}), "m", 2)
    assert [(p["sequence"], p["why"]) for p in one] == [("s1/a", ["worst", "median"])]


def _table() -> TableData:
    col = Column(group="MPVPE", label="", unit="mm", higher_is_better=False)
    rows = tuple(Row(label=m, cells=(Cell(ci=None, filters={"method": m}),))
                 for m in ("grip", "toch"))
    return TableData(id="t", title="T", version=1, description="d", row_header="Method",
                     columns=(col,), rows=rows, notes=())


def test_table_rows_link_to_their_pages(tmp_path):
    out = tmp_path
    page = out / "viewer" / "grip__s1_a.html"
    links = {"grip": [("worst", page)]}
    assert relative_links(links, out / "tables") == {"grip": [("worst",
                                                               "../viewer/grip__s1_a.html")]}
    html = table_html(_table(), relative_links(links, out))
    assert '<a href="viewer/grip__s1_a.html">worst</a>' in html
    assert html.count("<a href") == 1  # toch has no page
    assert row_method(_table().rows[0]) == "grip"
    assert "<a href" not in table_html(_table())


def test_render_all_links_table_rows_relative_to_their_folder(tmp_path):
    from grip_bench.report.render import render_all
    from grip_bench.results.schema import write_results

    write_results(_results({"s1/a": 1.0, "s1/b": 2.0}, method="gt"), tmp_path / "results.csv")
    page = tmp_path / "viewer" / "gt__s1_a.html"
    render_all(tmp_path, tmp_path / "tables", n_boot=20, links={"gt": [("worst", page)]})
    html = (tmp_path / "tables" / "table4_grasp.html").read_text()
    assert '<a href="../viewer/gt__s1_a.html">worst</a>' in html
    assert "viewer/" not in (tmp_path / "tables" / "table4_grasp.md").read_text()


def test_run_pages_in_two_processes_are_the_serial_bytes(small, tmp_path):
    """write_run_pages(workers=2) packs each page in its own process: same pages, same
    index (the runner passes --workers)."""
    root, _, _ = small
    df = pd.concat([_results({"s1/mug_lift_1": 4.5}, method=m) for m in ("m", "k", "gt")])
    sources = {m: (root / "pred", root / "gt") for m in ("m", "k")}
    outs = {}
    for w in (1, 2):
        out = tmp_path / f"w{w}"
        entries = V.write_run_pages(out, df, sources, 1, workers=w)
        assert [e["method"] for e in entries] == ["k", "m"]
        outs[w] = {p.name: p.read_bytes() for p in sorted((out / "viewer").iterdir())}
    assert len(outs[1]) == 3 and outs[1] == outs[2]  # two pages and index.json


def test_a_rerun_keeps_pages_whose_inputs_match(small, tmp_path, monkeypatch):
    """With a code digest, a page whose inputs match the index's entry is not written again;
    another code digest or another prediction file writes it again (same bytes as fresh)."""
    import shutil

    root, _, _ = small
    df = _results({"s1/mug_lift_1": 4.5}, method="m")
    sources = {"m": (root / "pred", root / "gt")}
    out = tmp_path / "out"
    first = V.write_run_pages(out, df, sources, 1, code="v1")
    page = out / "viewer" / first[0]["page"]
    fresh = page.read_bytes()
    assert len(first[0]["inputs"]) == 64 and first[0]["bytes"] == len(fresh)
    written = []
    real = V._write_page
    monkeypatch.setattr(V, "_write_page", lambda job: written.append(job) or real(job))
    again = V.write_run_pages(out, df, sources, 1, code="v1")
    assert written == [] and again == first and page.read_bytes() == fresh
    V.write_run_pages(out, df, sources, 1, code="v2")
    assert len(written) == 1 and page.read_bytes() == fresh
    moved = tmp_path / "pred2"
    shutil.copytree(root / "pred", moved)
    seq = next((moved / "grab").rglob("*.npz"))
    seq.write_bytes(seq.read_bytes() + b"")  # same bytes: still kept
    V.write_run_pages(out, df, {"m": (moved, root / "gt")}, 1, code="v2")
    assert len(written) == 1  # the inputs are the files' bytes, not their paths
    page.unlink()  # a missing page is written whatever the index says
    V.write_run_pages(out, df, sources, 1, code="v2")
    assert len(written) == 2 and page.read_bytes() == fresh


def test_index_round_trip_and_removal(tmp_path):
    (tmp_path / "viewer").mkdir()
    (tmp_path / "viewer" / "m__s1_a.html").write_text("x")
    V.write_index(tmp_path, [{"method": "m", "sequence": "s1/a", "why": ["worst", "median"],
                              "metric": "mpvpe", "value": 1.0, "unit": "mm",
                              "page": "m__s1_a.html", "bytes": 1}])
    assert V.viewer_links(tmp_path) == {"m": [("worst, median",
                                               tmp_path / "viewer" / "m__s1_a.html")]}
    V.remove_pages(tmp_path)
    assert not (tmp_path / "viewer").exists() and V.viewer_links(tmp_path) == {}


# --- grip-bench view --------------------------------------------------------------------------
def test_cli_writes_a_page(small, tmp_path, capsys):
    root, gt, _ = small
    out = tmp_path / "deep" / "page.html"
    assert main(["view", "--gt", str(root / "gt"), "--pred", str(root / "pred"), "--label",
                 "shifted", "--sequence", "s1/mug_lift_1", "--out", str(out), "--overlay",
                 "--frames-step", "2"]) == 0
    assert "wrote" in capsys.readouterr().out
    meta = json.loads(re.search(r'id="gb-meta">(.*?)</script>', out.read_text()).group(1))
    assert [t["label"] for t in meta["tracks"]] == ["ground truth", "shifted"]
    assert meta["overlay"] and meta["frames"] == list(range(0, 20, 2)) and meta["fps"] == 15.0


def test_cli_shows_results_values(small, tmp_path):
    root, gt, _ = small
    df = _results({"s1/mug_lift_1": 4.5}, method="shifted")
    from grip_bench.results.schema import write_results

    write_results(df, tmp_path / "results.csv")
    out = tmp_path / "page.html"
    assert main(["view", "--gt", str(root / "gt"), "--pred", str(root / "pred"), "--label",
                 "shifted", "--sequence", "s1/mug_lift_1", "--out", str(out), "--results",
                 str(tmp_path)]) == 0
    meta = json.loads(re.search(r'id="gb-meta">(.*?)</script>', out.read_text()).group(1))
    assert meta["tracks"][1]["sequence_metrics"] == {"mpvpe left (mm)": 4.5,
                                                     "mpvpe right (mm)": 4.5}


@pytest.mark.parametrize("case, message", [
    ("missing-sequence", "no sequence 's1/nope'"),
    ("missing-gt", "--gt"),
    ("length", "has 12 frames, the ground truth 20"),
    ("labels", "1 labels for 2 prediction folders"),
    ("step", "--frames-step: must be at least 1"),
    ("object", "the ground truth's is 'mug'"),
    ("results", "no results.csv here"),
])
def test_cli_bad_input_is_one_line(small, tmp_path, capsys, case, message):
    root, gt, pred = small
    args = {"--gt": str(root / "gt"), "--sequence": "s1/mug_lift_1",
            "--out": str(tmp_path / "p.html")}
    extra = ["--pred", str(root / "pred")]
    if case == "missing-sequence":
        args["--sequence"] = "s1/nope"
    elif case == "missing-gt":
        args["--gt"] = str(tmp_path / "absent")
    elif case == "length":
        write_grab(pred.frames(0, 12), tmp_path / "short" / "grab" / "s1" / "mug_lift_1.npz")
        extra = ["--pred", str(tmp_path / "short")]
    elif case == "labels":
        extra = ["--pred", str(root / "pred"), "--pred", str(root / "pred"), "--label", "a"]
    elif case == "step":
        extra += ["--frames-step", "0"]
    elif case == "object":
        other = pred.copy()
        other.obj_name = "cup"
        write_grab(other, tmp_path / "cup" / "grab" / "s1" / "mug_lift_1.npz")
        extra = ["--pred", str(tmp_path / "cup")]
    elif case == "results":
        extra += ["--results", str(tmp_path)]
    argv = ["view", *[x for kv in args.items() for x in kv], *extra]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "p.html").exists()
