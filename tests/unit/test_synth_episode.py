"""SynthGRAB episodes: invariants of the generated motion and of the written GRAB files."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from grip_bench.core import constants as C
from grip_bench.core.frames import SIDES
from grip_bench.data.grab_io import read_grab, write_grab
from grip_bench.data.sequence import CONTACT_HAND_LABELS
from grip_bench.data.synth import episode as E
from grip_bench.data.synth.caches import ObjectTools, hand_models
from grip_bench.data.synth.grasp_plan import hands_clear
from grip_bench.data.synth.motion import min_jerk_path
from grip_bench.data.synth.objects import make_instance
from grip_bench.data.synth.scene import object_of
from grip_bench.data.synth.world import make_subjects

SUBJECTS = make_subjects(4, 0)


@pytest.fixture(scope="module")
def cube():
    inst = make_instance("cubemedium", np.random.default_rng(0), 0)
    return inst, ObjectTools(inst)


@pytest.fixture(scope="module")
def lift(cube):
    inst, tools = cube
    return E.make_episode(SUBJECTS[0], inst, "lift", 3, tools)


@pytest.fixture(scope="module")
def bimanual():
    inst = make_instance("boxlarge", np.random.default_rng(0), 0)
    return E.make_episode(SUBJECTS[1], inst, "lift", 5)


@pytest.fixture(params=["lift", "bimanual"])
def episode(request):
    return request.getfixturevalue(request.param)


def _rest(ep):
    s = ep.cast.scene
    return s.obj_R, s.obj_p


def test_object_moves_only_while_held(episode):
    mo = episode.motion
    R0, p0 = _rest(episode)
    free = mo.carrier < 0
    assert free[0] and free[-1]
    assert np.array_equal(mo.obj_p[free], np.broadcast_to(p0, (free.sum(), 3)))
    assert np.array_equal(mo.obj_R[free], np.broadcast_to(R0, (free.sum(), 3, 3)))
    # The object only moves where a hand is in contact (GT hand within 4.5 mm).
    grasp = episode.contacts["right"].grasp | episode.contacts["left"].grasp
    moved = np.abs(np.diff(mo.obj_p, axis=0)).max(1) > 1e-9
    assert not (moved & ~(grasp[1:] & grasp[:-1])).any()


def test_held_object_is_rigid_with_every_holding_wrist(episode):
    mo = episode.motion
    for s in episode.cast.sides:
        m = mo.attached[s]
        assert m.sum() > 30
        R, p = object_of(mo.wrist[s][0][m], mo.wrist[s][1][m], episode.cast.grasps[s])
        np.testing.assert_allclose(R, mo.obj_R[m], atol=1e-6)
        np.testing.assert_allclose(p, mo.obj_p[m], atol=1e-6)


def test_rest_pose_at_start_and_end_and_ik_reached(episode):
    mo = episode.motion
    assert mo.reached.all()
    np.testing.assert_allclose(mo.body_pose[0], mo.body_pose[-1], atol=1e-6)
    # (v2: idle fingers start in one drawn relaxed pose and end in another, E.idle_poses)
    seed = 5 if episode.cast.inst.large else 3  # the fixtures' seeds
    idle = E.idle_poses(hand_models(episode.cast.subject.hand_scale), seed)
    for s in SIDES:
        np.testing.assert_allclose(mo.fingers[s][0], idle[s][0], atol=1e-9)
        np.testing.assert_allclose(mo.fingers[s][-1], idle[s][1], atol=1e-9)
        np.testing.assert_allclose(mo.wrist[s][1][0], mo.wrist[s][1][-1], atol=1e-6)
        # arms hang: the wrist is well below the shoulder and near the hip
        assert mo.wrist[s][1][0][1] < 0.6 * episode.cast.subject.height


def test_hands_stay_above_table_and_penetration_is_bounded(episode):
    for s in SIDES:
        c = episode.contacts[s]
        assert c.table_gap > -E.TABLE_TOLERANCE - 1e-9
        assert (c.penetration[c.grasp] <= 0.004).all()
    assert episode.contacts[episode.cast.sides[0]].grasp.sum() > 30


def test_contact_labels_come_from_hand_ids(episode):
    labels = episode.sequence.contact["object"]
    assert labels.shape == (episode.motion.n_frames, len(episode.mesh.vertices))
    ids = set(np.unique(labels)) - {0}
    assert ids and ids <= set(CONTACT_HAND_LABELS["right"]) | set(CONTACT_HAND_LABELS["left"])
    grasp = episode.contacts["right"].grasp | episode.contacts["left"].grasp
    assert not labels[~grasp].any()


def test_bimanual_hands_hold_together_without_colliding(bimanual):
    hands = hand_models(bimanual.cast.subject.hand_scale)
    g = bimanual.cast.grasps
    assert hands_clear(hands, g["right"], g["left"])
    both = bimanual.motion.attached["right"] & bimanual.motion.attached["left"]
    assert both.sum() >= 30
    assert (bimanual.contacts["right"].grasp & bimanual.contacts["left"].grasp).sum() >= 30


def test_same_seed_same_bytes_and_different_seed_differs(cube, lift):
    inst, tools = cube
    again = E.make_episode(SUBJECTS[0], inst, "lift", 3, tools)
    for part in ("body", "rhand", "lhand", "object", "table"):
        for k, v in getattr(lift.sequence, part).items():
            assert v.tobytes() == getattr(again.sequence, part)[k].tobytes(), (part, k)
    assert lift.sequence.contact["object"].tobytes() == again.sequence.contact["object"].tobytes()
    other = E.make_episode(SUBJECTS[0], inst, "lift", 4, tools)
    assert (
        not np.array_equal(
            other.sequence.object["transl"][:50], lift.sequence.object["transl"][:50]
        )
        or other.sequence.n_frames != lift.sequence.n_frames
    )


def test_plain_grab_recipe_reads_what_synthgrab_wrote(tmp_path, lift):
    path = write_grab(lift.sequence, tmp_path / "s1" / "cubemedium_lift_1.npz")
    ply = tmp_path / "cubemedium.ply"
    ply.write_bytes(lift.mesh.export(file_type="ply"))
    v_template = np.asarray(trimesh.load(ply, process=False).vertices)
    data = np.load(path, allow_pickle=True)
    obj = data["object"].item()["params"]
    R = torch.as_tensor(obj["global_orient"])
    from grip_bench.geometry.rotations import axis_angle_to_matrix

    verts = v_template[None] @ axis_angle_to_matrix(R).numpy() + obj["transl"][:, None]
    np.testing.assert_allclose(verts, lift.sequence.object_vertices(v_template), atol=1e-9)
    # GRAB's object params follow the row-vector convention: compare with the motion's world pose.
    world = np.einsum("tij,nj->tni", lift.motion.obj_R, v_template) + lift.motion.obj_p[:, None]
    np.testing.assert_allclose(verts, world, atol=1e-9)
    back = read_grab(path)
    assert back.n_frames == lift.sequence.n_frames and back.fps == C.FPS
    assert data["contact"].item()["object"].shape[1] == len(v_template)


def test_min_jerk_via_peaks_where_asked():
    p0, p1, via = np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.5, 0.8])
    path = min_jerk_path(p0, p1, 201, via, via_at=0.8)
    k = int(np.argmin(np.abs(path[:, 2] - 0.8)))
    assert abs(path[k, 1] - 0.5) < 0.02
    np.testing.assert_allclose(path[[0, -1]], [p0, p1], atol=1e-12)
