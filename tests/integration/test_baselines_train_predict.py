"""Baseline methods end to end on a tiny grasping dataset: train -> checkpoint -> load -> predict.

Tiny widths through the profile dict (the same path as ``--profile``); one thread, since
the test machine's two cores are shared.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from grip_bench.core.checkpoint import load_checkpoint
from grip_bench.core.errors import InputError
from grip_bench.data.grab_io import read_grab, write_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.data.perturb import perturb_sequence
from grip_bench.data.sequence import Sequence
from grip_bench.methods.api import PredictContext, TrainContext, load_all

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
# The networks each method holds once loaded (attribute names), and their classes.
NETWORKS = {
    "grabnet": {"coarse": "CoarseNet", "refine_net": "RefineNet"},
    "grabnet-smplx": {"coarse": "CoarseNet", "refine_net": "RefineNet"},
    "manipnet": {"net": "ManipNet"},
    "toch": {"net": "TemporalAE"},
    "nearest-neighbour": {"index": "NearestIndex"},
}


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.baseline_fixtures import baseline_dataset

    torch.set_num_threads(1)
    return baseline_dataset(tmp_path_factory.mktemp("baselines") / "data", T=24)


def _record_module_to(monkeypatch: pytest.MonkeyPatch, calls: list[tuple[str, Any]]) -> None:
    """Record ``(module class, requested device)`` of every ``nn.Module.to`` call."""
    original = torch.nn.Module.to

    def to(self: torch.nn.Module, *args: Any, **kwargs: Any) -> torch.nn.Module:
        dev = kwargs.get("device", args[0] if args else None)
        if isinstance(dev, str | torch.device):
            calls.append((type(self).__name__, torch.device(dev)))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(torch.nn.Module, "to", to)


# ``cpu:0`` is the CPU, but a device no code would pick by default: seeing it reach a
# network shows the requested device is plumbed through (a CPU-only machine has no other).
PLUMBED = torch.device("cpu:0")


@pytest.fixture(scope="module")
def trained(data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple]:
    """{name: (method object, checkpoint path, train .to() calls, load .to() calls)}, each
    trained once on the CPU spelled ``cpu:0`` (see PLUMBED) and loaded there."""
    torch.set_num_threads(1)
    methods = load_all()
    out = {}
    for name in METHOD_NAMES:
        m = methods.get(name).build()
        train_calls: list = []
        load_calls: list = []
        with pytest.MonkeyPatch.context() as mp:
            _record_module_to(mp, train_calls)
            ckpt = m.train(data, tmp_path_factory.mktemp("ckpt") / f"{name}.pt",
                           TrainContext(profile=TINY, seed=0, device="cpu:0", progress=False))
        with pytest.MonkeyPatch.context() as mp:
            _record_module_to(mp, load_calls)
            m.load(ckpt, "cpu:0")
        out[name] = (m, ckpt, train_calls, load_calls)
    return out


@pytest.fixture(scope="module")
def test_seq(data: Path) -> Sequence:
    return read_grab(data / "grab" / "s2" / "mug_lift_1.npz")


def ctx(data: Path, seed: int = 0, **kw: Any) -> PredictContext:
    return PredictContext(library=ObjectLibrary(data), seed=seed, data_dir=data, **kw)


def _same(
    a: Sequence,
    b: Sequence,
    side: str,
    keys: tuple[str, ...] = ("global_orient", "hand_pose", "transl"),
    frames: slice | np.ndarray = slice(None),
) -> None:
    for k in keys:
        np.testing.assert_array_equal(
            a.hand_params(side)[k][frames], b.hand_params(side)[k][frames]
        )


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_checkpoint_is_safe_and_described(trained: dict, name: str) -> None:
    ckpt = trained[name][1]
    raw = torch.load(ckpt, weights_only=True)
    meta = raw["meta"]
    assert meta["method"] == name and meta["trained"] is True
    assert len(meta["data_hash"]) == 64 and "train_seconds" not in meta  # same inputs, same bytes
    assert isinstance(meta["train_config"], dict)


def test_checkpoint_of_another_method_is_refused(trained: dict) -> None:
    methods = load_all()
    smplx = methods.get("grabnet-smplx").build()
    with pytest.raises(InputError, match="grabnet"):
        smplx.load(trained["grabnet"][1])


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_prediction_is_a_valid_grab_file(
    trained: dict, name: str, test_seq: Sequence, data: Path, tmp_path: Path
) -> None:
    m = trained[name][0]
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
def test_grabnet_samples_repeat_with_seed_and_differ_across_seeds(
    trained: dict, name: str, test_seq: Sequence, data: Path
) -> None:
    m = trained[name][0]
    a, b, c = (m.predict(test_seq, ctx(data, s)).rhand["hand_pose"] for s in (5, 5, 6))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-4


def test_grabnet_writes_grasp_frames_only(trained: dict, test_seq: Sequence, data: Path) -> None:
    from grip_baselines.common import contact_frames

    m = trained["grabnet"][0]
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


def test_grabnet_follows_given_grasp_frames(
    trained: dict, test_seq: Sequence, data: Path
) -> None:
    """``PredictContext.grasp_frames`` (typed; it was ``ctx.extra["grasp_frames"]``) picks
    the frames GrabNet places grasps at, instead of its own contact test."""
    m = trained["grabnet-smplx"][0]
    T = test_seq.n_frames
    given = {"right": np.arange(T) % 5 == 0, "left": np.zeros(T, bool)}
    out = m.predict(test_seq, ctx(data, grasp_frames=given))
    changed = np.abs(out.rhand["hand_pose"] - test_seq.rhand["hand_pose"]).max(1) > 0
    assert changed[given["right"]].any()
    np.testing.assert_array_equal(changed & ~given["right"], np.zeros(T, bool))
    _same(out, test_seq, "left")


def test_grabnet_smplx_keeps_the_wrists(trained: dict, test_seq: Sequence, data: Path) -> None:
    m = trained["grabnet-smplx"][0]
    out = m.predict(test_seq, ctx(data))
    for side in ("right", "left"):
        _same(out, test_seq, side, keys=("global_orient", "transl"))
    assert np.abs(out.rhand["hand_pose"] - test_seq.rhand["hand_pose"]).max() > 1e-3


def test_manipnet_generates_right_fingers_only(
    trained: dict, test_seq: Sequence, data: Path
) -> None:
    m = trained["manipnet"][0]
    out = m.predict(test_seq, ctx(data))
    _same(out, test_seq, "left")
    _same(out, test_seq, "right", keys=("global_orient", "transl"))
    assert np.abs(out.rhand["hand_pose"] - test_seq.rhand["hand_pose"]).max() > 1e-3
    # Deterministic: no sampling in an autoregressive rollout.
    np.testing.assert_array_equal(
        out.rhand["hand_pose"], m.predict(test_seq, ctx(data, 9)).rhand["hand_pose"]
    )


def test_toch_refines_interaction_frames_only(
    trained: dict, test_seq: Sequence, data: Path
) -> None:
    from grip_baselines.toch_method import interaction_frames

    m = trained["toch"][0]
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


def test_nearest_neighbour_copies_training_poses(
    trained: dict, test_seq: Sequence, data: Path
) -> None:
    m = trained["nearest-neighbour"][0]
    out = m.predict(test_seq, ctx(data))
    poses = m.index.poses.numpy()
    for pose in out.rhand["hand_pose"]:
        assert np.abs(poses - pose).max(1).min() < 1e-9
    for side in ("right", "left"):
        _same(out, test_seq, side, keys=("global_orient", "transl"))


def test_checkpoints_load_with_key_and_shape_checks(trained: dict) -> None:
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
def test_evaluate_accepts_the_prediction(
    trained: dict, name: str, test_seq: Sequence, data: Path
) -> None:
    evaluate = pytest.importorskip("grip_bench.metrics.evaluate")
    m = trained[name][0]
    pred = m.predict(test_seq, ctx(data))
    rows, _ = evaluate.evaluate_sequence(pred, test_seq, ObjectLibrary(data),
                                         metrics=["mpvpe", "iv", "contact_ratio"])
    values = {(r.hand, r.metric): r.value for r in rows}
    assert np.isfinite(values[("right", "iv")]) and np.isfinite(values[("right", "contact_ratio")])


# ----------------------------------------------------------------------------- devices


def _networks(m: Any, name: str) -> dict[str, torch.nn.Module]:
    nets = {attr: getattr(m, attr) for attr in NETWORKS[name]}
    for attr, cls in NETWORKS[name].items():
        assert type(nets[attr]).__name__ == cls, (name, attr)
    return nets


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_cpu_training_leaves_every_network_on_the_cpu(
    trained: dict, name: str, data: Path, tmp_path: Path
) -> None:
    m, ckpt = trained[name][:2]
    for net in _networks(m, name).values():
        tensors = [*net.parameters(), *net.buffers()]
        assert tensors and all(t.device == torch.device("cpu") for t in tensors)
    # loading with the plain "cpu" spelling as well
    fresh = load_all().get(name).build()
    fresh.load(ckpt, "cpu")
    for net in _networks(fresh, name).values():
        assert all(t.device == torch.device("cpu") for t in (*net.parameters(), *net.buffers()))


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_requested_device_reaches_every_network(trained: dict, name: str) -> None:
    """Training builds each network on the requested device, and ``load`` moves each
    loaded network there (recorded ``nn.Module.to`` calls, device ``cpu:0``)."""
    _, _, train_calls, load_calls = trained[name]
    for calls, stage in ((train_calls, "train"), (load_calls, "load")):
        moved = {cls for cls, dev in calls if dev == PLUMBED}
        for cls in NETWORKS[name].values():
            assert cls in moved, (stage, cls, calls)
        # nothing is sent to a device other than the one asked for
        assert {dev for _, dev in calls} <= {PLUMBED}, (stage, calls)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
@pytest.mark.parametrize("name", [*METHOD_NAMES, "gt", "mean-pose"])
def test_cuda_without_cuda_is_an_input_error(
    trained: dict, name: str, data: Path, tmp_path: Path
) -> None:
    """``--device cuda`` on a machine without CUDA fails in train and load, before any
    work, instead of silently running on the CPU."""
    m = load_all().get(name).build()
    with pytest.raises(InputError, match="CUDA is not available") as err:
        m.train(data, tmp_path / "x.pt", TrainContext(profile=TINY, device="cuda",
                                                      progress=False))
    assert err.value.where == "--device"
    assert not (tmp_path / "x.pt").exists()
    ckpt = trained[name][1] if name in trained else None
    with pytest.raises(InputError, match="CUDA is not available"):
        m.load(ckpt, "cuda")


@pytest.mark.parametrize("name", ["grabnet", "toch", "gt"])
def test_unknown_device_is_an_input_error(trained: dict, name: str, data: Path,
                                          tmp_path: Path) -> None:
    m = load_all().get(name).build()
    with pytest.raises(InputError, match="device"):
        m.train(data, tmp_path / "x.pt", TrainContext(profile=TINY, device="gpu",
                                                      progress=False))
    with pytest.raises(InputError, match="device"):
        m.load(trained[name][1] if name in trained else None, "tpu")
