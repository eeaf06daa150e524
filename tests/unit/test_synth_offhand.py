"""SynthGRAB off-hand passes and hand/object-table clearance."""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.core.frames import SIDES
from grip_bench.data.synth import episode as E
from grip_bench.data.synth.caches import ObjectTools, hand_models
from grip_bench.data.synth.contact import object_clearance
from grip_bench.data.synth.grasp import AVOID_CLEARANCE
from grip_bench.data.synth.grasp_plan import hands_clear
from grip_bench.data.synth.objects import make_instance
from grip_bench.data.synth.scene import (
    TABLE_THICKNESS,
    Scene,
    make_scene,
    object_of,
    table_clearance,
)
from grip_bench.data.synth.world import make_subjects

SUBJECTS = make_subjects(4, 0)


def _episode(family: str, seed: int, subject: int = 0):
    inst = make_instance(family, np.random.default_rng(0), 0)
    tools = ObjectTools(inst)
    return E.make_episode(SUBJECTS[subject], inst, "offhand", seed, tools), tools


@pytest.fixture(scope="module")
def flip():
    """A cube taken from above by the off hand, turned over and taken from above by the
    dominant hand."""
    # seed 1: seed 0's episode fails since SynthGRAB 2.3 (the off hand's pinch, opened after
    # the put-down, passes 7 mm into the table; the generator replaces such episodes)
    return _episode("cubemedium", 1)


@pytest.fixture(scope="module")
def split():
    """A flute lying across the subject: each hand takes one end."""
    return _episode("flute", 0)


@pytest.fixture(params=["flip", "split"])
def offhand(request):
    return request.getfixturevalue(request.param)


def test_handover_modes(flip, split):
    assert flip[0].cast.handover.mode == "flip" and split[0].cast.handover.mode == "split"
    ep, tools = flip
    # the cube turned over is the same cube: put back upside down it looks as before
    R = ep.cast.scene.obj_R.T @ ep.cast.end_R
    assert np.allclose(R[1, 1], -1.0) and tools.symmetric(R)
    assert np.array_equal(split[0].cast.end_R, split[0].cast.scene.obj_R)


def test_offhand_grasps_first_then_both_hold_then_dominant_puts_back(offhand):
    ep, _ = offhand
    mo, (N, D) = ep.motion, ep.cast.sides
    assert N == ep.cast.subject.off_hand and D == ep.cast.subject.dominant
    held = np.flatnonzero(mo.carrier >= 0)
    assert SIDES[mo.carrier[held[0]]] == N and SIDES[mo.carrier[held[-1]]] == D
    both = mo.attached[N] & mo.attached[D]
    assert both.sum() >= 10  # both hands hold during the handover
    c = ep.contacts
    assert (c[N].grasp & c[D].grasp & both).sum() >= 10
    assert not (mo.attached[N] & (mo.carrier == SIDES.index(D)) & ~both).any()
    hands = hand_models(ep.cast.subject.hand_scale)
    assert hands_clear(hands, ep.cast.grasps[N], ep.cast.grasps[D], AVOID_CLEARANCE - 1e-4)


def test_offhand_object_rigid_supported_and_at_rest_before_and_after(offhand):
    ep, _ = offhand
    mo = ep.motion
    for s in ep.cast.sides:
        m = mo.attached[s]
        R, p = object_of(mo.wrist[s][0][m], mo.wrist[s][1][m], ep.cast.grasps[s])
        np.testing.assert_allclose(R, mo.obj_R[m], atol=1e-6)
        np.testing.assert_allclose(p, mo.obj_p[m], atol=1e-6)
    free = mo.carrier < 0
    first = np.flatnonzero(~free)[0]
    before, after = free & (np.arange(mo.n_frames) < first), free & (np.arange(mo.n_frames) > first)
    sc = ep.cast.scene
    assert np.array_equal(mo.obj_R[before], np.broadcast_to(sc.obj_R, (before.sum(), 3, 3)))
    assert np.array_equal(mo.obj_R[after], np.broadcast_to(ep.cast.end_R, (after.sum(), 3, 3)))
    assert np.array_equal(mo.obj_p[free], np.broadcast_to(sc.obj_p, (free.sum(), 3)))
    grasp = ep.contacts["right"].grasp | ep.contacts["left"].grasp
    moved = np.abs(np.diff(mo.obj_p, axis=0)).max(1) > 1e-9
    assert not (moved & ~(grasp[1:] & grasp[:-1])).any()


