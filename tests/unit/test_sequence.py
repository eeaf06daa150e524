"""Sequence: validation messages, row-vector object transform, slicing, contact labels."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from grip_bench.core import constants as C
from grip_bench.core.errors import InputError
from grip_bench.data.sequence import (
    CONTACT_HAND_LABELS,
    contact_label,
    make_body_params,
)
from tests.grab_fixtures import box_mesh, make_sequence


def test_fixture_is_valid_and_has_expected_shapes():
    seq = make_sequence(T=12)
    assert seq.validate() is seq
    assert seq.n_frames == len(seq) == 12
    assert seq.duration == pytest.approx(12 / C.FPS)
    assert seq.body["fullpose"].shape == (12, 165)
    assert seq.hand_params("right") is seq.rhand and seq.hand_params("left") is seq.lhand
    assert seq.rhand["fullpose"].shape == (12, 48)


def test_object_vertices_use_grab_row_vector_convention():
    seq = make_sequence(T=3)
    seq.object["global_orient"][:] = 0
    seq.object["global_orient"][1] = [0, 0, np.pi / 2]  # 90 deg about z
    seq.object["transl"][:] = [1.0, 2.0, 3.0]
    v = np.array([[1.0, 0.0, 0.0]])
    verts = seq.object_vertices(v)
    assert verts.shape == (3, 1, 3)
    np.testing.assert_allclose(verts[0, 0], [2, 2, 3], atol=1e-6)
    # v @ Rz(90) = (0, -1, 0): the row-vector convention, NOT R @ v = (0, 1, 0)
    np.testing.assert_allclose(verts[1, 0], [1, 1, 3], atol=1e-6)


def test_object_vertices_match_a_per_frame_loop():
    seq = make_sequence(T=5, seed=3)
    v = np.asarray(box_mesh().vertices)
    verts = seq.object_vertices(v)
    for t in range(5):
        R = Rotation.from_rotvec(seq.object["global_orient"][t].astype(float)).as_matrix()
        np.testing.assert_allclose(verts[t], v @ R + seq.object["transl"][t], atol=1e-6)


def test_object_vertices_rejects_bad_template():
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        make_sequence(T=2).object_vertices(np.zeros((4, 2)))


def _set(seq, part, key, value):
    getattr(seq, part)[key] = value


@pytest.mark.parametrize(
    "mutate, key, message",
    [
        (
            lambda s: _set(s, "rhand", "transl", np.zeros((10, 2), np.float32)),
            "rhand.params.transl",
            r"should be \(T, 3\)",
        ),
        (
            lambda s: _set(s, "body", "body_pose", np.zeros((9, 63), np.float32)),
            "body.params.body_pose",
            "9 frames",
        ),
        (
            lambda s: s.lhand["hand_pose"].__setitem__((3, 4), np.nan),
            "lhand.params.hand_pose",
            "non-finite .*frame 3",
        ),
        (
            lambda s: s.object["transl"].__setitem__((0, 1), 800.0),
            "object.params.transl",
            "millimetres",
        ),
        (
            lambda s: s.rhand["global_orient"].__setitem__((2, 0), 90.0),
            "rhand.params.global_orient",
            "degrees",
        ),
        (
            lambda s: _set(s, "table", "transl", np.zeros((10, 3), np.int64)),
            "table.params.transl",
            "floating point",
        ),
        (lambda s: s.body.pop("expression"), "body.params.expression", "missing"),
        (lambda s: setattr(s, "fps", 120.0), "framerate", "should be 30"),
        (lambda s: setattr(s, "gender", "x"), "gender", "one of"),
        (lambda s: setattr(s, "body_model", "mano"), "body_model", "one of"),
        (lambda s: setattr(s, "obj_name", "../mug"), "obj_name", "path separators"),
        (lambda s: setattr(s, "height", 175.0), "body.height", "plausible range"),
        (lambda s: s.contact.pop("object"), "contact.object", "missing"),
        (lambda s: s.contact.__setitem__("object", np.zeros((10, 8))), "contact.object", "integer"),
        (
            lambda s: s.contact.__setitem__("object", np.zeros((7, 8), int)),
            "contact.object",
            "7 frames",
        ),
    ],
)
def test_validation_names_file_and_key(mutate, key, message):
    seq = make_sequence(T=10)
    mutate(seq)
    with pytest.raises(InputError, match=message) as e:
        seq.validate(source="f.npz")
    assert e.value.where == f"f.npz: {key}"
    assert "\n" not in str(e.value)


def test_slicing_copies_every_per_frame_array():
    seq = make_sequence(T=20, with_body_contact=True)
    part = seq[5:9]
    assert part.n_frames == 4
    np.testing.assert_array_equal(part.rhand["hand_pose"], seq.rhand["hand_pose"][5:9])
    np.testing.assert_array_equal(part.contact["body"], seq.contact["body"][5:9])
    part.rhand["transl"][:] = 0  # a copy, not a view
    assert np.abs(seq.rhand["transl"][5:9]).sum() > 0
    assert seq.frames(-3).n_frames == 3
    with pytest.raises(ValueError):
        seq[::2]
    with pytest.raises(TypeError):
        seq[3]


def test_contact_labels_follow_grab():
    assert contact_label("pelvis") == 1
    assert contact_label("left_wrist") == 21 and contact_label("right_wrist") == 22
    assert contact_label("right_index1") == 41 and contact_label("right_thumb3") == 55
    assert CONTACT_HAND_LABELS["left"] == {21, *range(26, 41)}
    assert CONTACT_HAND_LABELS["right"] == {22, *range(41, 56)}
    seq = make_sequence(T=20)
    right, left = seq.contact_frames("right"), seq.contact_frames("left")
    assert right.sum() == 10 and left.sum() == 10
    assert seq.contact_frames().sum() == (right | left).sum()


def test_body_fullpose_layout_is_smplx_order():
    rng = np.random.default_rng(0)
    a = {
        k: rng.normal(size=(2, n))
        for k, n in (
            ("go", 3),
            ("bp", 63),
            ("tr", 3),
            ("lh", 45),
            ("rh", 45),
            ("jaw", 3),
            ("le", 3),
            ("re", 3),
        )
    }
    p = make_body_params(a["go"], a["bp"], a["tr"], a["lh"], a["rh"], a["jaw"], a["le"], a["re"])
    full = p["fullpose"]
    assert full.shape == (2, 165)
    np.testing.assert_array_equal(full[:, 0:3], a["go"])
    np.testing.assert_array_equal(full[:, 3:66], a["bp"])
    np.testing.assert_array_equal(full[:, 66:69], a["jaw"])
    np.testing.assert_array_equal(full[:, 75:120], a["lh"])  # joints 25-39: left hand
    np.testing.assert_array_equal(full[:, 120:165], a["rh"])  # joints 40-54: right hand
    assert p["expression"].shape == (2, 10) and not p["expression"].any()


def test_bad_side():
    with pytest.raises(InputError, match="side"):
        make_sequence(T=2).hand_params("middle")


def test_with_hands_replaces_poses_and_keeps_fullposes_consistent():
    from grip_bench.data.sequence import body_fullpose, hand_fullpose
    from tests.grab_fixtures import make_sequence

    seq = make_sequence(T=6)
    pose = np.full((6, 15, 3), 0.1, dtype=seq.rhand["hand_pose"].dtype)
    out = seq.with_hands(right={"hand_pose": pose})
    np.testing.assert_array_equal(out.rhand["hand_pose"], pose.reshape(6, 45))
    np.testing.assert_array_equal(out.body["right_hand_pose"], pose.reshape(6, 45))
    np.testing.assert_array_equal(
        out.rhand["fullpose"], hand_fullpose(out.rhand["global_orient"], out.rhand["hand_pose"])
    )
    np.testing.assert_array_equal(out.body["fullpose"], body_fullpose(out.body))
    np.testing.assert_array_equal(
        out.lhand["hand_pose"], seq.lhand["hand_pose"]
    )  # other side untouched
    assert not np.array_equal(seq.rhand["hand_pose"], out.rhand["hand_pose"])  # input not modified
    out.validate()
