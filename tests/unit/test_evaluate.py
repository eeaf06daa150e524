"""Per-sequence evaluation: exact zeros for GT vs itself, known offsets, NaN (never 0) when a
metric cannot be computed, per-frame rows consistent with the sequence values."""

import math

import numpy as np
import pytest

from grip_bench.core.errors import InputError
from grip_bench.data.grab_io import read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.metrics import evaluate as E
from grip_bench.metrics import intersection as I
from grip_bench.metrics.aggregate import dataset_name, perturbation_name
from tests.eval_fixtures import grasp_dataset

FAST = E.EvalOptions(physics=False)
POSE_CONTACT = ["mpjpe", "mpvpe", "cc", "contact_drift", "cdev", "contact_ratio", "accel_err"]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """(library, {family: GT sequence}): a one-handed mug lift and a two-handed cylinder pass."""
    root = tmp_path_factory.mktemp("evaldata")
    files = grasp_dataset(root, T=40)  # lifted from frame 21: 9 held frames after the trim
    seqs = {read_grab(f).obj_name: read_grab(f) for f in files}
    return ObjectLibrary(root), seqs


def _by(rows):
    return {(r.hand, r.metric): r for r in rows}


def test_ground_truth_against_itself_is_exactly_zero(data):
    lib, seqs = data
    for gt in seqs.values():
        # every metric but the articulated hold test's (not asserted here, and its scenes
        # dominate the cost; tests/unit/test_metrics_hold_qs.py checks it)
        ids = tuple(m for m in E.METRICS.names() if not m.startswith("hold_sim"))
        rows, _ = E.evaluate_sequence(
            gt, gt.copy(), lib, options=E.EvalOptions(metrics=ids, max_physics_frames=2)
        )
        got = _by(rows)
        for side in ("right", "left"):
            assert got[side, "mpjpe"].value == 0.0 and got[side, "mpvpe"].value == 0.0
            assert got[side, "accel_err"].value == 0.0
        right = {
            m: got["right", m] for m in ("cc", "contact_drift", "cdev", "contact_ratio",
                                         "contact_ratio_strict", "iv", "sim_stable")
        }
        assert right["cc"].value == 0.0 and right["cc"].n_frames > 0
        assert right["contact_drift"].value == 0.0 and right["contact_drift"].n_frames > 0
        assert right["contact_ratio"].value == 100.0
        assert right["contact_ratio_strict"].value == 100.0  # held frames: thumb + finger by rule
        assert 0.0 <= right["cdev"].value <= 2.0 and right["cdev"].n_frames > 0  # GT: own gap
        assert right["iv"].n_frames > 0 and right["sim_stable"].n_frames == 2
        assert {r.unit for r in rows if r.metric == "iv"} == {"cm3"}


def test_translated_right_hand_measures_exactly_5mm(data):
    lib, seqs = data
    for gt in seqs.values():
        pred = gt.copy()
        pred.rhand["transl"] = pred.rhand["transl"] + 0.005 * np.array([1.0, 2.0, 2.0]) / 3.0
        got = _by(E.evaluate_sequence(pred, gt, lib, metrics=["mpjpe", "mpvpe", "cc"])[0])
        for m in ("mpjpe", "mpvpe", "cc"):
            assert got["right", m].value == pytest.approx(5.0, abs=1e-6)
        assert got["left", "mpjpe"].value == 0.0 and got["left", "mpvpe"].value == 0.0


def test_a_hand_that_never_grasps_gets_nan_not_zero(data):
    lib, seqs = data
    gt = seqs["mug"]  # the left hand stays parked far from the mug
    got = _by(E.evaluate_sequence(gt, gt, lib, options=FAST)[0])
    for m in ("cc", "contact_drift", "iv", "pen_depth", "contact_ratio"):
        assert math.isnan(got["left", m].value) and got["left", m].n_frames == 0


def test_per_frame_rows_average_to_the_sequence_value(data):
    lib, seqs = data
    gt = seqs["cylindermedium"]
    pred = gt.copy()
    pred.lhand["transl"] = pred.lhand["transl"] + np.array([0.0, -0.003, 0.002])
    rows, frames = E.evaluate_sequence(pred, gt, lib, per_frame=True, options=FAST)
    for r in rows:
        vals = [f.value for f in frames if (f.hand, f.metric) == (r.hand, r.metric)]
        finite = [v for v in vals if not math.isnan(v)]
        assert len(finite) == r.n_frames
        if finite:
            assert np.mean(finite) == pytest.approx(r.value, rel=1e-9, abs=1e-12)
    assert all(f.frame is not None for f in frames)