def test_offhand_keeps_hands_and_object_out_of_the_table_and_object(offhand):
    ep, _ = offhand
    scene = ep.cast.scene
    for s in SIDES:
        c = ep.contacts[s]
        assert c.table_gap > -E.TABLE_TOLERANCE
        assert (c.penetration[c.grasp] <= 0.004).all()
    assert object_clearance(ep.motion, ep.cast.inst, scene).min() > -E.TABLE_TOLERANCE
    # at the handover the object is above the table, in front of the chest
    both = ep.motion.attached["right"] & ep.motion.attached["left"]
    assert (ep.motion.obj_p[both, 1] > scene.table_height + ep.cast.inst.rest_height + 0.05).all()


def test_offhand_is_deterministic(flip):
    ep, tools = flip
    again = E.make_episode(SUBJECTS[0], tools.inst, "offhand", 1, tools)
    for part in ("body", "rhand", "lhand", "object"):
        for k, v in getattr(ep.sequence, part).items():
            assert v.tobytes() == getattr(again.sequence, part)[k].tobytes(), (part, k)


def _scene():
    return Scene(None, np.eye(3), np.array([0.0, 1.0, 0.5]), np.eye(3), np.zeros(3), np.zeros(3),
                 np.zeros(3), np.zeros(3), np.zeros(3))


def test_table_clearance_counts_the_slab_not_the_space_under_it():
    sc = _scene()  # top at y = 1, footprint |x| <= 0.6, 0.2 <= z <= 0.8
    pts = np.array([[0.0, 1.02, 0.5],  # 2 cm above the top
                    [0.0, 0.99, 0.5],  # 1 cm into the 3 cm top
                    [0.0, 0.9, 0.5],  # under the table: not in it
                    [0.0, 0.99, 0.205],  # in the slab, 5 mm from its front face
                    [0.0, 0.5, -0.5]])  # nowhere near
    gap = table_clearance(pts[:, None], sc)  # five frames of one point
    np.testing.assert_allclose(gap[:2], [0.02, -0.01], atol=1e-12)
    np.testing.assert_allclose(gap[3], -0.005, atol=1e-12)
    assert gap[2] == np.inf and gap[4] == np.inf
    # from above the top to under the table in one frame: it went through
    through = table_clearance(np.array([[[0.0, 1.01, 0.5]], [[0.0, 0.95, 0.5]]]), sc)
    assert through[1] <= -TABLE_THICKNESS / 2


def test_inspecting_at_a_high_table_stays_above_it():
    """The shortest subject at the highest table: "in front of the chest" lies inside the
    table top."""
    sub = min(make_subjects(10, 0), key=lambda s: s.height)
    inst = make_instance("fryingpan", np.random.default_rng(0), 0)
    tools = ObjectTools(inst)
    seed = max(
        range(40), key=lambda k: make_scene(sub, inst, np.random.default_rng(k)).table_height
    )
    ep = E.make_episode(sub, inst, "use", seed, tools)
    scene = ep.cast.scene
    assert scene.table_height > 1.1 and scene.chest[1] < scene.table_height + 0.05
    assert object_clearance(ep.motion, inst, scene).min() > -E.TABLE_TOLERANCE
    assert min(ep.contacts[s].table_gap for s in SIDES) > -E.TABLE_TOLERANCE
