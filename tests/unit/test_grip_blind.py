"""``grip-blind``: GRIP without object geometry (issue #16's probe). Its object input is the
object's pose in the wrist frames; swapping the mesh for another one must change nothing it
reads or predicts, and every existing variant keeps its training key."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from grip_bench.core.errors import InputError
from grip_bench.data.grab_io import list_sequences, object_mesh_path, read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.grip import train as TR
from grip_bench.grip.data import build_split
from grip_bench.grip.method import VARIANTS, GripMethod
from grip_bench.grip.pipeline import GripPipeline, Options
from grip_bench.methods.api import METHODS, PredictContext, TrainContext, load_all
from grip_bench.sensors import object_pose_feature
from tests.grip_fixtures import SPECS, tiny_profile, write_grip_dataset

# every variant's key before the geometry switch existed: its checkpoints and caches
KEYS_BEFORE = {
    "grip": "ambient=distance,proximity=1,consistency=latent,future=10",
    "grip-no-ambient": "ambient=none,proximity=1,consistency=latent,future=10",
    "grip-no-proximity": "ambient=distance,proximity=0,consistency=latent,future=10",
    "grip-voxel-ambient": "ambient=voxel,proximity=1,consistency=latent,future=10",
    "grip-no-consist": "ambient=distance,proximity=1,consistency=none,future=10",
    "grip-output-consist": "ambient=distance,proximity=1,consistency=output,future=10",
    "grip-no-rnet": "ambient=distance,proximity=1,consistency=latent,future=10",
    "grip-future0": "ambient=distance,proximity=1,consistency=latent,future=0",
    "grip-future3": "ambient=distance,proximity=1,consistency=latent,future=3",
    "grip-future5": "ambient=distance,proximity=1,consistency=latent,future=5",
    "grip-future10": "ambient=distance,proximity=1,consistency=latent,future=10",
}
BLIND_KEY = "ambient=none,proximity=0,consistency=latent,future=0,geometry=0"


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def roots(tmp_path_factory):
    """The GRIP fixture data twice: with its box meshes, and with every mesh replaced by a
    sphere of another size (same sequences, so the same body, wrist and object poses)."""
    box = write_grip_dataset(tmp_path_factory.mktemp("box"), T=16)
    ball = tmp_path_factory.mktemp("ball") / "data"
    shutil.copytree(box, ball)
    for obj in {o for _, o, _ in SPECS}:
        trimesh.creation.icosphere(subdivisions=2, radius=0.045).export(object_mesh_path(ball, obj))
    return box, ball


@pytest.fixture(scope="module")
def blind(roots, tmp_path_factory):
    out = tmp_path_factory.mktemp("ckpt") / "blind.pt"
    torch.set_num_threads(1)
    ctx = TrainContext(profile=tiny_profile(), progress=False,
                       feature_cache=out.parent / "features")
    return METHODS.get("grip-blind").build().train(roots[0], out, ctx)


def test_object_pose_feature_matches_transforming_points():
    """Analytic: the feature is where the object frame's origin and axes land in the wrist
    frame, computed here by mapping points object -> world -> wrist one at a time."""
    rng = np.random.default_rng(0)
    T = 5
    obj_rot = Rotation.random(T, random_state=1).as_matrix()  # GRAB's row-vector rotation
    obj_t = rng.normal(size=(T, 3))
    w_rot = Rotation.random(2 * T, random_state=2).as_matrix().reshape(T, 2, 3, 3)
    w_t = rng.normal(size=(T, 2, 3))
    feat = object_pose_feature(obj_rot, obj_t, w_rot, w_t)
    assert feat.shape == (T, 2, 9) and feat.dtype == np.float32
    for t in range(T):
        for h in range(2):
            def in_wrist(p, t=t, h=h):
                world = p @ obj_rot[t] + obj_t[t]  # world = local @ R + t
                return w_rot[t, h].T @ (world - w_t[t, h])

            origin = in_wrist(np.zeros(3))
            axes = [in_wrist(e) - origin for e in np.eye(3)]  # columns of the rotation
            want = np.concatenate([origin, axes[0], axes[1]])
            np.testing.assert_allclose(feat[t, h], want, atol=1e-6)
    # the wrist at the object's pose sees the object at its origin, unrotated
    same = object_pose_feature(obj_rot, obj_t, np.repeat(obj_rot.transpose(0, 2, 1)[:, None], 2, 1),
                               np.repeat(obj_t[:, None], 2, 1))
    np.testing.assert_allclose(same, np.broadcast_to([0, 0, 0, 1, 0, 0, 0, 1, 0], same.shape),
                               atol=1e-6)


def test_existing_keys_unchanged_and_blind_key():
    load_all()
    for name, key in KEYS_BEFORE.items():
        assert METHODS.get(name).build().variant.train_key() == key, name
    m = METHODS.get("grip-blind").build()
    assert m.variant.train_key() == BLIND_KEY and m.train_key() == "grip:" + BLIND_KEY
    assert not m.use_rnet and METHODS.get("grip-blind").variant_of == "grip"
    assert set(VARIANTS) == set(KEYS_BEFORE) | {"grip-blind"}
    cnet = TR.build_configs(tiny_profile()["grip"], m.variant)["cnet"]
    assert (cnet.ambient_dim, cnet.future_dim) == (9, 0)


def test_blind_refuses_geometry_inputs_and_rnet():
    with pytest.raises(InputError, match="without geometry"):
        TR.Variant(geometry=False)  # the ambient sensor left on
    with pytest.raises(InputError, match="without geometry"):
        TR.Variant(geometry=False, ambient="none", proximity=False, future_frames=10)
    with pytest.raises(InputError, match="RNet"):
        GripMethod("x", geometry=False, ambient="none", proximity=False, future_frames=0)
    v = TR.Variant(geometry=False, ambient="none", proximity=False, future_frames=0)
    with pytest.raises(InputError, match="RNet"):
        Options(v)


def test_blind_trains_without_rnet_and_is_deterministic(roots, blind, tmp_path):
    nets, meta = TR.load_grip(blind)
    assert meta["train_key"] == BLIND_KEY and set(meta["curves"]) == {"anet", "cnet"}
    assert meta["curves"]["cnet"]["train"][-1] < meta["curves"]["cnet"]["train"][0]
    assert nets["cnet"].cfg.ambient_dim == 9
    again = METHODS.get("grip-blind").build().train(
        roots[0], tmp_path / "again.pt", TrainContext(profile=tiny_profile(), progress=False))
    a, b = TR.load_grip(blind)[0], TR.load_grip(again)[0]
    for name in ("anet", "cnet"):
        sa, sb = a[name].state_dict(), b[name].state_dict()
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
    with pytest.raises(InputError, match="trained for"):
        GripMethod().load(blind)  # the full model refuses the blind checkpoint


def test_blind_predicts_offline_and_online(roots, blind):
    m = METHODS.get("grip-blind").build()
    m.load(blind)
    lib = ObjectLibrary(roots[0])
    seq = read_grab(list_sequences(roots[0])[0])
    off = m.predict(seq, PredictContext(library=lib))
    on = m.predict(seq, PredictContext(library=lib, online=True))
    for pred in (off, on):
        for part in (pred.rhand, pred.lhand):
            assert part["hand_pose"].shape == seq.rhand["hand_pose"].shape
            assert np.isfinite(part["hand_pose"]).all()
    np.testing.assert_array_equal(off.rhand["hand_pose"], m.predict(
        seq, PredictContext(library=lib)).rhand["hand_pose"])  # deterministic
    head = m.predict(seq.frames(0, 10), PredictContext(library=lib, online=True))
    np.testing.assert_allclose(on.rhand["hand_pose"][:10], head.rhand["hand_pose"], atol=1e-5)


def test_blind_features_and_hands_ignore_the_mesh(roots, blind, tmp_path):
    """Same poses, another mesh: the blind variant's inputs (training batches and inference
    frames) and its hands are identical; the full model's stage-one inputs are not."""
    box, ball = roots
    libs = ObjectLibrary(box), ObjectLibrary(ball)
    m = METHODS.get("grip-blind").build()
    m.load(blind)
    v = m.variant
    fs = [build_split(r, "train", cache_dir=tmp_path / r.name, seed=0) for r in roots]
    assert not np.allclose(fs[0].ambient, fs[1].ambient)  # the meshes do differ
    idx = fs[0].pair_index()
    a, b = TR.cnet_batch(fs[0], idx, v), TR.cnet_batch(fs[1], idx, v)
    for key in ("body", "ambient", "proximity", "future"):
        assert torch.equal(a[key], b[key]), key
    assert not torch.equal(TR.cnet_batch(fs[0], idx, TR.Variant())["ambient"],
                           TR.cnet_batch(fs[1], idx, TR.Variant())["ambient"])
    seq = read_grab(list_sequences(box)[0])
    full = GripPipeline(m.nets, Options(TR.Variant()))
    blind_pipe = GripPipeline(m.nets, Options(v, use_rnet=False))
    bp, wrists = blind_pipe.arms_and_wrists(seq)
    fb = [blind_pipe.cnet_frames(seq, lib, bp, wrists) for lib in libs]
    for key in fb[0]:
        np.testing.assert_array_equal(fb[0][key], fb[1][key])
    ff = [full.cnet_frames(seq, lib, bp, wrists) for lib in libs]
    assert not np.allclose(ff[0]["proximity"], ff[1]["proximity"])
    for online in (False, True):
        ctx = [PredictContext(library=lib, online=online) for lib in libs]
        p0, p1 = (m.predict(seq, c) for c in ctx)
        for part in ("rhand", "lhand"):
            for k in ("hand_pose", "global_orient", "transl"):
                np.testing.assert_array_equal(getattr(p0, part)[k], getattr(p1, part)[k])
    # the object's rigid motion is an input: moving the object changes the hands
    moved = replace(seq, object={**seq.object,
                                 "transl": seq.object["transl"] + np.float32([0.0, 0.05, 0.0])})
    p2 = m.predict(moved, PredictContext(library=libs[0]))
    assert not np.array_equal(p2.rhand["hand_pose"], p0.rhand["hand_pose"])
