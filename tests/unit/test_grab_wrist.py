"""Real GRAB's hand transl vs the wrist (docs/real_grab.md), on format-faithful fixtures.

MANO rotates a hand about its rest wrist J0 (13 cm from the origin in these fixture
models), so GRAB's ``transl`` is not the wrist: the reader adds J0, posing subtracts it
again, the writer can give GRAB's convention back. Checked here: GRIP's sensor frames sit
on the posed MANO wrist, ANet-style wrist updates rotate about it, read -> write -> read
is exact, the evaluated meshes did not move, and symlinked GRAB trees find the templates.
"""

from __future__ import annotations

import os
import zipfile

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from grip_bench import sensors as S
from grip_bench.bodies.layouts import SMPLX_INDEX
from grip_bench.core.errors import InputError
from grip_bench.core.safe_pickle import load_npz
from grip_bench.data.grab_io import (
    HAND_TRANSL_KEY,
    REST_WRIST_KEY,
    list_sequences,
    load_mano_backend,
    read_grab,
    read_grab_header,
    write_grab,
)
from grip_bench.data.posing import hand_poser
from tests.grab_fixtures import (
    FakeMano,
    box_mesh,
    real_grab_arrays,
    subject_template,
    write_mano_models,
    write_npz,
    write_subject_templates,
)

smplx = pytest.importorskip("smplx")

SIDES = (("right", "rhand"), ("left", "lhand"))
T_SOURCE = 41  # 120 fps -> 11 frames at 30 fps


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


@pytest.fixture
def grab(tmp_path):
    """A real-GRAB-like tree (120 fps, 24 PCA coefficients, subject templates, object
    mesh) and MANO-layout model files; returns (path, raw members, model dir, J0 per side)."""
    mano = FakeMano()
    models = write_mano_models(tmp_path / "models", mano)
    raw = real_grab_arrays(T=T_SOURCE)
    root = tmp_path / "data"
    path = write_npz(root / "grab" / "s1" / "mug_lift.npz", raw)
    j0 = write_subject_templates(root, raw, mano)
    mesh = root / "tools" / "object_meshes" / "contact_meshes" / "mug.ply"
    mesh.parent.mkdir(parents=True)
    box_mesh().export(mesh)
    return path, raw, models, j0


def _read(path, models):
    return read_grab(path, mano_backend=load_mano_backend(models))


def _mano(models, side, wrist_origin):
    from grip_bench.bodies.smplx_backend import MANOHand

    return MANOHand(side, models, n_comps=45, flat_hand_mean=True, wrist_origin=wrist_origin,
                    v_template=subject_template(FakeMano(), side))


def test_reader_adds_the_rest_wrist(grab):
    path, raw, models, j0 = grab
    assert read_grab_header(path)[HAND_TRANSL_KEY] == "mano"  # unmarked SMPL-X: GRAB's
    seq = _read(path, models)
    for side, part in SIDES:
        assert np.linalg.norm(j0[side]) > 0.1  # the fixture puts J0 far from the origin
        stored = raw[part].item()["params"]["transl"][::4]
        np.testing.assert_allclose(seq.hand_params(side)["transl"], stored + j0[side], atol=1e-7)
        assert seq.hand_params(side)["transl"].dtype == np.float64
    # the stand-in backend and the model files agree on J0
    fake = read_grab(path, mano_backend=FakeMano())
    np.testing.assert_array_equal(fake.rhand["transl"], seq.rhand["transl"])


