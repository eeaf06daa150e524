"""SynthGRAB regrasps (issue #16): a ``use`` episode whose hand first picks the object up with
another grasp, puts it back down at rest, lets go and then takes the use grasp."""

from __future__ import annotations

import json

import numpy as np
import pytest

from grip_bench.cli.data import grasp_type_counts as info_counts
from grip_bench.data.synth import episode as E
from grip_bench.data.synth.caches import ObjectTools
from grip_bench.data.synth.choreography import use_verb
from grip_bench.data.synth.generate import _pre_hold_near, episode_stats, grasp_type_counts
from grip_bench.data.synth.grasp_plan import (
    REGRASP_LIFT,
    REGRASP_MIN_TURN_DEG,
    make_cast,
    wrist_turn,
)
from grip_bench.data.synth.objects import make_instance
from grip_bench.data.synth.scene import make_scene, object_of
from grip_bench.data.synth.world import make_subjects

SUBJECTS = make_subjects(4, 0)
SEED = 3  # a cup whose use grasp and first grasp are both power grasps (other wrist poses)


@pytest.fixture(scope="module")
def cup():
    inst = make_instance("cup", np.random.default_rng(0), 0)
    return inst, ObjectTools(inst)


@pytest.fixture(scope="module")
def regrasp(cup):
    inst, tools = cup
    return E.make_episode(SUBJECTS[SEED % 4], inst, "use", SEED, tools, regrasp=True)


def _spans(ep):
    side = ep.cast.sides[0]
    return side, E.hold_spans(ep.motion.attached[side])


def test_two_holds_with_the_object_resting_untouched_between(regrasp):
    ep = regrasp
    assert ep.cast.regrasp is not None
    side, spans = _spans(ep)
    assert len(spans) == 2
    (a1, b1), (a2, b2) = spans
    mo, scene = ep.motion, ep.cast.scene
    gap = np.arange(b1, a2)
    assert len(gap) > 10
    # between the holds nobody carries the object and it rests exactly at its rest pose
    assert (mo.carrier[gap] < 0).all()
    assert np.array_equal(mo.obj_p[gap], np.broadcast_to(scene.obj_p, (len(gap), 3)))
    assert np.array_equal(mo.obj_R[gap], np.broadcast_to(scene.obj_R, (len(gap), 3, 3)))
    # the hand lets go: frames where it does not touch the object (GT hand beyond 4.5 mm)
    touch = ep.contacts[side].grasp
    assert (~touch[gap]).sum() > 0.5 * len(gap)
    assert touch[a1:b1].all() and touch[a2:b2].all()
    # ... and backs off a few cm (as drawn, 2 cm up), not back to rest
    names = [p[0] for p in ep.script.phases]
    _, _, off = ep.script.phases[names.index("regrasp_backoff")]
    wrist_p = mo.wrist[side][1]
    back = wrist_p[off] - wrist_p[b1 - 1]
    g = ep.cast.regrasp.grasps[side]
    want = ep.cast.regrasp.backoff * (scene.obj_R @ g.approach) + np.array([0.0, 0.02, 0.0])
    np.testing.assert_allclose(back, want, atol=0.002)  # (the hold ends within 0.2 mm of rest)
    back = np.linalg.norm(back)
    assert 0.02 < back < 0.15
    assert np.linalg.norm(wrist_p[off] - wrist_p[0]) > 2 * back
    # the first grasp lifts the object 5-10 cm (the solved wrist, within a cm) and puts it back
    lift = mo.obj_p[a1:b1, 1].max() - scene.obj_p[1]
    assert REGRASP_LIFT[0] - 0.01 < lift < REGRASP_LIFT[1] + 0.01
    assert np.linalg.norm(mo.obj_p[b1 - 1] - scene.obj_p) < 0.01


def test_each_hold_keeps_its_own_grasp_and_the_two_differ(regrasp):
    ep = regrasp
    side, spans = _spans(ep)
    first, use = ep.cast.regrasp.grasps[side], ep.cast.grasps[side]
    assert first.kind != use.kind or wrist_turn(first, use) >= np.radians(REGRASP_MIN_TURN_DEG)
    mo = ep.motion
    for (a, b), g in zip(spans, (first, use), strict=True):
        R, p = object_of(mo.wrist[side][0][a:b], mo.wrist[side][1][a:b], g)
        np.testing.assert_allclose(R, mo.obj_R[a:b], atol=1e-9)
        np.testing.assert_allclose(p, mo.obj_p[a:b], atol=1e-9)
    # the wrist in the object frame really changes between the holds
    rel = []
    for a, _ in spans:
        Ro, po = mo.obj_R[a + 2], mo.obj_p[a + 2]
        rel.append((Ro.T @ mo.wrist[side][0][a + 2], Ro.T @ (mo.wrist[side][1][a + 2] - po)))
    turn = np.arccos(np.clip((np.trace(rel[0][0].T @ rel[1][0]) - 1) / 2, -1, 1))
    assert turn > np.radians(10) or np.linalg.norm(rel[0][1] - rel[1][1]) > 0.02


