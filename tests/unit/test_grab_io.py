"""GRAB .npz I/O: round trip, plain-GRAB compatibility, subsampling, PCA, hostile files."""

import os
import zipfile

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from grip_bench.core.errors import InputError, MissingModelError, UnsafeFileError
from grip_bench.data.grab_io import (
    data_root_of,
    dataset_hash,
    list_sequences,
    object_mesh_path,
    read_grab,
    read_grab_header,
    resolve_object_mesh,
    write_grab,
)
from grip_bench.data.sequence import BODY_DIMS, HAND_DIMS
from tests.grab_fixtures import (
    FakeMano,
    box_mesh,
    make_sequence,
    real_grab_arrays,
    write_dataset,
    write_npz,
    write_subject_templates,
)


def _assert_same(a, b):
    for part, params in a.parts().items():
        other = b.parts()[part]
        assert params.keys() == other.keys(), part
        for k in params:
            assert params[k].dtype == other[k].dtype, (part, k)
            assert np.array_equal(params[k], other[k]), (part, k)
    assert a.contact.keys() == b.contact.keys()
    for k in a.contact:
        assert np.array_equal(a.contact[k], b.contact[k])
    for f in (
        "sbj_id",
        "gender",
        "obj_name",
        "motion_intent",
        "fps",
        "body_model",
        "height",
        "hand_scale",
        "object_mesh",
        "table_mesh",
        "body_vtemp",
        "rhand_vtemp",
        "lhand_vtemp",
    ):
        assert getattr(a, f) == getattr(b, f), f


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_round_trip_is_bit_exact(tmp_path, dtype):
    seq = make_sequence(T=17, dtype=dtype, with_body_contact=True)
    path = write_grab(seq, tmp_path / "grab" / "s1" / "mug_lift_1.npz")
    back = read_grab(path)
    _assert_same(seq, back)
    assert back.name == "s1/mug_lift_1" and back.source == path
    assert sorted(os.listdir(path.parent)) == ["mug_lift_1.npz"]  # no temp file left


def test_plain_grab_recipe_reads_our_files(tmp_path):
    """A GRAB user's own loader (np.load + .item() + v @ R + t) sees the same object."""
    seq = make_sequence(T=9, seed=5)
    path = write_grab(seq, tmp_path / "seq.npz")
    data = np.load(path, allow_pickle=True)  # the plain GRAB recipe, test-only
    assert set(data.files) == {"gender", "sbj_id", "obj_name", "motion_intent", "framerate",
                               "n_frames", "n_comps", "body", "lhand", "rhand", "object",
                               "table", "contact", "body_model"}
    assert data["framerate"].item() == 30.0 and data["n_comps"].item() == 45
    assert data["n_frames"].item() == 9 and str(data["obj_name"]) == "mug"
    body = data["body"].item()
    assert set(body["params"]) == set(BODY_DIMS)
    assert set(data["rhand"].item()["params"]) == set(HAND_DIMS)
    obj = data["object"].item()
    assert obj["object_mesh"] == "tools/object_meshes/contact_meshes/mug.ply"
    params = obj["params"]
    v = np.asarray(box_mesh().vertices)
    R = Rotation.from_rotvec(params["global_orient"].astype(float)).as_matrix()
    verts = np.matmul(v[None], R) + params["transl"][:, None]
    np.testing.assert_allclose(verts, seq.object_vertices(v), atol=1e-9)
    assert data["contact"].item()["object"].shape == (9, 8)


def test_write_is_atomic(tmp_path, monkeypatch):
    path = write_grab(make_sequence(T=4), tmp_path / "a.npz")
    before = path.read_bytes()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(OSError):
        write_grab(make_sequence(T=5), path)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["a.npz"]


def test_write_refuses_invalid_sequence(tmp_path):
    seq = make_sequence(T=4)
    seq.rhand["transl"][0, 0] = np.inf
    with pytest.raises(InputError, match="rhand.params.transl"):
        write_grab(seq, tmp_path / "x.npz")
    assert not any(tmp_path.iterdir())