def test_sliding_against_a_turning_object_shows_as_drift(data):
    """A hand fixed in the world while the object turns under it slides: drift > 0."""
    lib, seqs = data
    gt = seqs["mug"]
    pred = gt.copy()
    pred.rhand["transl"] = pred.rhand["transl"] + np.array([0.0, 0.0, 0.004])
    got = _by(E.evaluate_sequence(pred, gt, lib, metrics=["contact_drift"])[0])
    assert got["right", "contact_drift"].value > 0.01  # mm per frame


def test_pushing_the_hand_in_raises_iv_and_penetration(data):
    lib, seqs = data
    gt = seqs["cylindermedium"]
    base = _by(E.evaluate_sequence(gt, gt, lib, metrics=["iv", "pen_depth"])[0])
    pred = gt.copy()
    mesh = lib.mesh(gt.obj_name)
    centre = gt.object_vertices(np.asarray(mesh.bounding_box.centroid)[None])[:, 0]
    wrist = pred.rhand["transl"]
    pred.rhand["transl"] = wrist + 0.004 * (centre - wrist) / np.linalg.norm(
        centre - wrist, axis=1, keepdims=True
    )
    got = _by(E.evaluate_sequence(pred, gt, lib, metrics=["iv", "pen_depth"])[0])
    assert got["right", "iv"].value > base["right", "iv"].value
    assert got["right", "pen_depth"].value > base["right", "pen_depth"].value


def test_iv_early_out_equals_the_boolean(data):
    """Frames skipped because no hand vertex is inside really have zero volume."""
    lib, seqs = data
    gt = seqs["mug"]
    pair = E.SequencePair(gt, gt, lib, FAST, I.FailureCounter())
    t = pair.track("gt", "right")
    faces, mesh = pair.poser.faces("right"), lib.mesh(gt.obj_name)
    fast = E.intersection_volumes(t.local, t.sd, faces, mesh)
    full = I.intersection_volume_batch(t.local, faces, mesh)
    skipped = t.sd.min(axis=1) > 0
    assert skipped.any() and (~skipped).any()
    np.testing.assert_array_equal(fast, full)


def test_iv_on_a_sample_of_grasp_frames(data):
    """max_iv_frames=k: the exact volumes of k evenly spaced grasp frames, nothing else."""
    lib, seqs = data
    gt = seqs["cylindermedium"]
    pred = gt.copy()
    pred.rhand["transl"] = gt.rhand["transl"] + [0.0, -0.006, 0.0]  # pushed down: volume
    full = E.m_iv(E.SequencePair(pred, gt, lib, FAST, I.FailureCounter()), "right")
    opts = E.EvalOptions(physics=False, max_iv_frames=3)
    some = E.m_iv(E.SequencePair(pred, gt, lib, opts, I.FailureCounter()), "right")
    assert len(full.frames) > 3 and len(some.frames) == 3
    assert set(some.frames) <= set(full.frames)
    assert some.frames[0] == full.frames[0] and some.frames[-1] == full.frames[-1]
    lookup = dict(zip(full.frames.tolist(), full.values.tolist(), strict=True))
    np.testing.assert_array_equal(some.values, [lookup[t] for t in some.frames.tolist()])


def test_warped_hand_manifolds_match_fresh_builds(data):
    lib, seqs = data
    gt = seqs["cylindermedium"]
    pair = E.SequencePair(gt, gt, lib, FAST, I.FailureCounter())
    local, faces = pair.track("gt", "left").local, pair.poser.faces("left")
    mesh = lib.mesh(gt.obj_name)
    origin = np.asarray(mesh.vertices).mean(axis=0)
    obj = I.to_manifold(mesh.vertices, mesh.faces, origin)
    posed = I._PosedManifolds(faces, origin)
    for v in local[::3]:
        warped = posed.at(v)
        fresh = I.to_manifold(v, faces, origin)
        assert (warped ^ obj).volume() == pytest.approx(
            (fresh ^ obj).volume(), rel=1e-12, abs=1e-18
        )
    assert posed.perm is not None  # the warp path was really taken


