"""Baseline methods end to end on a tiny grasping dataset: train -> checkpoint -> load -> predict.

Tiny widths through the profile dict (the same path as ``--profile``); one thread, since
the test machine's two cores are shared.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from grip_bench.bench.methods import PredictContext, load_all
from grip_bench.checkpoint import load_checkpoint
from grip_bench.data.grab_io import read_grab, write_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.data.perturb import perturb_sequence

TINY = {
    "grabnet": dict(bps_points=64, width=32, hidden=32, latent=4, refine_width=32,
                    epochs_coarse=2, epochs_refine=1, batch_size=32, loss_vertices=32),
    "manipnet": dict(width=32, hidden=32, n_blocks=1, epochs=2, ss_epochs=1, batch_size=32,
                     loss_vertices=32),
    # A barely trained field AE is unsure of every hit; a low threshold still exercises the fit.
    "toch": dict(n_points=96, local_dim=16, frame_dim=32, gru_hidden=32, epochs=3,
                 max_windows=4, window=12, fit_iters=10, hit_threshold=0.05),
    "nearest": dict(n_components=8),
}
METHOD_NAMES = ("grabnet", "grabnet-smplx", "manipnet", "toch", "nearest-neighbour")


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from tests.baseline_fixtures import baseline_dataset

    torch.set_num_threads(1)
    return baseline_dataset(tmp_path_factory.mktemp("baselines") / "data", T=24)


@pytest.fixture(scope="module")
def trained(data, tmp_path_factory):
    """{name: (method object, checkpoint path)}, each trained once."""
    torch.set_num_threads(1)
    methods = load_all()
    out = {}
    for name in METHOD_NAMES:
        m = methods.get(name).build()
        ckpt = m.train(data, tmp_path_factory.mktemp("ckpt") / f"{name}.pt", profile=TINY,
                       seed=0, progress=False)
        m.load(ckpt)
        out[name] = (m, ckpt)
    return out


@pytest.fixture(scope="module")
def test_seq(data):
    return read_grab(data / "grab" / "s2" / "mug_lift_1.npz")


def ctx(data, seed=0):
    return PredictContext(library=ObjectLibrary(data), seed=seed)


def _same(a, b, side, keys=("global_orient", "hand_pose", "transl"), frames=slice(None)):
    for k in keys:
        np.testing.assert_array_equal(a.hand_params(side)[k][frames], b.hand_params(side)[k][frames])


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_checkpoint_is_safe_and_described(trained, name):
    _, ckpt = trained[name]
    raw = torch.load(ckpt, weights_only=True)
    meta = raw["meta"]
    assert meta["method"] == name and meta["trained"] is True
    assert len(meta["data_hash"]) == 64 and meta["train_seconds"] > 0
    assert isinstance(meta["train_config"], dict)


def test_checkpoint_of_another_method_is_refused(trained):
    from grip_bench.errors import InputError

    methods = load_all()
    smplx = methods.get("grabnet-smplx").build()
    with pytest.raises(InputError, match="grabnet"):
        smplx.load(trained["grabnet"][1])


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_prediction_is_a_valid_grab_file(trained, name, test_seq, data, tmp_path):
    m, _ = trained[name]
    inp = perturb_sequence(test_seq, "T", 0.01, 0) if name == "toch" else test_seq
    out = m.predict(inp, ctx(data))
    out.validate()
    assert out.n_frames == inp.n_frames and out.name == inp.name
    back = read_grab(write_grab(out, tmp_path / "grab" / "s2" / "mug_lift_1.npz"))
    for side in ("right", "left"):
        np.testing.assert_allclose(back.hand_params(side)["hand_pose"],
                                   out.hand_params(side)["hand_pose"], atol=1e-6)
    # The body's copy of the hands follows (one consistent file for every reader).
    np.testing.assert_allclose(out.body["right_hand_pose"], out.rhand["hand_pose"], atol=1e-6)


@pytest.mark.parametrize("name", ["grabnet", "grabnet-smplx"])
def test_grabnet_samples_repeat_with_seed_and_differ_across_seeds(trained, name, test_seq, data):
    m, _ = trained[name]
    a, b, c = (m.predict(test_seq, ctx(data, s)).rhand["hand_pose"] for s in (5, 5, 6))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-4


def test_grabnet_writes_grasp_frames_only(trained, test_seq, data):
    from grip_baselines.common import contact_frames

    m, _ = trained["grabnet"]
    library = ObjectLibrary(data)
    out = m.predict(test_seq, ctx(data))
    grasp = contact_frames(library, test_seq, "right")
    assert grasp.any() and (~grasp).any()
    _same(out, test_seq, "right", frames=~grasp)
    _same(out, test_seq, "left")
    changed = np.abs(out.rhand["transl"] - test_seq.rhand["transl"]).max(1) > 0
    np.testing.assert_array_equal(changed, grasp)  # a free wrist is generated per grasp frame
    # The generated wrist sits near the object (within the BPS ball around its centre).
    centre = library.mesh(test_seq.obj_name).centroid
    world_centre = centre @ test_seq.object_rotations()[grasp] + test_seq.object["transl"][grasp]
    assert np.linalg.norm(out.rhand["transl"][grasp] - world_centre, axis=1).max() < 0.3


def test_grabnet_smplx_keeps_the_wrists(trained, test_seq, data):
    m, _ = trained["grabnet-smplx"]
    out = m.predict(test_seq, ctx(data))
    for side in ("right", "left"):
        _same(out, test_seq, side, keys=("global_orient", "transl"))
    assert np.abs(out.rhand["hand_pose"] - test_seq.rhand["hand_pose"]).max() > 1e-3


def test_manipnet_generates_right_fingers_only(trained, test_seq, data):
    m, _ = trained["manipnet"]
    out = m.predict(test_seq, ctx(data))
    _same(out, test_seq, "left")
    _same(out, test_seq, "right", keys=("global_orient", "transl"))
    assert np.abs(out.rhand["hand_pose"] - test_seq.rhand["hand_pose"]).max() > 1e-3
    # Deterministic: no sampling in an autoregressive rollout.
    np.testing.assert_array_equal(out.rhand["hand_pose"], m.predict(test_seq, ctx(data, 9)).rhand["hand_pose"])


def test_toch_refines_interaction_frames_only(trained, test_seq, data):
    from grip_baselines.toch_method import interaction_frames

    m, _ = trained["toch"]
    library = ObjectLibrary(data)
    noisy = perturb_sequence(test_seq, "R", 0.3, 1)
    out = m.predict(noisy, ctx(data))
    for side in ("right", "left"):
        near = interaction_frames(library, noisy, side, noisy.hand_params(side),
                                  m.cfg.interaction_distance)
        _same(out, noisy, side, frames=~near)
    near = interaction_frames(library, noisy, "right", noisy.rhand, m.cfg.interaction_distance)
    assert near.any()
    assert np.abs(out.rhand["hand_pose"][near] - noisy.rhand["hand_pose"][near]).max() > 1e-4


def test_nearest_neighbour_copies_training_poses(trained, test_seq, data):
    m, _ = trained["nearest-neighbour"]
    out = m.predict(test_seq, ctx(data))
    poses = m.index.poses.numpy()
    for pose in out.rhand["hand_pose"]:
        assert np.abs(poses - pose).max(1).min() < 1e-9
    for side in ("right", "left"):
        _same(out, test_seq, side, keys=("global_orient", "transl"))


def test_checkpoints_load_with_key_and_shape_checks(trained):
    from grip_baselines.grabnet import CoarseNetConfig, RefineNetConfig
    from grip_baselines.manipnet import ManipNetConfig
    from grip_baselines.nearest import NearestIndexConfig
    from grip_baselines.toch import TemporalAEConfig

    expected = {
        "grabnet": {"coarse": CoarseNetConfig, "refine": RefineNetConfig},
        "grabnet-smplx": {"coarse": CoarseNetConfig, "refine": RefineNetConfig},
        "manipnet": {"manipnet": ManipNetConfig},
        "toch": {"toch": TemporalAEConfig},
        "nearest-neighbour": {"index": NearestIndexConfig},
    }
    for name, want in expected.items():
        ck = load_checkpoint(trained[name][1], want)
        assert set(ck.models()) == set(want)


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_evaluate_accepts_the_prediction(trained, name, test_seq, data):
    evaluate = pytest.importorskip("grip_bench.metrics.evaluate")
    m, _ = trained[name]
    pred = m.predict(test_seq, ctx(data))
    rows, _ = evaluate.evaluate_sequence(pred, test_seq, ObjectLibrary(data),
                                         metrics=["mpvpe", "iv", "contact_ratio"])
    values = {(r.hand, r.metric): r.value for r in rows}
    assert np.isfinite(values[("right", "iv")]) and np.isfinite(values[("right", "contact_ratio")])
