"""Report figures: each renders, twice to the same bytes, and rejects malformed input.

``python -m tests.unit.test_figures docs/img`` rewrites the example renders in the docs.
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

from grip_bench.bodies.hand import ProceduralHand
from grip_bench.core.errors import InputError
from grip_bench.report import figures as F

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels from the IHDR chunk."""
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    return struct.unpack(">II", data[16:24])


def grab_like_frequency(side: str, seed: int = 0, scale: float = 1.0) -> np.ndarray:
    """(V,) fractions shaped like GRAB's contact statistics: thumb, index and middle tips hot,
    ring and pinky tips warm, finger pads and the palm's centre warm, the back of the hand cold.
    ``scale`` multiplies everything (a method that touches less often)."""
    hand = ProceduralHand(side)
    v = hand.template_vertices.double().numpy()
    normals = trimesh.Trimesh(v, hand.faces, process=False).vertex_normals
    volar = np.clip(-normals[:, 1], 0.0, 1.0)  # palm normal is -y
    tip_heat = (0.85, 0.8, 0.7, 0.5, 0.35)  # thumb, index, middle, ring, pinky
    f = np.zeros(len(v))
    for tip, heat in zip(hand.fingertip_ids, tip_heat, strict=True):
        d = np.linalg.norm(v - v[tip], axis=1)
        f = np.maximum(f, heat * np.exp(-0.5 * (d / 0.018) ** 2) * (0.3 + 0.7 * volar))
    pads = (hand.part_labels > 0) & (volar > 0.5)  # finger pads touch now and then
    f = np.maximum(f, 0.12 * pads * volar)
    palm = v[hand.part_labels == 0].mean(0)
    d = np.linalg.norm((v - palm)[:, [0, 2]], axis=1)
    f = np.maximum(f, 0.3 * np.exp(-0.5 * (d / 0.03) ** 2) * volar ** 2)
    noise = np.random.default_rng(seed).uniform(0.9, 1.1, len(v))
    return np.clip(scale * f * noise, 0.0, 1.0) * (f > 0.01)


@pytest.fixture(scope="module")
def freqs() -> dict[str, dict[str, np.ndarray]]:
    return {"grip": {s: grab_like_frequency(s, 1, 0.8) for s in F.SIDES},
            "gt": {s: grab_like_frequency(s, 0) for s in F.SIDES}}


def fake_results(seed: int = 0) -> pd.DataFrame:
    """results.csv-shaped rows: 3 methods x 3 objects x 4 sequences x 2 hands, MPVPE in mm."""
    rng = np.random.default_rng(seed)
    rows = []
    for m, base in (("grip", 8.0), ("toch", 12.0), ("gt", 0.0)):
        for o in ("mug", "apple", "binoculars"):
            for k in range(4):
                for hand in ("right", "left"):
                    rows.append(dict(method=m, dataset="synthgrab", split="test",
                                     perturbation="none", sequence=f"s1/{o}_lift_{k}", object=o,
                                     hand=hand, metric="mpvpe", value=base + rng.gamma(2.0),
                                     unit="mm", n_frames=90))
    return pd.DataFrame(rows)


# --- projection ----------------------------------------------------------------------------
@pytest.mark.parametrize("side", F.SIDES)
def test_views_show_palm_and_back(side):
    """Fingers point up in both views; the thumb sits on the side anatomy puts it."""
    hand = ProceduralHand(side)
    views = F.hand_template_views(side)
    thumb = hand.fingertip_ids[0]
    for name, view in views.items():
        assert len(view.faces) < len(hand.faces)  # back faces culled
        assert view.xy[hand.fingertip_ids[2], 1] > view.xy[:, 1].mean()  # middle tip up
        # seen palm-first, a right hand's thumb is on the viewer's right; the back view and
        # the left hand flip it
        thumb_right = (name == "palm") == (side == "right")
        assert (view.xy[thumb, 0] > view.xy[:, 0].mean()) == thumb_right
    palm_ids = set(views["palm"].face_ids)
    assert not palm_ids & set(views["back"].face_ids)  # a face faces one camera only


def test_painter_order_is_far_to_near():
    view = F.hand_template_views("right")["palm"]
    verts = ProceduralHand("right").template_vertices.double().numpy()
    depth = verts[view.faces][..., 1].mean(1)  # the palm camera sits at -y: near = small y
    assert np.all(np.diff(-depth) >= -1e-12)


# --- heatmaps ------------------------------------------------------------------------------
def test_heatmap_renders_deterministically(tmp_path, freqs):
    a = F.contact_heatmap(freqs, tmp_path / "a.png", title="contact heatmaps")
    b = F.contact_heatmap(freqs, tmp_path / "b.png", title="contact heatmaps")
    assert a.read_bytes() == b.read_bytes()
    w, h = png_size(a)
    assert 800 < w < 2000 and 600 < h < 2000


def test_heatmap_random_percent_and_missing_side(tmp_path):
    rng = np.random.default_rng(3)
    n = len(ProceduralHand("right").template_vertices)
    freqs = {"manipnet": {"right": 100 * rng.random(n)},  # right hand only
             "gt": {"right": 100 * rng.random(n), "left": np.full(n, np.nan)}}
    out = F.contact_heatmap(freqs, tmp_path / "h.png", unit="percent")
    assert out.stat().st_size > 10_000


