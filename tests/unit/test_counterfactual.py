"""Counterfactual geometry pairs (data/synth/counterfactual.py): the twin object, the fingers
closed again at A's wrist, a twin's motion shared with A, the rules, the written split."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from grip_bench.core import constants as C
from grip_bench.core.errors import InputError
from grip_bench.core.frames import world_to_object
from grip_bench.data.synth import counterfactual as CF
from grip_bench.data.synth.caches import ObjectTools, hand_models
from grip_bench.data.synth.episode import make_episode
from grip_bench.data.synth.grasp import MAX_PENETRATION
from grip_bench.data.synth.objects import make_instance
from grip_bench.data.synth.world import make_subjects
from grip_bench.geometry.distance import DistanceField

SUBJECTS = make_subjects(4, 0)


@pytest.fixture(scope="module")
def cube():
    inst = make_instance("cubemedium", np.random.default_rng(0), 0)
    return inst, ObjectTools(inst)


@pytest.fixture(scope="module")
def source(cube):
    inst, tools = cube
    return make_episode(SUBJECTS[0], inst, "lift", 3, tools)


@pytest.fixture(scope="module")
def twin(source):
    """The first variant (CF_VARIANTS order) whose twin passes the rules."""
    reasons = []
    for variant in C.CF_VARIANTS:
        try:
            return CF.make_twin(source, variant, "cubemedium_cf1")
        except CF.TwinRejected as err:
            reasons.append(str(err))
    pytest.fail(f"no variant makes a valid twin: {reasons}")


def test_twin_instance_stretches_about_the_pivot_and_keeps_heights():
    inst = make_instance("mug", np.random.default_rng(1), 0)
    v = np.asarray(inst.mesh.vertices)
    pivot = v[np.argmax(v[:, 0])]  # a surface point (the handle's far side)
    tw = CF.twin_instance(inst, pivot, (1.25, 0.8), "mug_cf9")
    w = np.asarray(tw.mesh.vertices)
    np.testing.assert_allclose(w[:, 1], v[:, 1])  # heights: still standing on the table
    np.testing.assert_allclose(w[:, 0] - pivot[0], 1.25 * (v[:, 0] - pivot[0]))
    np.testing.assert_allclose(w[:, 2] - pivot[2], 0.8 * (v[:, 2] - pivot[2]))
    assert tw.rest_height == inst.rest_height and tw.name == "mug_cf9"
    assert tw.family == "mug" and tw.mesh.is_watertight
    assert tw.mesh.volume == pytest.approx(inst.mesh.volume * 1.25 * 0.8, rel=1e-9)
    h0, h1 = inst.handles[0], tw.handles[0]
    np.testing.assert_allclose(
        np.asarray(h1.point) - pivot, (np.asarray(h0.point) - pivot) * [1.25, 1.0, 0.8])
    assert np.linalg.norm(h1.axis) == pytest.approx(1.0)
    assert tw.params["cf_scale_x"] == 1.25 and inst.mesh is not tw.mesh
    with pytest.raises(InputError):
        CF.twin_instance(inst, pivot, (0.0, 1.0), "bad")


def test_reclosing_on_the_same_object_gives_the_same_fingers(cube, source):
    _, tools = cube
    (side, g), = source.cast.grasps.items()
    hand = hand_models(SUBJECTS[0].hand_scale)[side]
    again = CF.reclose(tools, hand, g, SUBJECTS[0].hand_scale)
    np.testing.assert_allclose(again.hand_pose, g.hand_pose, atol=1e-12)
    np.testing.assert_array_equal(again.R, g.R)
    np.testing.assert_array_equal(again.t, g.t)


def test_twin_shares_body_wrists_and_object_motion(source, twin):
    a, b = source.sequence, twin.sequence
    assert a.n_frames == b.n_frames and b.obj_name == "cubemedium_cf1"
    for part in ("body", "object", "table"):
        for key, arr in getattr(a, part).items():
            if key == "fullpose":  # its last 90 columns are the two hands' finger poses
                arr, other = arr[:, :-90], getattr(b, part)[key][:, :-90]
            elif key in ("left_hand_pose", "right_hand_pose"):
                continue
            else:
                other = getattr(b, part)[key]
            np.testing.assert_array_equal(other, arr, err_msg=f"{part}.{key}")
    for s in ("right", "left"):
        pa, pb = a.hand_params(s), b.hand_params(s)
        np.testing.assert_array_equal(pa["global_orient"], pb["global_orient"])
        np.testing.assert_array_equal(pa["transl"], pb["transl"])
    side = twin.side
    fa = a.hand_params(side)["hand_pose"]
    fb = b.hand_params(side)["hand_pose"]
    held = source.motion.attached[side]
    assert held.any()
    assert np.abs(fb[held] - fa[held]).max() > 0.01  # the fingers answer the shape
    np.testing.assert_array_equal(fb[0], fa[0])  # relaxed before the reach
    other = "left" if side == "right" else "right"
    np.testing.assert_array_equal(a.hand_params(other)["hand_pose"],
                                  b.hand_params(other)["hand_pose"])
    assert twin.max_change >= C.CF_MIN_CHANGE
    n_verts = len(ObjectTools(twin.inst).contact_mesh.vertices)
    assert b.contact["object"].shape == (b.n_frames, n_verts)


def test_twin_hand_holds_the_twin_without_penetrating(source, twin):
    """Measured independently of the generator: the written B hand against the twin mesh."""
    b, side = twin.sequence, twin.side
    hand = hand_models(SUBJECTS[0].hand_scale)[side]
    p = b.hand_params(side)
    with torch.no_grad():
        v, _ = hand(torch.as_tensor(p["global_orient"]),
                    torch.as_tensor(p["hand_pose"]).reshape(-1, 15, 3),
                    torch.as_tensor(p["transl"]))
    held = np.flatnonzero(source.motion.attached[side])
    local = world_to_object(v.numpy()[held], b.object_rotations()[held],
                            np.asarray(b.object["transl"])[held])
    sd = DistanceField(twin.inst.mesh).exact_signed_distance(local.reshape(-1, 3))
    sd = sd.reshape(len(held), -1)
    assert sd.min() >= -MAX_PENETRATION - 1e-6
    labels = hand.part_labels
    thumb = (sd[:, labels == 1].min(1) <= C.CONTACT_THRESHOLD)
    finger = np.stack([sd[:, labels == k].min(1) <= C.CONTACT_THRESHOLD
                       for k in range(2, 6)], 1).any(1)
    assert (thumb & finger).all()


def test_no_shape_change_is_rejected_and_twins_are_deterministic(source, twin):
    with pytest.raises(CF.TwinRejected) as err:
        CF.make_twin(source, ("same", 1.0, 1.0), "cubemedium_cf2")
    assert err.value.reason == "no_change"
    again = CF.make_twin(source, (twin.variant, *twin.scale_xz), "cubemedium_cf1")
    for s in ("right", "left"):
        np.testing.assert_array_equal(again.sequence.hand_params(s)["hand_pose"],
                                      twin.sequence.hand_params(s)["hand_pose"])
    np.testing.assert_array_equal(again.sequence.contact["object"], twin.sequence.contact["object"])


def test_twin_motion_refuses_fingers_the_script_does_not_make(source):
    (side, g), = source.cast.grasps.items()
    fingers = dict(source.motion.fingers)
    fingers[side] = fingers[side] + 0.01
    tampered = dataclasses.replace(source, motion=dataclasses.replace(source.motion,
                                                                      fingers=fingers))
    with pytest.raises(RuntimeError, match="finger keys"):
        CF.twin_motion(tampered, side, g.hand_pose, g.hand_pose + 0.1)


def test_source_plan_and_variant_order_are_seeded():
    objs = [make_instance("apple", np.random.default_rng(0), 0),
            make_instance("cup", np.random.default_rng(0), 0)]
    p1 = CF.source_plan(objs, 5, 6, seed=3)
    assert p1 == CF.source_plan(objs, 5, 6, seed=3) and len(p1) == 6
    assert {i.intent for i in p1} <= set(C.CF_INTENTS)
    assert {i.object for i in p1} == {"apple", "cup"}
    assert sorted(CF.variant_order(0, 4)) == sorted(C.CF_VARIANTS)
    assert CF.variant_order(0, 4) == CF.variant_order(0, 4)
    with pytest.raises(InputError):
        CF.source_plan(objs, 5, 2, seed=0, intents=("offhand",))


@pytest.mark.slow
def test_counterfactual_pairs_write_a_scoreable_split(tmp_path):
    from grip_bench.data.splits import read_splits, sequences_in_split
    from grip_bench.report.sensitivity import sanity_gate, score_pairs

    out = tmp_path / "cf"
    doc = CF.counterfactual_pairs(out, "smoke", seed=0, n_sources=3, progress=False)
    again = json.loads((out / "pairs.json").read_text())
    assert again == doc and doc["split"] == C.CF_SPLIT
    c = doc["counts"]
    assert c["pairs"] == len(doc["pairs"]) >= 1
    assert c["twins_tried"] == c["pairs"] + c["twins_rejected"]
    assert len(sequences_in_split(out, "test")) == 2 * c["pairs"]
    names = set(read_splits(out)["test"])
    for p in doc["pairs"]:
        assert (out / p["a"]).is_file() and (out / p["b"]).is_file()
        assert {p["object_a"], p["object_b"]} <= names
    # scored: the references pass the gate; the dataset itself as a prediction is the truth
    rows = score_pairs(out, {"oracle": out})
    assert all(ok for _, ok, _ in sanity_gate(rows))
    np.testing.assert_allclose(rows.loc[rows["method"] == "oracle", "reproduced"], 1.0)


@pytest.mark.slow
def test_counterfactual_pairs_are_the_same_bytes_for_any_worker_count(tmp_path):
    """Sources grouped by object over a spawn pool: every file (the manifest but its wall
    time) is the bytes of the in-process run."""
    from grip_bench.data.grab_io import dataset_hash

    docs, files = {}, {}
    for w in (1, 2):
        out = tmp_path / f"w{w}"
        docs[w] = CF.counterfactual_pairs(out, "smoke", seed=0, n_sources=4, progress=False,
                                          workers=w)
        files[w] = {p.relative_to(out).as_posix(): p.read_bytes()
                    for p in sorted(out.rglob("*")) if p.is_file() and p.name != "manifest.json"}
        man = json.loads((out / "manifest.json").read_text())
        assert man.pop("data_hash") == dataset_hash(out)
        man.pop("wall_time_s")
        files[w]["manifest"] = man
    assert docs[1] == docs[2] and docs[1]["counts"]["pairs"] >= 2
    assert len({p["object_a"] for p in docs[1]["pairs"]}) >= 2  # groups on both workers
    assert files[1] == files[2]
    with pytest.raises(InputError):
        CF.counterfactual_pairs(tmp_path / "bad", "smoke", n_sources=1, workers=0)