def test_evenly_spaced_frames_and_seeded_physics_frames(data):
    mask = np.zeros(40, bool)
    mask[10:30] = True
    np.testing.assert_array_equal(E.evenly_spaced(mask, 3), [10, 20, 29])  # 9.5 rounds to even
    assert len(E.evenly_spaced(mask, 50)) == 20 and len(E.evenly_spaced(mask, 0)) == 0
    lib, seqs = data
    gt = seqs["mug"]

    def draw(seed, k=3):
        opts = E.EvalOptions(max_physics_frames=k, physics_seed=seed)
        return E.physics_frames(E.SequencePair(gt, gt, lib, opts, I.FailureCounter()), "right")

    held = np.flatnonzero(E.SequencePair(gt, gt, lib, FAST, I.FailureCounter()).held("right"))
    a = draw(0)
    assert len(a) == 3 and set(a) <= set(held) and list(a) == sorted(a)
    np.testing.assert_array_equal(a, draw(0))  # deterministic for a seed
    assert any(not np.array_equal(a, draw(s)) for s in range(1, 6))  # and the seed matters
    np.testing.assert_array_equal(draw(0, k=100), held)  # fewer held frames than k: all


def test_sim_frames_are_a_seeded_draw_among_the_physics_frames(data):
    """The MuJoCo tests' frames: the physics frames themselves unless ``max_sim_frames`` is
    smaller, then that many of them, drawn with the seed (the validity report's budget)."""
    lib, seqs = data
    gt = seqs["mug"]

    def frames(**kw):
        pair = E.SequencePair(gt, gt, lib, E.EvalOptions(**kw), I.FailureCounter())
        return E.physics_frames(pair, "right"), E.sim_frames(pair, "right")

    qs, sim = frames(max_physics_frames=6)
    np.testing.assert_array_equal(qs, sim)  # no sim budget: the same frames
    qs, sim = frames(max_physics_frames=6, max_sim_frames=2)
    assert len(qs) == 6 and len(sim) == 2 and set(sim) <= set(qs) and list(sim) == sorted(sim)
    again = frames(max_physics_frames=6, max_sim_frames=2)
    np.testing.assert_array_equal(sim, again[1])  # deterministic
    assert any(not np.array_equal(sim, frames(max_physics_frames=6, max_sim_frames=2,
                                              physics_seed=s)[1]) for s in range(1, 6))
    np.testing.assert_array_equal(frames(max_physics_frames=6, max_sim_frames=50)[1], qs)
    # the quasi-static check and the articulated test itself (the validity report judges
    # both) run on every physics frame; the support test and the articulated test's
    # friction, grip and direction variants on the sim frames
    pair = E.SequencePair(gt, gt, lib, E.EvalOptions(max_physics_frames=3, max_sim_frames=1),
                          I.FailureCounter())
    qs = E.physics_frames(pair, "right")
    assert len(qs) == 3 and len(E.sim_frames(pair, "right")) == 1
    for m in (E.m_hold_qs, E.m_hold_sim, E.m_hold_sim_disp, E.m_hold_sim_ruled):
        np.testing.assert_array_equal(m(pair, "right").frames, qs)
    variants = (E.m_hold_sim_axes, E.m_sim_stable, E.METRICS.get("hold_sim_mu05").compute,
                E.METRICS.get("hold_sim_weak").compute)
    for m in variants:
        np.testing.assert_array_equal(m(pair, "right").frames, E.sim_frames(pair, "right"))


def test_metric_selection_and_errors(data):
    lib, seqs = data
    gt = seqs["mug"]
    rows, _ = E.evaluate_sequence(gt, gt, lib, metrics=["jitter", "mpjpe"])
    assert [r.metric for r in rows] == ["mpjpe", "jitter"] * 2  # registry order, per hand
    assert "iv" not in E.EvalOptions(iv=False).metric_ids()
    assert not set(E.PHYSICS_METRICS) & set(E.EvalOptions(physics=False).metric_ids())
    with pytest.raises(InputError, match="unknown metric"):
        E.EvalOptions(metrics=("mpjpe", "nope")).metric_ids()
    short = gt.frames(0, 10)
    with pytest.raises(InputError, match="10 frames, but the ground truth"):
        E.evaluate_sequence(short, gt, lib)
    other = gt.copy()
    other.obj_name = "cylindermedium"
    with pytest.raises(InputError, match="object 'cylindermedium'"):
        E.evaluate_sequence(other, gt, lib)


def test_labels_from_manifests(tmp_path):
    assert dataset_name(tmp_path, {"generator": "SynthGRAB", "version": "1"}) == "synthgrab"
    assert dataset_name(tmp_path / "mydata", {}) == "mydata"
    assert perturbation_name({"perturbation": "T0.01"}) == "T0.01"
    assert (
        perturbation_name({"generator": "grip_bench.data.perturb", "kind": "R", "sigma": 0.3})
        == "R0.3"
    )
    assert perturbation_name({}) == "none"


