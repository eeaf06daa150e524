"""Perturbations: noise statistics, determinism, only targeted fields change, dataset output."""

import json
import shutil

import numpy as np
import pytest

from grip_bench.bodies.layouts import SMPLX_INDEX
from grip_bench.core.errors import InputError
from grip_bench.data.grab_io import dataset_hash, read_grab
from grip_bench.data.perturb import perturb_dataset, perturb_sequence, sequence_rng
from grip_bench.data.splits import read_splits
from tests.grab_fixtures import make_sequence, write_dataset

T = 300  # 1800+ noise samples per check: the std estimate is within ~2% (1 sigma)


def _diffs(a, b):
    """{(part, key): b - a} for every array that changed."""
    out = {}
    for part, params in a.parts().items():
        for k, v in params.items():
            d = b.parts()[part][k].astype(float) - v.astype(float)
            if np.any(d != 0):
                out[(part, k)] = d
    for k, v in a.contact.items():
        assert np.array_equal(v, b.contact[k])
    return out


@pytest.fixture(scope="module")
def seq():
    return make_sequence(T=T, seed=11, dtype=np.float64)


@pytest.mark.parametrize("sigma", [0.01, 0.02])
def test_translation_noise(seq, sigma):
    out = perturb_sequence(seq, "T", sigma, np.random.default_rng(0))
    d = _diffs(seq, out)
    assert set(d) == {("rhand", "transl"), ("lhand", "transl")}
    noise = np.concatenate([d[("rhand", "transl")], d[("lhand", "transl")]])
    assert noise.std() == pytest.approx(sigma, rel=0.1)
    assert abs(noise.mean()) < 4 * sigma / np.sqrt(noise.size)
    assert out.validate() is out


@pytest.mark.parametrize("sigma", [0.3, 0.5])
def test_hand_pose_noise(seq, sigma):
    out = perturb_sequence(seq, "R", sigma, np.random.default_rng(1))
    d = _diffs(seq, out)
    assert set(d) == {
        ("rhand", "hand_pose"),
        ("lhand", "hand_pose"),
        ("rhand", "fullpose"),
        ("lhand", "fullpose"),
        ("body", "right_hand_pose"),
        ("body", "left_hand_pose"),
        ("body", "fullpose"),
    }
    for side, part in (("right", "rhand"), ("left", "lhand")):
        noise = d[(part, "hand_pose")]
        assert noise.std() == pytest.approx(sigma, rel=0.1)
        assert not d[(part, "fullpose")][:, :3].any()  # wrist orientation untouched
        np.testing.assert_allclose(d[(part, "fullpose")][:, 3:], noise, atol=1e-12)
        np.testing.assert_allclose(d[("body", f"{side}_hand_pose")], noise, atol=1e-12)
    full = d[("body", "fullpose")]
    assert not full[:, :75].any()
    np.testing.assert_allclose(full[:, 75:120], d[("lhand", "hand_pose")], atol=1e-12)
    np.testing.assert_allclose(full[:, 120:], d[("rhand", "hand_pose")], atol=1e-12)


