"""GRIP's data, training (determinism, resume), pipeline (offline, online, refine), variants."""

import numpy as np
import pytest
import torch

from grip_bench.core.errors import InputError
from grip_bench.data.grab_io import list_sequences, read_grab, write_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.grip import train as TR
from grip_bench.grip.data import build_split
from grip_bench.grip.method import VARIANTS, GripMethod
from grip_bench.methods.api import METHODS, PredictContext, TrainContext, load_all
from grip_bench.profiles import load_profile, validate_profile
from tests.grip_fixtures import tiny_profile


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def root(tiny_grip_root):
    return tiny_grip_root


@pytest.fixture(scope="module")
def trained(tiny_grip_checkpoint):
    return tiny_grip_checkpoint


def _weights(path):
    nets, _ = TR.load_grip(path)
    return {f"{n}.{k}": v for n, m in nets.items() for k, v in m.state_dict().items()}


def test_frame_set_shapes_and_cache(root, tmp_path):
    fs = build_split(root, "train", cache_dir=tmp_path, seed=0)
    n = len(fs)
    assert fs.body.shape == (n, 154) and fs.ambient.shape == (n, 2, 1024)
    assert fs.gt_poses.shape == (n, 2, 15, 6) and fs.arms.shape == (n, 4, 6)
    assert (fs.gt_min_dist[:, 1] < 0.02).any() and (fs.gt_min_dist[:, 1] > 0.1).any()
    assert not np.array_equal(fs.arms, fs.noisy_arms)
    assert len(list(tmp_path.glob("grip-train-*.npz"))) == 1
    again = build_split(root, "train", cache_dir=tmp_path, seed=0)  # from the cache
    np.testing.assert_array_equal(again.ambient, fs.ambient)
    assert fs.future(np.array([0]), 10).shape == (1, 40)


def test_training_reduces_loss_and_is_deterministic(root, trained, tmp_path):
    meta = TR.load_grip(trained)[1]
    curve = meta["curves"]["cnet"]["train"]
    assert curve[-1] < curve[0]
    assert meta["train_key"] == TR.Variant().train_key() and len(meta["data_hash"]) == 64
    again = GripMethod().train(
        root, tmp_path / "again.pt", TrainContext(profile=tiny_profile(), progress=False)
    )
    a, b = _weights(trained), _weights(again)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_variants_share_anet_through_the_feature_cache(root, tmp_path, monkeypatch):
    """A variant's ANet, loaded from the first training's cache, equals one trained afresh."""
    shared_ctx = TrainContext(profile=tiny_profile(), progress=False,
                              feature_cache=tmp_path / "shared")
    first = GripMethod().train(root, tmp_path / "grip.pt", shared_ctx)
    assert len(list((tmp_path / "shared").glob("anet-*.pt"))) == 1
    calls = []
    real_fit = TR.fit
    monkeypatch.setattr(
        TR, "fit", lambda stage, *a: calls.append(stage.name) or real_fit(stage, *a)
    )
    variant = GripMethod("grip-no-consist", consistency="none")
    shared = variant.train(root, tmp_path / "nc.pt", shared_ctx)
    assert calls == ["cnet", "rnet"]  # ANet came from the cache
    alone = variant.train(root, tmp_path / "nc-alone.pt",
                          TrainContext(profile=tiny_profile(), progress=False,
                                       feature_cache=tmp_path / "alone"))
    a, b, c = _weights(first), _weights(shared), _weights(alone)
    assert all(torch.equal(b[k], c[k]) for k in b)  # sharing changes nothing
    anet = [k for k in a if k.startswith("anet.")]
    assert anet and all(torch.equal(a[k], b[k]) for k in anet)
    assert TR.load_grip(shared)[1]["curves"]["anet"] == TR.load_grip(first)[1]["curves"]["anet"]