def test_contact_stats_pool_to_the_contact_frequency_of_all_grasp_frames(data, tmp_path):
    from grip_bench.metrics.aggregate import pool_contact_stats, read_npz, write_npz
    from grip_bench.metrics.contact import contact_frequency

    lib, seqs = data
    pred = seqs["mug"].copy()
    pred.rhand["transl"] = pred.rhand["transl"] + np.array([0.0, -0.004, 0.0])  # push it in
    pairs = [(pred, seqs["mug"]), *((gt, gt) for gt in seqs.values())]
    stats, sds, masks = [], {"right": [], "left": []}, {"right": [], "left": []}
    n_held = {"right": 0, "left": 0}
    for p, gt in pairs:
        plain, plain_frames = E.evaluate_sequence(p, gt, lib, options=FAST, per_frame=True)
        got: dict = {}
        rows, frames = E.evaluate_sequence(p, gt, lib, options=FAST, per_frame=True, stats=got)
        assert repr((rows, frames)) == repr(
            (plain, plain_frames)
        )  # the rows do not change (NaN-safe)
        stats.append(got)
        pair = E.SequencePair(p, gt, lib, FAST, I.FailureCounter())
        for side in ("right", "left"):
            sds[side].append(pair.track("pred", side).sd)
            masks[side].append(pair.grasp(side))
            pen = [r.value for r in frames if r.hand == side and r.metric == "pen_depth"]
            assert len(pen) == int(pair.held(side).sum())  # pen_depth and the CDF: held frames
            np.testing.assert_allclose(got[side]["depths"], pen, rtol=1e-12, atol=1e-12)  # mm
            assert int(got[side]["frames"]) == int(pair.grasp(side).sum())
            n_held[side] += int(pair.held(side).sum())
    pooled = pool_contact_stats(stats)
    for side in ("right", "left"):
        freq = contact_frequency(np.concatenate(sds[side]), np.concatenate(masks[side]))
        n = int(pooled[f"{side}_frames"][0])
        assert n == sum(int(m.sum()) for m in masks[side]) > 0
        assert pooled[f"{side}_counts"].dtype == np.int64
        np.testing.assert_allclose(pooled[f"{side}_counts"] / n, freq, rtol=0, atol=1e-12)
        assert len(pooled[f"{side}_depths"]) == n_held[side]
    assert pooled["right_depths"].max() > 0  # the pushed-in hand penetrates
    assert int(stats[0]["left"]["frames"]) == 0 and not stats[0]["left"]["counts"].any()
    a, b = write_npz(tmp_path / "a.npz", pooled), write_npz(tmp_path / "b.npz", pooled)
    assert a.read_bytes() == b.read_bytes()  # deterministic bytes
    back = read_npz(a)
    assert list(back) == list(pooled)
    for k, v in pooled.items():
        np.testing.assert_array_equal(back[k], v)


def test_cached_ground_truth_hands_give_the_same_rows_and_are_read_only(data, tmp_path):
    """gt_cache=True keeps the posed ground truth for the next prediction set: the rows are
    the uncached ones, the kept arrays cannot be written, and a changed file is re-posed."""
    from grip_bench.data.grab_io import write_grab

    lib, seqs = data
    gt = next(iter(seqs.values()))
    pred = gt.copy()
    pred.rhand["transl"] = np.asarray(pred.rhand["transl"]) + np.array([0.003, 0.0, 0.0])
    E._GT_TRACKS.clear()
    plain, _ = E.evaluate_sequence(pred, gt, lib, options=FAST)
    first, _ = E.evaluate_sequence(pred, gt, lib, options=FAST, gt_cache=True)
    kept = dict(E._GT_TRACKS)
    again, _ = E.evaluate_sequence(pred, gt, lib, options=FAST, gt_cache=True)
    def same(rows):  # NaN-aware: repr of every field
        return [tuple(map(repr, vars(r).values())) for r in rows]

    assert same(plain) == same(first) == same(again) and len(kept) == 2  # posed once
    assert next(r.value for r in first if r.metric == "mpjpe") == pytest.approx(3.0)
    assert all(a is b for a, b in zip(kept.values(), E._GT_TRACKS.values(), strict=True))
    track = next(iter(kept.values()))
    with pytest.raises(ValueError):
        track.sd[0, 0] = 1.0
    # the same path with other content is another key: posed again
    moved = gt.copy()
    moved.rhand["transl"] = np.asarray(moved.rhand["transl"]) + np.array([0.0, 0.002, 0.0])
    path = tmp_path / "grab" / "s1" / "x.npz"
    write_grab(moved, path)
    other = read_grab(path)
    E.evaluate_sequence(pred, other, lib, options=FAST, gt_cache=True)
    assert len(E._GT_TRACKS) == 4
    E._GT_TRACKS.clear()