def test_heatmap_rejects_wrong_vertex_count(tmp_path, freqs):
    bad = {"gt": {"right": np.zeros(778), "left": freqs["gt"]["left"]}}
    with pytest.raises(InputError, match=r"freqs\['gt'\]\['right'\].*778"):
        F.contact_heatmap(bad, tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("bad, match", [
    ({"gt": {"middle": np.zeros(3)}}, "sides"),
    ({"gt": {"right": "percent"}}, "per-vertex numbers"),
    ({}, "no methods"),
])
def test_heatmap_rejects_malformed(tmp_path, bad, match):
    with pytest.raises(InputError, match=match):
        F.contact_heatmap(bad, tmp_path / "x.png")


def test_heatmap_rejects_values_out_of_range(tmp_path, freqs):
    bad = {"gt": {"right": 100 * freqs["gt"]["right"] + 1}}  # percent passed as fractions
    with pytest.raises(InputError, match=r"fractions must lie in \[0, 1\]"):
        F.contact_heatmap(bad, tmp_path / "x.png")


def test_heatmap_data_round_trip(tmp_path, freqs):
    data = {**freqs, "manipnet": {"right": freqs["grip"]["right"]}}
    p = F.write_heatmap_data(tmp_path / "h.npz", data)
    back = F.read_heatmap_data(p)
    assert list(back) == list(data)
    for m in data:
        assert set(back[m]) == set(data[m])
        for s in data[m]:
            np.testing.assert_array_equal(back[m][s], data[m][s])
    with np.load(p, allow_pickle=False) as z:  # numbers and plain strings only
        assert all(z[k].dtype != object for k in z.files)
    assert F.write_heatmap_data(tmp_path / "h2.npz", data).read_bytes() == p.read_bytes()


def test_heatmap_data_rejects_junk(tmp_path):
    p = tmp_path / "junk.npz"
    p.write_bytes(b"not a zip")
    with pytest.raises(InputError, match="junk.npz"):
        F.read_heatmap_data(p)
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(InputError, match="missing"):
        F.read_heatmap_data(tmp_path / "other.npz")
    with pytest.raises(InputError, match="shape"):
        F.write_heatmap_data(tmp_path / "x.npz", {"a": {"right": np.zeros(3)},
                                                  "b": {"right": np.zeros(4)}})


# --- penetration CDF -----------------------------------------------------------------------
def test_pen_cdf_renders_deterministically(tmp_path):
    rng = np.random.default_rng(0)
    depths = {"grip": rng.gamma(2.0, 1.2, 400), "gt": np.r_[rng.gamma(3.0, 1.0, 300), np.nan],
              "toch": np.zeros(50)}
    for log_x in (False, True):
        a = F.penetration_cdf(depths, tmp_path / f"a{log_x}.png", log_x=log_x)
        b = F.penetration_cdf(depths, tmp_path / f"b{log_x}.png", log_x=log_x)
        assert a.read_bytes() == b.read_bytes()
        w, h = png_size(a)
        assert 600 < w < 1500 and 400 < h < 1000


def test_ecdf_values():
    x, y = F._ecdf(np.array([3.0, 1.0, 2.0, 2.0]))
    np.testing.assert_array_equal(x, [1, 2, 2, 3])
    np.testing.assert_array_equal(y, [25, 50, 75, 100])


def test_pen_cdf_rejects_inf(tmp_path):
    with pytest.raises(InputError, match="grip"):
        F.penetration_cdf({"grip": np.array([1.0, np.inf])}, tmp_path / "x.png")


# --- per-object bars -----------------------------------------------------------------------
def test_per_object_bars_renders_deterministically(tmp_path):
    df = fake_results()
    a = F.per_object_bars(df, "mpvpe", tmp_path / "a.png")
    b = F.per_object_bars(df.sample(frac=1.0, random_state=1), "mpvpe", tmp_path / "b.png")
    assert a.read_bytes() == b.read_bytes()  # row order does not matter
    w, h = png_size(a)
    assert 600 < w < 2500 and 400 < h < 1000


def test_per_object_stats_match_bootstrap():
    from grip_bench.results.stats import bootstrap_ci

    df = fake_results()
    rows = df[df["hand"] == "right"]
    stats = F._object_cis(rows, ["grip"], ["mug"])
    v = rows[(rows["method"] == "grip") & (rows["object"] == "mug")].sort_values("sequence")
    ci = bootstrap_ci(v["value"].to_numpy())
    np.testing.assert_allclose(stats[0, 0], [ci.mean, ci.lo, ci.hi])
    assert ci.lo <= ci.mean <= ci.hi


def test_per_object_bars_errors(tmp_path):
    df = fake_results()
    with pytest.raises(InputError, match="no rows for metric 'iv'"):
        F.per_object_bars(df, "iv", tmp_path / "x.png")
    with pytest.raises(InputError, match="nope"):
        F.per_object_bars(df, "mpvpe", tmp_path / "x.png", methods=["grip", "nope"])
    with pytest.raises(InputError, match="lacks columns"):
        F.per_object_bars(df.drop(columns=["object"]), "mpvpe", tmp_path / "x.png")


def write_examples(folder: str | Path) -> None:
    """Example renders for the docs (GRAB-like synthetic statistics)."""
    folder = Path(folder)
    freqs = {"gt": {s: grab_like_frequency(s, 0) for s in F.SIDES},
             "grip": {s: grab_like_frequency(s, 1, 0.8) for s in F.SIDES}}
    F.contact_heatmap(freqs, folder / "example_heatmap.png",
                      title="Contact heatmaps (synthetic GRAB-like statistics)")
    rng = np.random.default_rng(0)
    depths = {"gt": rng.normal(3.25, 0.68, 2000).clip(0), "grip": rng.gamma(2.2, 1.3, 2000),
              "toch": rng.gamma(3.0, 1.6, 2000)}
    F.penetration_cdf(depths, folder / "example_pen_cdf.png",
                      title="Penetration depth per grasp frame (synthetic)")


if __name__ == "__main__":
    write_examples(sys.argv[1] if len(sys.argv) > 1 else "docs/img")