def test_resume_continues_an_interrupted_training(root, trained, tmp_path, monkeypatch):
    out = tmp_path / "resumed.pt"
    real_fit = TR.fit

    def interrupted(stage, hp, st, seed, epochs, save, progress):
        if stage.name != "cnet":
            return real_fit(stage, hp, st, seed, epochs, save, progress)

        def save_then_stop(state):  # CNet's first epoch is saved, then the run dies
            save(state)
            raise KeyboardInterrupt

        return real_fit(stage, hp, st, seed, epochs, save_then_stop, progress)

    monkeypatch.setattr(TR, "fit", interrupted)
    with pytest.raises(KeyboardInterrupt):
        GripMethod().train(root, out, TrainContext(profile=tiny_profile(), progress=False))
    assert (tmp_path / "resumed.pt.partial").is_file() and not out.exists()
    monkeypatch.setattr(TR, "fit", real_fit)
    GripMethod().train(root, out, TrainContext(profile=tiny_profile(), progress=False))
    assert not (tmp_path / "resumed.pt.partial").exists()
    a, b = _weights(trained), _weights(out)
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_predict_writes_a_valid_grab_file(root, trained, tmp_path):
    m = GripMethod()
    m.load(trained)
    seq = read_grab(list_sequences(root)[0])
    lib = ObjectLibrary(root)
    off = m.predict(seq, PredictContext(library=lib))
    on = m.predict(seq, PredictContext(library=lib, online=True))
    for pred in (off, on):
        assert pred.rhand["hand_pose"].shape == seq.rhand["hand_pose"].shape
        assert (
            np.isfinite(pred.rhand["hand_pose"]).all() and np.isfinite(pred.lhand["transl"]).all()
        )
        np.testing.assert_array_equal(pred.body["right_hand_pose"], pred.rhand["hand_pose"])
    back = read_grab(write_grab(off, tmp_path / "grab" / "s1" / "x.npz"))
    np.testing.assert_allclose(back.rhand["hand_pose"], off.rhand["hand_pose"])
    assert not np.allclose(off.rhand["hand_pose"], on.rhand["hand_pose"])  # the future cue matters


def test_online_uses_only_past_frames(root, trained):
    m = GripMethod()
    m.load(trained)
    seq = read_grab(list_sequences(root)[0])
    lib = ObjectLibrary(root)
    ctx = PredictContext(library=lib, online=True)
    full, head = m.predict(seq, ctx), m.predict(seq.frames(0, 10), ctx)
    np.testing.assert_allclose(full.rhand["hand_pose"][:10], head.rhand["hand_pose"], atol=1e-5)
    np.testing.assert_allclose(full.lhand["transl"][:10], head.lhand["transl"], atol=1e-6)


def test_run_many_batches_anet_across_sequences_without_changing_results(root, trained):
    from grip_bench.grip.pipeline import GripPipeline, Options

    m = GripMethod()
    m.load(trained)
    lib = ObjectLibrary(root)
    seqs = [read_grab(f) for f in list_sequences(root)[:3]]
    seqs[1] = seqs[1].frames(0, 9)  # unequal lengths: shorter sequences drop out of the batch
    pipe = GripPipeline(m.nets, Options(m.variant))
    many = pipe.run_many(seqs, lib)
    for seq, got in zip(seqs, many, strict=True):
        one = pipe.run(seq, lib)
        assert got.n_frames == seq.n_frames
        for part in ("rhand", "lhand"):
            for key in ("hand_pose", "global_orient", "transl"):
                # float32 GEMMs of other batch shapes sum in another order (AMX / AVX512
                # kernels per shape), and ANet's recursion carries that rounding forward: it
                # weighs its previous output (trained on noisy current frames), so the
                # rounding lasts some frames (measured up to 4.9e-5 here)
                np.testing.assert_allclose(
                    getattr(got, part)[key], getattr(one, part)[key], rtol=1e-4, atol=1e-4
                )


@torch.no_grad()
def _naive_hands(nets, variant, seq, lib):
    """GRIP offline, written plainly: eval-mode networks, every decoded frame kept, exact
    proximity on every frame, RNet on every frame behind the interaction mask."""
    from grip_bench.core.frames import NET_SIDES
    from grip_bench.grip.data import arms_6d, body_context, hand_proximity
    from grip_bench.grip.pipeline import moved_wrists, set_arms
    from grip_bench.grip.train import sensor_inputs
    from grip_bench.sensors import future_cue, stage_one, wrist_frames

    t_ = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    noisy = arms_6d(seq.body["body_pose"])
    arms, T = noisy.copy(), seq.n_frames
    for t in range(T - 1):
        fut = np.minimum(np.arange(t + 1, t + 6), T - 1)
        arms[t + 1] = (
            noisy[t + 1] + nets["anet"](t_(arms[t][None]), t_(noisy[fut][None])).arms[0, 1].numpy()
        )
    pose0 = np.asarray(seq.body["body_pose"], np.float64)
    body_pose = set_arms(pose0, arms)
    wrists = moved_wrists(seq, pose0, body_pose, {s: wrist_frames(seq, s) for s in NET_SIDES})
    one = stage_one(lib, seq, wrists, variant.ambient)
    amb, prox = sensor_inputs(one.ambient, one.proximity, variant)
    body, cue = (
        body_context(seq, wrists, body_pose),
        future_cue(one.mean_dist, variant.future_frames),
    )
    poses = np.zeros((T, 2, 15, 6), np.float32)
    for t in range(T - 1):
        p = [t, t + 1]
        res = nets["cnet"](t_(body[p][None]), t_(amb[p][None]), t_(prox[p][None]), t_(cue[[t]]))
        poses[t] = res.poses_t[0].numpy()
        poses[t + 1] = res.poses_t1[0].numpy()  # kept for the last frame only
    hp, dist = hand_proximity(lib, seq, poses, wrists)
    mask = torch.as_tensor(dist.min(axis=2) < 0.02)
    return nets["rnet"](t_(poses), t_(hp), mask=mask).numpy(), mask.numpy()