def test_ground_truth_cache_keeps_the_first_tracks_when_a_sweep_exceeds_its_budget(
        data, tmp_path, monkeypatch):
    """A budget below one sweep's tracks: the first tracks are kept and hit on the next sweep
    (least-recently-used eviction would drop each just before its next use), later ones are
    posed anew; the rows equal the uncached ones either way."""
    from grip_bench.data.grab_io import write_grab

    lib, seqs = data
    files = []
    for i, gt in enumerate(seqs.values()):  # own files: the keys hold path and content
        files.append(write_grab(gt, tmp_path / "grab" / "s1" / f"seq{i}.npz"))
    gts = [read_grab(f) for f in files]
    E._GT_TRACKS.clear()
    plain = [E.evaluate_sequence(g, g.copy(), lib, options=FAST)[0] for g in gts]
    E.evaluate_sequence(gts[0], gts[0].copy(), lib, options=FAST, gt_cache=True)
    one_seq = sum(t.nbytes for t in E._GT_TRACKS.values())  # both hands of gts[0]
    E._GT_TRACKS.clear()
    monkeypatch.setattr(E, "GT_CACHE_BYTES", one_seq)

    def same(rows):  # NaN-aware: repr of every field
        return [tuple(map(repr, vars(r).values())) for r in rows]

    sweeps = []
    for _ in range(2):
        sweeps.append([E.evaluate_sequence(read_grab(f), read_grab(f), lib, options=FAST,
                                           gt_cache=True)[0] for f in files])
        kept = dict(E._GT_TRACKS)
        assert len(kept) == 2 and {k[0] for k in kept} == {str(files[0].resolve())}
        if len(sweeps) == 1:
            first = kept
    assert all(a is b for a, b in zip(first.values(), kept.values(), strict=True))
    for rows in sweeps:
        assert [same(r) for r in rows] == [same(r) for r in plain]
    E._GT_TRACKS.clear()


def test_jitter_and_acceleration_error_equal_the_pure_functions_bit_for_bit(data):
    """The evaluation computes the prediction's acceleration once for both metrics: the
    values are exactly ``jitter`` / ``acceleration_error`` of the posed vertices; a sequence
    of 2 frames has neither (NaN, 0 frames)."""
    import importlib

    J = importlib.import_module("grip_bench.metrics.jitter")  # the package exports jitter()

    lib, seqs = data
    gt = seqs["cylindermedium"]
    pred = gt.copy()
    rng = np.random.default_rng(0)
    pred.lhand["transl"] = pred.lhand["transl"] + rng.normal(0, 0.002, (gt.n_frames, 3))
    pair = E.SequencePair(pred, gt, lib, FAST, I.FailureCounter())
    for side in ("right", "left"):
        p, g = pair.track("pred", side).verts, pair.track("gt", side).verts
        jit, acc = E.m_jitter(pair, side), E.m_accel_err(pair, side)
        assert jit.summary()[0] == J.jitter(p, gt.fps)
        np.testing.assert_array_equal(jit.values,
                                      J.acceleration_magnitudes(p, gt.fps).mean(axis=-1))
        np.testing.assert_array_equal(acc.values, J.acceleration_error(p, g, gt.fps))
        naive = np.array([np.mean(np.linalg.norm(
            (p[t + 1] - 2 * p[t] + p[t - 1]) * gt.fps**2
            - (g[t + 1] - 2 * g[t] + g[t - 1]) * gt.fps**2, axis=-1))
            for t in range(1, gt.n_frames - 1)])
        np.testing.assert_allclose(acc.values, naive, rtol=1e-12, atol=1e-12)
    assert E.m_accel_err(pair, "left").summary()[0] > 0.0  # the noisy hand
    short = gt.frames(0, 2)
    rows, _ = E.evaluate_sequence(short, short.copy(), lib, metrics=["jitter", "accel_err"])
    assert all(math.isnan(r.value) and r.n_frames == 0 for r in rows) and len(rows) == 4