def test_arm_noise(seq):
    out = perturb_sequence(seq, "arm", None, np.random.default_rng(2))
    d = _diffs(seq, out)
    assert set(d) == {("body", "body_pose"), ("body", "fullpose")}
    bp, full = d[("body", "body_pose")], d[("body", "fullpose")]
    cols = {name: 3 * (SMPLX_INDEX[name] - 1) for name in
            ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow")}
    changed = sorted(c + i for c in cols.values() for i in range(3))
    assert sorted(np.flatnonzero(np.abs(bp).sum(0))) == changed
    shoulders = np.concatenate([bp[:, c:c + 3] for n, c in cols.items() if "shoulder" in n])
    elbows = np.concatenate([bp[:, c:c + 3] for n, c in cols.items() if "elbow" in n])
    assert shoulders.std() == pytest.approx(0.01, rel=0.1)
    assert elbows.std() == pytest.approx(0.03, rel=0.1)
    np.testing.assert_allclose(full[:, 3:66], bp, atol=1e-12)  # same joints in fullpose
    assert not full[:, :3].any() and not full[:, 66:].any()


def test_determinism_and_seeds(seq):
    a = perturb_sequence(seq, "R", 0.3, np.random.default_rng(5))
    b = perturb_sequence(seq, "R", 0.3, 5)
    c = perturb_sequence(seq, "R", 0.3, np.random.default_rng(6))
    assert np.array_equal(a.rhand["hand_pose"], b.rhand["hand_pose"])
    assert not np.array_equal(a.rhand["hand_pose"], c.rhand["hand_pose"])
    fresh = make_sequence(T=T, seed=11, dtype=np.float64)
    assert np.array_equal(seq.rhand["hand_pose"], fresh.rhand["hand_pose"])  # input untouched


def test_float32_sequences_stay_float32():
    s = make_sequence(T=10, dtype=np.float32)
    out = perturb_sequence(s, "T", 0.01, 0)
    assert out.rhand["transl"].dtype == np.float32


@pytest.mark.parametrize("kind, sigma, message", [
    ("T", None, "needs a sigma"), ("X", 0.1, "unknown perturbation"), ("R", -1.0, ">= 0"),
    ("arm", (0.1, 0.2, 0.3), "shoulder, elbow"),
])
def test_bad_arguments(seq, kind, sigma, message):
    with pytest.raises(InputError, match=message):
        perturb_sequence(seq, kind, sigma, 0)


def test_unseeded_is_refused(seq):
    with pytest.raises(InputError, match="seed"):
        perturb_sequence(seq, "T", 0.01, None)


def _data(tmp_path):
    specs = [("s1", "mug", "lift"), ("s1", "cup", "pass"), ("s2", "mug", "use")]
    src = tmp_path / "src"
    write_dataset(src, specs, T=8, splits={"train": ["cup"], "val": [], "test": ["mug"]})
    return src


def test_perturb_dataset_writes_test_split(tmp_path):
    src = _data(tmp_path)
    h = dataset_hash(src)
    manifest = perturb_dataset(src, tmp_path / "out", "T", 0.02, seed=3)
    out = tmp_path / "out"
    info = json.loads(manifest.read_text())
    assert info["kind"] == "T" and info["sigma"] == 0.02 and info["seed"] == 3
    assert info["protocol"] == "GRAB-T" and info["source_hash"] == h and info["split"] == "test"
    assert info["sequences"] == ["s1/mug_lift_1", "s2/mug_use_1"]
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert files == ["grab/s1/mug_lift_1.npz", "grab/s2/mug_use_1.npz", "manifest.json",
                     "splits.json", "tools/object_meshes/contact_meshes/mug.ply"]
    assert read_splits(out) == read_splits(src)
    clean = read_grab(src / "grab/s2/mug_use_1.npz")
    noisy = read_grab(out / "grab/s2/mug_use_1.npz")
    expect = perturb_sequence(clean, "T", 0.02, sequence_rng(3, clean.name))
    assert np.array_equal(noisy.rhand["transl"], expect.rhand["transl"])
    assert np.array_equal(noisy.body["fullpose"], clean.body["fullpose"])
    assert dataset_hash(src) == h  # the source is untouched
    assert info["source"] == str(src.resolve())


def test_perturbed_bytes_do_not_depend_on_where_the_source_lies(tmp_path):
    """A run names its dataset unit as the source: two copies of one dataset in different
    folders give byte-identical perturbed manifests (a cached unit is the same anywhere)."""
    src = _data(tmp_path)
    copy = tmp_path / "elsewhere" / "src"
    shutil.copytree(src, copy)
    a = perturb_dataset(src, tmp_path / "a", "R", 0.3, seed=1, source="dataset-abc")
    b = perturb_dataset(copy, tmp_path / "b", "R", 0.3, seed=1, source="dataset-abc")
    assert a.read_bytes() == b.read_bytes()
    assert json.loads(a.read_text())["source"] == "dataset-abc"


def test_perturb_dataset_refuses_non_empty_output(tmp_path):
    src = _data(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="not an empty folder"):
        perturb_dataset(src, out, "R", 0.3, seed=0)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "src"]