def test_quality_gates_hold_and_the_verb_stays_the_use_verb(regrasp, cup):
    ep = regrasp
    inst, _ = cup
    assert ep.cast.verb == use_verb(inst) == ep.sequence.motion_intent
    assert ep.sequence.name.endswith(f"{inst.name}_{use_verb(inst)}_1")
    st = episode_stats(ep)
    assert st["unsupported_moves"] == 0
    side = ep.cast.sides[0]
    h = st["hands"][side]
    assert h["holds"] == 2 and h["pen_max"] <= 0.003
    assert min(c.table_gap for c in ep.contacts.values()) > -E.TABLE_TOLERANCE
    # nowhere on its way round to the use grasp does the hand touch the object
    names = [p[0] for p in ep.script.phases]
    _, a, b = ep.script.phases[names.index("regrasp_backoff") + 1]
    assert not ep.contacts[side].grasp[a:b + 1].any()


def test_same_seed_same_bytes_and_the_use_grasp_is_the_plain_episodes(regrasp, cup):
    inst, tools = cup
    again = E.make_episode(SUBJECTS[SEED % 4], inst, "use", SEED, tools, regrasp=True)
    for key in ("body", "rhand", "lhand", "object"):
        a, b = getattr(regrasp.sequence, key), getattr(again.sequence, key)
        assert all(np.asarray(a[k]).tobytes() == np.asarray(b[k]).tobytes() for k in a), key
    labels = regrasp.sequence.contact["object"]
    assert labels.tobytes() == again.sequence.contact["object"].tobytes()
    # the regrasp draws from streams of its own: the use grasp is the plain episode's
    subject, rng = SUBJECTS[SEED % 4], np.random.default_rng(SEED)
    scene = make_scene(subject, inst, rng, "use")
    plain = make_cast(subject, inst, scene, "use", rng, tools,
                      kind_rng=E.sub_stream(SEED, E.KIND_STREAM))
    assert plain.regrasp is None and plain.rng_seed == regrasp.cast.rng_seed
    side = plain.sides[0]
    g, h = plain.grasps[side], regrasp.cast.grasps[side]
    assert g.kind == h.kind and np.array_equal(g.R, h.R) and np.array_equal(g.t, h.t)


def test_the_draw_is_a_third_of_one_hand_use_episodes_from_its_own_stream():
    small = make_instance("cup", np.random.default_rng(0), 0)
    large = make_instance("boxlarge", np.random.default_rng(0), 0)
    drawn = [E.draws_regrasp(np.random.SeedSequence([0, k, 0]), "use", small)
             for k in range(3000)]
    assert 0.30 < np.mean(drawn) < 0.365
    assert not any(E.draws_regrasp(k, i, small) for k in range(50) for i in ("lift", "pass"))
    assert not any(E.draws_regrasp(k, "use", large) for k in range(50))
    # the draw reads a stream of its own: the main stream and the grasp-type stream do not
    # see it
    ss = np.random.SeedSequence(7)
    main = np.random.default_rng(ss).random(3)
    E.draws_regrasp(ss, "use", small)
    assert np.array_equal(main, np.random.default_rng(ss).random(3))


def test_pre_hold_near_counts_the_approach_before_each_hold():
    near = np.zeros(30, bool)
    near[3:6] = near[8:10] = True  # approach of the first hold [10, 15)
    near[15:17] = True  # release of the first hold
    near[20:22] = True  # approach of the second hold [22, 28)
    near[10:15] = near[22:28] = True
    assert _pre_hold_near(near, [(10, 15), (22, 28)]) == 5 + 2
    assert _pre_hold_near(near, [(10, 15)]) == 5
    assert _pre_hold_near(near, []) == int(near.sum())
    # a hand that stays near from one hold to the next counts the whole gap once
    near[15:22] = True
    assert _pre_hold_near(near, [(10, 15), (22, 28)]) == 5 + 7


def test_both_grasps_of_a_regrasping_hand_are_counted(tmp_path):
    results = [
        {"family": "cup", "grasps": {"right": "power"}, "regrasp": {"right": "tripod"}},
        {"family": "cup", "grasps": {"right": "power"}},
        {"family": "pot", "grasps": {"left": "bimanual", "right": "bimanual"}},
    ]
    want = {"cup": {"power": 2, "tripod": 1}, "pot": {"bimanual": 2}}
    assert grasp_type_counts(results) == want
    files = ["grab/s1/cup_drink_1.npz", "grab/s1/cup_lift_1.npz", "grab/s2/pot_lift_1.npz"]
    seqs = {f: {k: v for k, v in r.items()} for f, r in zip(files, results, strict=True)}
    (tmp_path / "manifest.json").write_text(json.dumps({"sequences": seqs}))
    assert info_counts(tmp_path, files) == want
    assert info_counts(tmp_path, files[1:]) == {"cup": {"power": 1}, "pot": {"bimanual": 2}}