def test_pipeline_matches_a_naive_reference(root, trained):
    """Folded networks, decoding only the latents kept, and proximity computed only where a
    hand can interact change nothing but float rounding."""
    from grip_bench.geometry.rotations import rotation_6d_to_matrix
    from grip_bench.grip.data import gt_poses_6d
    from grip_bench.grip.pipeline import GripPipeline, Options

    m = GripMethod()
    m.load(trained)
    lib = ObjectLibrary(root)
    seqs = [read_grab(f) for f in list_sequences(root)[:2]]
    got = GripPipeline(m.nets, Options(m.variant)).run_many(seqs, lib)
    for seq, pred in zip(seqs, got, strict=True):
        ref, mask = _naive_hands(m.nets, m.variant, seq, lib)
        assert mask.any() and not mask.all()  # both kinds of frames are exercised
        want = rotation_6d_to_matrix(torch.as_tensor(ref, dtype=torch.float64))
        got = rotation_6d_to_matrix(torch.as_tensor(gt_poses_6d(pred), dtype=torch.float64))
        torch.testing.assert_close(got, want, atol=2e-4, rtol=0)


def test_no_anet_keeps_wrists_and_refine_keeps_far_fingers_close(root, trained):
    m = GripMethod()
    m.load(trained)
    seq = read_grab(list_sequences(root)[0])
    lib = ObjectLibrary(root)
    pred = m.predict(seq, PredictContext(library=lib, use_anet=False))
    np.testing.assert_array_equal(pred.rhand["transl"], seq.rhand["transl"])
    ref = m.predict(seq, PredictContext(library=lib, refine=True))
    assert (
        np.abs(ref.rhand["hand_pose"] - seq.rhand["hand_pose"]).max() < 1.0
    )  # refined, not replaced
    with pytest.raises(InputError, match="future"):
        m.predict(seq, PredictContext(library=lib, future_frames=3))


def test_every_variant_builds_from_its_switch():
    load_all()
    hp = load_profile("smoke")["grip"]
    keys = {}
    for name in VARIANTS:
        method = METHODS.get(name).build()
        assert isinstance(method, GripMethod) and method.name == name
        configs = TR.build_configs(hp, method.variant)
        assert {k: c.build() for k, c in configs.items()}
        keys.setdefault(method.train_key(), []).append(name)
    shared = keys[GripMethod().train_key()]
    assert sorted(shared) == ["grip", "grip-future10", "grip-no-rnet"]
    assert len(keys) == len(VARIANTS) - 2
    assert (
        TR.build_configs(hp, METHODS.get("grip-voxel-ambient").build().variant)["cnet"].ambient_dim
        == 1014
    )
    assert (
        TR.build_configs(hp, METHODS.get("grip-future3").build().variant)["cnet"].future_dim == 12
    )


def test_mismatched_checkpoint_is_refused(trained):
    with pytest.raises(InputError, match="trained for"):
        METHODS.get("grip-future3").build().load(trained)
    with pytest.raises(InputError, match="not found"):
        GripMethod().load(trained.parent / "missing.pt")


def test_profiles_validate_keys(tmp_path):
    for name in ("smoke", "default", "paper"):
        assert load_profile(name)["grip"]["latent"] > 0
    assert load_profile("paper")["grip"]["hidden"] == 2048
    bad = tmp_path / "mine.toml"
    bad.write_text("[grip]\nlatnet = 3\n")
    with pytest.raises(InputError, match="latnet"):
        load_profile(bad)
    with pytest.raises(InputError, match="should be an integer"):
        validate_profile({"grip": {"latent": "x"}}, {"grip": {"latent": 1}}, tmp_path)
    with pytest.raises(InputError, match="unknown profile"):
        load_profile("huge")