def test_sensor_frames_sit_on_the_posed_mano_wrist(grab):
    """wrist_frames (Ambient and Proximity placement) == MANO's posed wrist frame, 0.1 mm."""
    path, raw, models, _ = grab
    seq = _read(path, models)
    poser = hand_poser(seq, models)
    for side, part in SIDES:
        verts, joints = poser.pose(side, seq.hand_params(side))
        rot, wrist = S.wrist_frames(seq, side)
        np.testing.assert_allclose(joints[:, 0], wrist, atol=1e-4)
        # GRAB's transl as the wrist (the old reading) was J0 away from it
        old = raw[part].item()["params"]["transl"][::4]
        assert np.linalg.norm(joints[:, 0] - old, axis=1).min() > 0.1
        # the hand in the sensor's hand frame, placed by the sensor's to_world, is MANO's hand
        local = _mano(models, side, wrist_origin=True)
        p = seq.hand_params(side)
        for t in range(seq.n_frames):
            with torch.no_grad():
                hand, _ = local(np.zeros((1, 3)), p["hand_pose"][t:t + 1], np.zeros((1, 3)))
            placed = S.to_world(hand[0].numpy().astype(float), rot[t:t + 1], wrist[t:t + 1])
            np.testing.assert_allclose(placed[0], verts[t], atol=1e-4)
        # the sensor points keep their hand-frame coordinates about MANO's wrist
        amb = S.to_world(S.ambient_points(side), rot, wrist)
        back = np.einsum("tji,tnj->tni", rot, amb - joints[:, None, 0])
        np.testing.assert_allclose(back, np.broadcast_to(S.ambient_points(side), back.shape),
                                   atol=1e-4)


def test_stage_one_sensors_at_the_mano_wrist(grab):
    from grip_bench.data.library import ObjectLibrary

    path, raw, models, _ = grab
    seq = _read(path, models)
    library = ObjectLibrary(path.parents[2])
    poser = hand_poser(seq, models)
    at_mano = {side: (S.wrist_frames(seq, side)[0],
                      poser.pose(side, seq.hand_params(side))[1][:, 0]) for side, _ in SIDES}
    got, want = S.stage_one(library, seq), S.stage_one(library, seq, at_mano)
    np.testing.assert_allclose(got.ambient, want.ambient, atol=1e-3)
    np.testing.assert_allclose(got.mean_dist, want.mean_dist, atol=1e-4)
    old = {side: (S.wrist_frames(seq, side)[0],
                  raw[part].item()["params"]["transl"][::4].astype(float)) for side, part in SIDES}
    assert np.abs(S.stage_one(library, seq, old).mean_dist - want.mean_dist).max() > 0.01


def test_rotating_the_wrist_keeps_the_wrist_joint(grab):
    """ANet's wrist update rotates about the wrist: (delta R, transl) keeps joint 0 fixed."""
    path, _, models, _ = grab
    seq = _read(path, models)
    poser = hand_poser(seq, models)
    delta = Rotation.from_rotvec([0.4, -0.7, 0.2])
    for side, _ in SIDES:
        p = seq.hand_params(side)
        v0, j0 = poser.pose(side, p)
        turned = dict(p, global_orient=(delta * Rotation.from_rotvec(p["global_orient"]))
                      .as_rotvec())
        v1, j1 = poser.pose(side, turned)
        np.testing.assert_allclose(j1[:, 0], j0[:, 0], atol=1e-5)
        np.testing.assert_allclose(v1 - j1[:, :1], delta.apply((v0 - j0[:, :1]).reshape(-1, 3))
                                   .reshape(v0.shape), atol=1e-5)