def test_real_grab_file_is_subsampled_and_expanded(tmp_path):
    raw = real_grab_arrays(T=41)
    path = write_npz(tmp_path / "grab" / "s1" / "mug_lift.npz", raw)
    mano = FakeMano()
    j0 = write_subject_templates(tmp_path, raw, mano)
    seq = read_grab(path, mano_backend=mano)
    assert seq.fps == 30.0 and seq.n_frames == 11  # frames 0, 4, ..., 40
    assert seq.body_model == "smplx"  # no body_model key: a real GRAB file
    rh = raw["rhand"].item()["params"]
    # GRAB's transl + MANO's rest wrist J0 = the wrist (tests/unit/test_grab_wrist.py)
    np.testing.assert_allclose(seq.rhand["transl"], rh["transl"][::4] + j0["right"], atol=1e-7)
    np.testing.assert_allclose(
        seq.rhand["hand_pose"], mano.expand_pca("right", rh["hand_pose"][::4]), rtol=1e-5, atol=1e-6
    )
    np.testing.assert_allclose(seq.rhand["fullpose"][:, :3], rh["global_orient"][::4])
    np.testing.assert_allclose(seq.rhand["fullpose"][:, 3:], seq.rhand["hand_pose"])
    # GRAB's SMPL-X body hand poses are offsets from the mean hand (smplx default)
    lh_body = raw["body"].item()["params"]["left_hand_pose"][::4]
    np.testing.assert_allclose(seq.body["left_hand_pose"],
                               mano.expand_pca("left", lh_body) + mano.mean["left"], atol=1e-6)
    np.testing.assert_array_equal(
        seq.body["fullpose"], raw["body"].item()["params"]["fullpose"][::4]
    )
    np.testing.assert_array_equal(seq.contact["object"], raw["contact"].item()["object"][::4])
    assert seq.rhand_vtemp == "tools/subject_meshes/male/s1_rhand.ply"
    hdr = read_grab_header(path)
    assert hdr["n_frames"] == 41 and hdr["framerate"] == 120.0 and hdr["step"] == 4


def test_flat_hand_mean_override(tmp_path):
    raw = real_grab_arrays(T=8)
    path = write_npz(tmp_path / "grab" / "s1" / "g.npz", raw)
    mano = FakeMano()
    write_subject_templates(tmp_path, raw, mano)
    default = read_grab(path, mano_backend=mano)  # GRAB: MANO hands flat, body not
    flat = read_grab(path, mano_backend=mano, flat_hand_mean=True)
    meaned = read_grab(path, mano_backend=mano, flat_hand_mean=False)
    np.testing.assert_allclose(meaned.lhand["hand_pose"] - flat.lhand["hand_pose"],
                               np.broadcast_to(mano.mean["left"], (2, 45)), atol=1e-6)
    np.testing.assert_allclose(meaned.lhand["fullpose"][:, 3:], meaned.lhand["hand_pose"])
    np.testing.assert_array_equal(default.lhand["hand_pose"], flat.lhand["hand_pose"])
    np.testing.assert_allclose(default.body["right_hand_pose"] - flat.body["right_hand_pose"],
                               np.broadcast_to(mano.mean["right"], (2, 45)), atol=1e-6)


def test_written_files_are_marked_flat(tmp_path):
    path = write_grab(make_sequence(T=3), tmp_path / "a.npz")
    data = np.load(path, allow_pickle=True)
    assert all(data[p].item()["flat_hand_mean"] is True for p in ("body", "rhand", "lhand"))
    back = read_grab(path, flat_hand_mean=False)  # the marker wins over the override
    np.testing.assert_array_equal(
        back.body["left_hand_pose"], make_sequence(T=3).body["left_hand_pose"]
    )


def test_pca_without_backend_is_a_clear_error(tmp_path):
    path = write_npz(tmp_path / "g.npz", real_grab_arrays(T=8))
    with pytest.raises(MissingModelError, match="PCA") as e:
        read_grab(path)
    assert e.value.where == f"{path}: rhand.params.hand_pose"


