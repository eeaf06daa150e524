"""SMPL-X / MANO adapters on tiny format-faithful fixture files written here.

The fixtures have the official files' keys and shapes with random values: a MANO
``.pkl`` with chumpy arrays (a stand-in class ``chumpy.ch.Ch``, registered only while
writing) and a scipy sparse joint regressor, and a SMPL-X ``.npz`` with an object member.
Nothing here fetches or needs the licensed models.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse as sp
import torch
import trimesh

from grip_bench.bodies import smplx_backend as sb
from grip_bench.bodies.layouts import MANO_PARENTS, SMPLX_PARENTS
from grip_bench.core.errors import GripBenchError, MissingModelError, UnsafeFileError
from tests.grab_fixtures import tube

smplx = pytest.importorskip("smplx")

ROOT = 4294967295  # the official kintree tables mark the root with uint32 -1


# ------------------------------------------------------------ fixtures
@contextlib.contextmanager
def fake_chumpy():
    """A module ``chumpy.ch`` with a class ``Ch`` holding ``x``, present only inside."""
    pkg, mod = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = np.asarray(x)
            self._dirty_vars = set()  # chumpy objects carry more state than the value

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    mod.Ch, pkg.ch = Ch, mod
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = pkg, mod
    try:
        yield Ch
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]


def cup(n_rings: int = 37, n_around: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """An outward-oriented round cup along -x (open ring at the wrist, x = 0)."""
    return tube(0.03, 0.03, n_rings, n_around)


def mano_data(rng, ch=None) -> dict:
    """A MANO_*.pkl-like dict: keys and shapes of the official file, random values."""
    verts, faces = cup()
    n = len(verts)
    weights = rng.random((n, 16)) ** 4
    weights /= weights.sum(1, keepdims=True)
    reg = np.zeros((16, n))
    for j in range(16):
        reg[j, rng.choice(n, 4, replace=False)] = 0.25
    comps = np.linalg.qr(rng.normal(size=(45, 45)))[0]
    wrap = ch if ch is not None else np.asarray
    return {
        "v_template": verts, "f": faces.astype(np.uint32), "weights": weights,
        "J_regressor": sp.csc_matrix(reg), "J": reg @ verts,
        "kintree_table": np.array([[ROOT, *MANO_PARENTS[1:]], list(range(16))], dtype=np.int64),
        "posedirs": rng.normal(scale=1e-4, size=(n, 3, 135)),
        "shapedirs": wrap(rng.normal(scale=1e-3, size=(n, 3, 10))),
        "hands_components": wrap(comps), "hands_mean": rng.normal(scale=0.1, size=45),
        "hands_coeffs": rng.normal(size=(8, 45)), "bs_style": "lbs", "bs_type": "lrotmin",
    }


@pytest.fixture
def model_dir(tmp_path):
    """A model folder with MANO_RIGHT.pkl (chumpy + sparse) and SMPLX_NEUTRAL.npz."""
    rng = np.random.default_rng(0)
    (tmp_path / "mano").mkdir()
    with fake_chumpy() as Ch:
        data = mano_data(rng, Ch)
        with open(tmp_path / "mano" / "MANO_RIGHT.pkl", "wb") as f:
            pickle.dump(data, f, protocol=2)  # the official files are Python 2 pickles
    (tmp_path / "smplx").mkdir()
    np.savez(tmp_path / "smplx" / "SMPLX_NEUTRAL.npz", **smplx_data(rng))
    return tmp_path


def smplx_data(rng) -> dict:
    """A SMPLX_*.npz-like dict (SMPL-X 1.0 layout: 10 shape + 10 expression directions)."""
    sphere = trimesh.creation.icosphere(subdivisions=2)  # 162 vertices
    verts, faces = sphere.vertices * 0.3, sphere.faces
    n = len(verts)
    weights = rng.random((n, 55)) ** 6
    weights /= weights.sum(1, keepdims=True)
    reg = np.zeros((55, n))
    for j in range(55):
        reg[j, rng.choice(n, 3, replace=False)] = 1 / 3
    return {
        "v_template": verts,
        "f": faces.astype(np.int32),
        "weights": weights,
        "J_regressor": reg,
        "kintree_table": np.array([[ROOT, *SMPLX_PARENTS[1:]], list(range(55))], dtype=np.int64),
        "posedirs": rng.normal(scale=1e-4, size=(n, 3, 486)),
        "shapedirs": rng.normal(scale=1e-3, size=(n, 3, 20)),
        "hands_componentsl": np.linalg.qr(rng.normal(size=(45, 45)))[0],
        "hands_componentsr": np.linalg.qr(rng.normal(size=(45, 45)))[0],
        "hands_meanl": rng.normal(scale=0.1, size=45),
        "hands_meanr": rng.normal(scale=0.1, size=45),
        "lmk_faces_idx": rng.integers(0, len(faces), 51),
        "lmk_bary_coords": np.full((51, 3), 1 / 3),
        "joint2num": np.array({"pelvis": 0}, dtype=object),  # object members exist in the real npz
        "part2num": np.array({"global": 0}, dtype=object),
    }


# ---------------------------------------------------------------- files
def test_missing_model_path_names_the_variable(monkeypatch):
    monkeypatch.delenv(sb.MODEL_PATH_ENV, raising=False)
    with pytest.raises(MissingModelError, match=sb.MODEL_PATH_ENV):
        sb.resolve_model_path(None)


def test_missing_file_names_expected_files_and_source(tmp_path):
    with pytest.raises(MissingModelError) as err:
        sb.MANOHand("left", model_path=tmp_path)
    msg = str(err.value)
    assert "MANO_LEFT.pkl" in msg and "https://mano.is.tue.mpg.de" in msg
    with pytest.raises(MissingModelError, match=r"SMPLX_FEMALE\.npz.*smpl-x\.is\.tue\.mpg\.de"):
        sb.SMPLXBody(tmp_path, gender="female")


def test_env_variable_is_used(model_dir, monkeypatch):
    monkeypatch.setenv(sb.MODEL_PATH_ENV, str(model_dir))
    assert sb.find_model_file(None, "mano", "right") == model_dir / "mano" / "MANO_RIGHT.pkl"


def test_missing_smplx_package_suggests_the_extra(model_dir, monkeypatch):
    monkeypatch.setitem(sys.modules, "smplx", None)
    with pytest.raises(GripBenchError, match=r"grip-bench\[smplx\]"):
        sb.MANOHand("right", model_path=model_dir)


def test_hostile_pickle_is_refused_and_does_not_run(tmp_path):
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return os.system, (f"touch {marker}",)

    (tmp_path / "mano").mkdir()
    data = mano_data(np.random.default_rng(1))
    data["hands_mean"] = Evil()
    with open(tmp_path / "mano" / "MANO_RIGHT.pkl", "wb") as f:
        pickle.dump(data, f, protocol=2)
    with pytest.raises(UnsafeFileError, match="system"):
        sb.MANOHand("right", model_path=tmp_path)
    assert not marker.exists()


def test_missing_key_is_named(tmp_path):
    (tmp_path / "mano").mkdir()
    data = mano_data(np.random.default_rng(2))
    del data["posedirs"]
    with open(tmp_path / "mano" / "MANO_RIGHT.pkl", "wb") as f:
        pickle.dump(data, f, protocol=2)
    with pytest.raises(GripBenchError, match="posedirs"):
        sb.MANOHand("right", model_path=tmp_path)


def test_smplx_never_unpickles_the_user_file(model_dir, monkeypatch):
    """smplx's own pickle.load / np.load never see the user's files."""
    seen = []
    real_load = np.load

    def spy_load(path, *a, **k):
        seen.append(str(path))
        return real_load(path, *a, **k)

    def no_pickle(*a, **k):
        raise AssertionError("smplx unpickled a file")

    monkeypatch.setattr(smplx.body_models.np, "load", spy_load)
    monkeypatch.setattr(smplx.body_models.pickle, "load", no_pickle)
    sb.MANOHand("right", model_path=model_dir)
    sb.SMPLXBody(model_dir)
    assert seen and not any(str(model_dir) in p for p in seen)


# ----------------------------------------------------------------- MANO
def test_mano_forward_shapes_and_tips(model_dir):
    hand = sb.MANOHand("right", model_path=model_dir)
    b = 3
    verts, joints = hand(torch.randn(b, 3) * 0.3, torch.randn(b, 15, 3) * 0.2, torch.randn(b, 3))
    assert verts.shape == (b, 779, 3) and joints.shape == (b, 21, 3)
    assert torch.equal(joints[:, 16:], verts[:, list(sb.MANO_TIP_IDS)])
    assert hand.faces.shape[0] == len(cup()[1]) + 21


def test_mano_sealed_mesh_is_watertight_and_outward(model_dir):
    hand = sb.MANOHand("right", model_path=model_dir)
    verts, _ = hand(torch.tensor([[0.3, -0.2, 0.5]]), torch.zeros(1, 45), torch.zeros(1, 3))
    mesh = hand.mesh(verts[0])
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    assert len(hand.loops) == 1 and len(hand.loops[0]) == 21


def test_seal_faces_closes_every_loop():
    tube = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=12)
    open_faces = tube.faces[np.abs(tube.face_normals[:, 2]) < 0.5]  # drop both caps
    verts = tube.vertices
    sealed, loops = sb.seal_faces(open_faces, len(verts))
    centres = np.array([verts[loop].mean(0) for loop in loops])
    mesh = trimesh.Trimesh(np.concatenate([verts, centres]), sealed, process=False)
    assert len(loops) == 2 and mesh.is_watertight and mesh.volume > 0


def test_mano_pca_matches_full_pose(model_dir):
    full = sb.MANOHand("right", model_path=model_dir)
    pca = sb.MANOHand("right", model_path=model_dir, n_comps=24)
    coeffs = torch.randn(2, 24) * 0.5
    go, tr = torch.randn(2, 3) * 0.2, torch.randn(2, 3)
    v_pca, _ = pca(go, coeffs, tr)
    v_full, _ = full(go, sb.expand_pca(coeffs, pca.components), tr)
    torch.testing.assert_close(v_pca, v_full, atol=1e-5, rtol=0)
    assert torch.allclose(pca.full_hand_pose(coeffs), sb.expand_pca(coeffs, pca.components))


def test_mano_flat_hand_mean_offsets_the_pose(model_dir):
    flat = sb.MANOHand("right", model_path=model_dir, flat_hand_mean=True)
    mean = sb.MANOHand("right", model_path=model_dir, flat_hand_mean=False)
    pose, go, tr = torch.randn(1, 15, 3) * 0.2, torch.zeros(1, 3), torch.zeros(1, 3)
    v_mean, _ = mean(go, pose, tr)
    v_flat, _ = flat(go, mean.full_hand_pose(pose), tr)
    torch.testing.assert_close(v_mean, v_flat, atol=1e-5, rtol=0)


def test_mano_wrist_origin_puts_the_wrist_at_transl(model_dir):
    hand = sb.MANOHand("right", model_path=model_dir, wrist_origin=True)
    tr = torch.randn(2, 3)
    _, joints = hand(torch.randn(2, 3), torch.zeros(2, 45), tr)
    torch.testing.assert_close(joints[:, 0], tr)


def test_mano_rejects_bad_shapes(model_dir):
    hand = sb.MANOHand("right", model_path=model_dir)
    with pytest.raises(GripBenchError, match="hand_pose"):
        hand(torch.zeros(1, 3), torch.zeros(1, 24), torch.zeros(1, 3))
    with pytest.raises(GripBenchError, match="transl"):
        hand(torch.zeros(1, 3), torch.zeros(1, 45), torch.full((1, 3), float("nan")))


# ---------------------------------------------------------------- SMPL-X
def test_smplx_forward_joints_and_rotations(model_dir):
    body = sb.SMPLXBody(model_dir, flat_hand_mean=True)  # zero pose = rest, hands too
    data = np.load(model_dir / "smplx" / "SMPLX_NEUTRAL.npz")  # numeric keys only
    b = 2
    out = body(torch.zeros(b, 3), torch.zeros(b, 21, 3), torch.zeros(b, 3))
    rest = data["J_regressor"] @ data["v_template"]
    assert out.joints.shape == (b, 55, 3) and out.rotations.shape == (b, 55, 3, 3)
    np.testing.assert_allclose(out.joints[0].numpy(), rest, atol=1e-5)
    g = torch.Generator().manual_seed(0)
    out = body(torch.randn(b, 3, generator=g), torch.randn(b, 63, generator=g) * 0.3,
               torch.randn(b, 3, generator=g), torch.randn(b, 45, generator=g) * 0.3)
    # LBS skeletons are rigid: every bone is its rest offset rotated by the parent's frame.
    rest_t = torch.as_tensor(rest, dtype=torch.float32)
    for j in range(1, 55):
        p = SMPLX_PARENTS[j]
        want = out.joints[:, p] + out.rotations[:, p] @ (rest_t[j] - rest_t[p])
        torch.testing.assert_close(out.joints[:, j], want, atol=1e-5, rtol=0)
    r, pos = body.wrist_frame(out, "left")
    assert r.shape == (b, 3, 3) and torch.equal(pos, out.joints[:, 20])


def test_smplx_pca_hands(model_dir):
    body = sb.SMPLXBody(model_dir, n_comps=24)
    out = body(torch.zeros(1, 3), torch.zeros(1, 63), torch.zeros(1, 3),
               torch.randn(1, 24), torch.randn(1, 24))
    assert out.joints.shape == (1, 55, 3) and out.vertices.shape == (1, 162, 3)