def test_anet_moved_wrists_move_the_mano_hand_rigidly(grab):
    """grip.pipeline.moved_wrists (the FK wrist's change applied to the hand wrist) moves the
    posed MANO hand rigidly with the body's wrist."""
    from grip_bench.geometry.rotations import matrix_to_axis_angle
    from grip_bench.grip.pipeline import _body_fk, moved_wrists

    path, _, models, _ = grab
    seq = _read(path, models)
    old = np.asarray(seq.body["body_pose"], np.float64)
    new = old.reshape(-1, 21, 3).copy()
    new[:, SMPLX_INDEX["right_elbow"] - 1] += [0.3, 0.2, -0.4]
    new[:, SMPLX_INDEX["left_wrist"] - 1] += [-0.5, 0.1, 0.3]
    new = new.reshape(-1, 63)
    wrists = {side: S.wrist_frames(seq, side) for side, _ in SIDES}
    moved = moved_wrists(seq, old, new, wrists)
    r0, p0, _ = _body_fk(seq, old)
    r1, p1, _ = _body_fk(seq, new)
    poser = hand_poser(seq, models)
    for side, _ in SIDES:
        j = SMPLX_INDEX[f"{side}_wrist"]
        rot, transl = moved[side]
        p = dict(seq.hand_params(side), transl=transl,
                 global_orient=matrix_to_axis_angle(torch.as_tensor(rot)).numpy())
        before = poser.vertices(side, seq.hand_params(side))
        after = poser.vertices(side, p)
        delta = np.einsum("tij,tkj->tik", r1[:, j], r0[:, j])
        rigid = p1[:, None, j] + np.einsum("tij,tnj->tni", delta, before - p0[:, None, j])
        np.testing.assert_allclose(after, rigid, atol=1e-4)


def _same(a, b):
    for part, params in a.parts().items():
        for k, v in params.items():
            w = b.parts()[part][k]
            assert v.dtype == w.dtype and np.array_equal(v, w), (part, k)
    for k, v in a.contact.items():
        assert np.array_equal(v, b.contact[k]), k


def test_read_write_read_is_exact(grab, tmp_path):
    path, raw, models, _ = grab
    backend = load_mano_backend(models)
    seq = read_grab(path, mano_backend=backend)
    # the suite's own files: marked "wrist", read back without any model
    ours = write_grab(seq, path.parent / "ours.npz")
    assert str(load_npz(ours)[HAND_TRANSL_KEY]) == "wrist"
    _same(seq, read_grab(ours))
    # GRAB's convention for GRAB's tools: the original float32 transl bytes come back
    grabs = write_grab(seq, path.parent / "grabs.npz", mano_backend=backend)
    members = load_npz(grabs)
    assert str(members[HAND_TRANSL_KEY]) == "mano"
    for _, part in SIDES:
        stored = members[part]["params"]["transl"]
        assert stored.dtype == np.float32
        np.testing.assert_array_equal(stored, raw[part].item()["params"]["transl"][::4])
        assert members[part][REST_WRIST_KEY].shape == (3,)
    _same(seq, read_grab(grabs))  # the stored J0: no model needed
    _same(seq, read_grab(grabs, mano_backend=backend))
    # and a "wrist" file is never converted again, with or without a model
    _same(read_grab(ours, mano_backend=backend), seq)


def test_evaluated_meshes_did_not_move(grab):
    """Posing (hand_poser) puts the hands where GRAB's semantics did before the change."""
    path, raw, models, _ = grab
    seq = _read(path, models)
    poser = hand_poser(seq, models)
    for side, part in SIDES:
        p = seq.hand_params(side)
        stored = raw[part].item()["params"]["transl"][::4]
        with torch.no_grad():  # what MANOPoser computed before: wrist_origin=False, GRAB transl
            v_old, j_old = _mano(models, side, wrist_origin=False)(
                p["global_orient"], p["hand_pose"], stored)
        v_new, j_new = poser.pose(side, p)
        np.testing.assert_allclose(v_new, v_old.numpy(), atol=1e-6)
        np.testing.assert_allclose(j_new, j_old.numpy(), atol=1e-6)


def test_bad_marker_and_rest_wrist_name_the_key(grab, tmp_path):
    path, raw, models, _ = grab
    bad = write_npz(path.parent / "bad.npz", {**raw, HAND_TRANSL_KEY: np.array("elbow")})
    with pytest.raises(InputError, match="'wrist' or 'mano'") as e:
        read_grab(bad, mano_backend=FakeMano())
    assert e.value.where == f"{bad}: {HAND_TRANSL_KEY}"
    entry = dict(raw["rhand"].item(), **{REST_WRIST_KEY: np.array([0.1, np.nan, 0.0])})
    wrapped = np.empty((), object)
    wrapped[()] = entry
    bad = write_npz(path.parent / "bad2.npz", {**raw, "rhand": wrapped})
    with pytest.raises(InputError, match="3 finite") as e:
        read_grab(bad, mano_backend=FakeMano())
    assert e.value.where == f"{bad}: rhand.{REST_WRIST_KEY}"