def test_full_pose_real_file(tmp_path):
    raw = real_grab_arrays(T=8, n_comps=45, framerate=30.0)
    path = write_npz(tmp_path / "grab" / "s1" / "g.npz", raw)
    with pytest.raises(MissingModelError, match="mean hand") as e:
        read_grab(path)  # the body's hand poses are offsets from the mean: needs MANO
    assert e.value.where == f"{path}: body.params.right_hand_pose"
    with pytest.raises(MissingModelError, match="J0") as e:
        read_grab(path, flat_hand_mean=True)  # GRAB's transl is not the wrist: needs MANO
    assert e.value.where == f"{path}: rhand.params.transl"
    write_subject_templates(tmp_path, raw, FakeMano())
    seq = read_grab(path, flat_hand_mean=True, mano_backend=FakeMano())
    assert seq.n_frames == 8
    np.testing.assert_array_equal(
        seq.rhand["hand_pose"], raw["rhand"].item()["params"]["hand_pose"]
    )


def test_bad_frame_rate(tmp_path):
    path = write_npz(tmp_path / "g.npz", real_grab_arrays(T=8, n_comps=45, framerate=100.0))
    with pytest.raises(InputError, match="multiple") as e:
        read_grab(path)
    assert e.value.where.endswith(": framerate")


class _Evil:
    def __init__(self, target):
        self.target = target

    def __reduce__(self):
        return (os.system, (f"touch {self.target}",))


def test_hostile_pickle_is_refused_and_not_run(tmp_path):
    target = tmp_path / "pwned"
    raw = real_grab_arrays(T=8, n_comps=45, framerate=30.0)
    evil = np.empty((), dtype=object)
    evil[()] = {"params": _Evil(target)}
    raw["object"] = evil
    path = write_npz(tmp_path / "evil.npz", raw)
    with pytest.raises(UnsafeFileError, match="refused") as e:
        read_grab(path)
    assert str(path) in e.value.where and not target.exists()


def _truncate(path, keep=0.5):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def test_truncated_and_not_npz_files(tmp_path):
    path = write_grab(make_sequence(T=6), tmp_path / "t.npz")
    _truncate(path)
    with pytest.raises(InputError) as e:
        read_grab(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)
    (tmp_path / "x.npz").write_text("hello")
    with pytest.raises(InputError, match="not a readable"):
        read_grab(tmp_path / "x.npz")
    with pytest.raises(InputError, match="no such file"):
        read_grab(tmp_path / "missing.npz")


def _rewrite(path, **changes):
    """Re-save a written file with members replaced (None removes one)."""
    with zipfile.ZipFile(path) as zf:
        members = {n[:-4] for n in zf.namelist()}
    data = np.load(path, allow_pickle=True)  # test-only: building malformed fixtures
    arrays = {k: data[k] for k in members}
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v
    return write_npz(path, arrays)


def _with_param(path, part, key, value):
    data = np.load(path, allow_pickle=True)
    entry = data[part].item()
    if value is None:
        entry["params"].pop(key)
    else:
        entry["params"][key] = value
    a = np.empty((), dtype=object)
    a[()] = entry
    return _rewrite(path, **{part: a})


@pytest.mark.parametrize(
    "make_bad, key, message",
    [
        (lambda p: _rewrite(p, contact=None), "contact", "missing key"),
        (lambda p: _rewrite(p, n_frames=np.array("ten")), "n_frames", "number"),
        (lambda p: _rewrite(p, body=np.array([1.0, 2.0])), "body", "dict"),
        (
            lambda p: _with_param(p, "body", "body_pose", None),
            "body.params.body_pose",
            "missing key",
        ),
        (
            lambda p: _with_param(p, "rhand", "transl", np.zeros((6, 2), np.float32)),
            "rhand.params.transl",
            r"\(n_frames=6, 3\)",
        ),
        (
            lambda p: _with_param(p, "rhand", "transl", np.zeros((5, 3), np.float32)),
            "rhand.params.transl",
            "n_frames=6",
        ),
        (
            lambda p: _with_param(p, "lhand", "hand_pose", np.full((6, 45), np.nan, np.float32)),
            "lhand.params.hand_pose",
            "non-finite",
        ),
        (
            lambda p: _with_param(p, "rhand", "hand_pose", np.zeros((6, 30), np.float32)),
            "rhand.params.hand_pose",
            r"\(6, 30\) should be \(n_frames=6, 45\)",
        ),
        (
            lambda p: _with_param(p, "object", "transl", np.full((6, 3), 400.0, np.float32)),
            "object.params.transl",
            "millimetres",
        ),
        (
            lambda p: _with_param(p, "object", "transl", np.array(["a"] * 18).reshape(6, 3)),
            "object.params.transl",
            "numeric",
        ),
    ],
)
def test_malformed_files_name_file_and_key(tmp_path, make_bad, key, message):
    path = write_grab(make_sequence(T=6), tmp_path / "m.npz")
    make_bad(path)
    with pytest.raises(InputError, match=message) as e:
        read_grab(path)
    assert e.value.where == f"{path}: {key}"