def test_missing_template_names_the_file_and_key(grab):
    path, _, models, _ = grab
    os.remove(path.parents[2] / "tools" / "subject_meshes" / "male" / "s1_lhand.ply")
    with pytest.raises(InputError, match="subject hand template not found") as e:
        _read(path, models)
    assert e.value.where == f"{path}: lhand.vtemp"


@pytest.mark.parametrize("linked", ["subject_folder", "subject_meshes", "both"])
def test_symlinked_grab_tree_finds_the_templates(grab, tmp_path, linked):
    """grab/s1 and tools/subject_meshes may be symbolic links to folders elsewhere."""
    path, raw, models, _ = grab
    root = path.parents[2]
    want = _read(path, models)
    store = tmp_path / "store"
    store.mkdir()
    if linked in ("subject_folder", "both"):
        os.replace(root / "grab" / "s1", store / "s1")
        os.symlink(store / "s1", root / "grab" / "s1", target_is_directory=True)
    if linked in ("subject_meshes", "both"):
        os.replace(root / "tools" / "subject_meshes", store / "subject_meshes")
        os.symlink(store / "subject_meshes", root / "tools" / "subject_meshes",
                   target_is_directory=True)
    files = list_sequences(root)
    assert files == [root / "grab" / "s1" / "mug_lift.npz"]
    seq = _read(files[0], models)
    _same(want, seq)
    verts = hand_poser(seq, models).vertices("right", seq.rhand)  # posing finds them too
    assert np.isfinite(verts).all()


def test_procedural_files_carry_no_marker(tmp_path):
    from tests.grab_fixtures import make_sequence

    seq = make_sequence(T=5)
    path = write_grab(seq, tmp_path / "grab" / "s1" / "mug_lift_1.npz")
    with zipfile.ZipFile(path) as zf:
        assert f"{HAND_TRANSL_KEY}.npy" not in zf.namelist()
    assert read_grab_header(path)[HAND_TRANSL_KEY] == "wrist"
    _same(seq, read_grab(path, mano_backend=FakeMano()))  # never converted


def test_the_articulated_hold_test_runs_on_mano_hands(grab):
    """MANO hands (sealed wrist) enter the articulated hold test: the sealed template has the
    posed meshes' vertices, the bodies follow MANO's kinematic tree, and a frame's test runs
    (here the fixture's tube hands do not touch the box, so it falls: not held, no NaN)."""
    from grip_bench.bodies.layouts import MANO_PARENTS
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.metrics.evaluate import EvalOptions, SequencePair, hold_frame, posed_hands
    from grip_bench.metrics.intersection import FailureCounter

    path, _, models, _ = grab
    seq = _read(path, models)
    failures = FailureCounter()
    pair = SequencePair(seq, seq, ObjectLibrary(path.parents[2]),
                        EvalOptions(model_path=str(models), up=(0.0, 0.0, 1.0)), failures)
    pair._grasp.update({f"held:{s}": np.ones(seq.n_frames, bool) for s, _ in SIDES})
    hands = posed_hands(pair, 3)
    assert len(hands) == 2
    for hand, (side, _) in zip(hands, SIDES, strict=True):
        assert len(hand.vertices) == len(pair.poser.hands[side].template_vertices) == 778 + 1
        assert hand.parents == tuple(MANO_PARENTS) and hand.parents[0] == -1
        np.testing.assert_array_equal(hand.vertices, pair.track("pred", side).verts[3])
        assert len(hand.pieces) > 0
    res = hold_frame(pair, 3)
    assert res is not None and not res.held and np.isfinite(res.settle)
    assert failures.count == 0