def test_list_sequences_and_paths(tmp_path):
    specs = [
        ("s10", "mug", "lift"),
        ("s2", "apple", "pass"),
        ("s2", "camera", "use"),
        ("s1", "mug", "use"),
    ]
    write_dataset(tmp_path, specs, T=5)
    (tmp_path / "grab" / "s1" / "notes.txt").write_text("x")
    names = [p.relative_to(tmp_path / "grab").as_posix() for p in list_sequences(tmp_path)]
    assert names == ["s1/mug_use_1.npz", "s2/apple_pass_1.npz", "s2/camera_use_1.npz",
                     "s10/mug_lift_1.npz"]
    assert (
        object_mesh_path(tmp_path, "mug") == tmp_path / "tools/object_meshes/contact_meshes/mug.ply"
    )
    seq = read_grab(list_sequences(tmp_path)[0])
    assert data_root_of(seq.source) == tmp_path.resolve()
    assert (
        resolve_object_mesh(seq)
        == (tmp_path / "tools/object_meshes/contact_meshes/mug.ply").resolve()
    )
    with pytest.raises(InputError, match="grab/"):
        list_sequences(tmp_path / "grab")


def test_grab_vertex_files_beside_the_sequences_are_skipped(tmp_path, capsys):
    """GRAB's save_grab_vertices.py writes <seq>_verts_*.npz into the s<k>/ folders by
    default: they are not sequences, so listing skips them (with a note) and reading works."""
    write_dataset(tmp_path, [("s1", "mug", "lift"), ("s2", "apple", "pass")], T=5)
    for part in ("body", "object", "rhand", "lhand"):
        np.savez(tmp_path / "grab" / "s1" / f"mug_lift_1_verts_{part}.npz",
                 verts=np.zeros((5, 10, 3), np.float32))
    files = list_sequences(tmp_path)
    assert [p.name for p in files] == ["mug_lift_1.npz", "apple_pass_1.npz"]
    assert "skipped 4 file(s) that are not sequences" in capsys.readouterr().err
    assert all(read_grab(p).n_frames == 5 for p in files)


def test_the_grab_folder_itself_is_refused_with_the_folder_to_pass(tmp_path):
    write_dataset(tmp_path, [("s1", "mug", "lift")], T=5)
    with pytest.raises(InputError, match="pass its parent") as err:
        list_sequences(tmp_path / "grab")
    assert str(tmp_path.resolve()) in err.value.what


def test_dataset_hash_tracks_content_and_names(tmp_path):
    write_dataset(tmp_path, [("s1", "mug", "lift")], T=5)
    h0 = dataset_hash(tmp_path)
    assert h0 == dataset_hash(tmp_path) and len(h0) == 64
    (tmp_path / "manifest.json").write_text("{}")  # excluded: it records the hash
    assert dataset_hash(tmp_path) == h0
    mesh = tmp_path / "tools/object_meshes/contact_meshes/mug.ply"
    mesh.rename(mesh.with_name("cup.ply"))
    h1 = dataset_hash(tmp_path)
    assert h1 != h0
    with open(mesh.with_name("cup.ply"), "ab") as f:
        f.write(b"\n")
    assert dataset_hash(tmp_path) != h1
