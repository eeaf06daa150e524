"""Baseline methods: registration, profile sections, and the small pieces they are built from."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from grip_bench.core.errors import InputError
from grip_bench.methods.api import METHOD_MODULES, load_all, reference_rows

NAMES = ("grabnet", "grabnet-smplx", "manipnet", "toch", "nearest-neighbour")
REFERENCE_ROWS = ("gt", "perturbed-input", "flat-input", "mean-pose")


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize("name", NAMES)
def test_methods_are_registered(name: str) -> None:
    spec = load_all().get(name)
    assert spec.trainable and not spec.reference
    assert not hasattr(spec, "tables")  # the table TOML files say which tables show a method
    assert not spec.supports_online  # no baseline streams frame by frame
    assert spec.version == "1"
    assert spec.description and "\n" not in spec.description
    assert "object" in spec.needs
    assert name in spec.describe()


@pytest.mark.parametrize("name", REFERENCE_ROWS)
def test_reference_rows_are_marked(name: str) -> None:
    spec = load_all().get(name)
    assert not spec.trainable and not spec.supports_online
    # only the rows that bound the scale are never marked best
    assert (name in reference_rows()) == (name in ("gt", "perturbed-input")) == spec.reference


def test_method_modules_listed() -> None:
    for module in ("grabnet_method", "toch_method", "manipnet_method", "nearest"):
        assert f"grip_baselines.{module}" in METHOD_MODULES


def test_needs_match_what_the_methods_read() -> None:
    methods = load_all()
    assert "noisy_hands" in methods.get("toch").needs
    assert "body" in methods.get("grabnet-smplx").needs
    assert "train_data" in methods.get("nearest-neighbour").needs


@pytest.mark.parametrize("profile", ["smoke", "default", "paper"])
def test_profiles_carry_every_train_config_field(profile: str) -> None:
    import dataclasses

    from grip_baselines.common import section_config
    from grip_baselines.grabnet_method import GrabNetTrainConfig
    from grip_baselines.manipnet_method import ManipNetTrainConfig
    from grip_baselines.nearest import NearestTrainConfig
    from grip_baselines.toch_method import TochTrainConfig

    from grip_bench.profiles import load_profile

    p = load_profile(profile)
    for section, cls in (("grabnet", GrabNetTrainConfig), ("toch", TochTrainConfig),
                         ("manipnet", ManipNetTrainConfig), ("nearest", NearestTrainConfig)):
        assert set(p[section]) == {f.name for f in dataclasses.fields(cls)}
        section_config(cls, p, section)


def test_default_profile_matches_config_defaults() -> None:
    import dataclasses

    from grip_baselines.grabnet_method import GrabNetTrainConfig
    from grip_baselines.manipnet_method import ManipNetTrainConfig
    from grip_baselines.nearest import NearestTrainConfig
    from grip_baselines.toch_method import TochTrainConfig

    from grip_bench.profiles import load_profile

    p = load_profile("default")
    for section, cls in (("grabnet", GrabNetTrainConfig), ("toch", TochTrainConfig),
                         ("manipnet", ManipNetTrainConfig), ("nearest", NearestTrainConfig)):
        for f in dataclasses.fields(cls):
            assert p[section][f.name] == pytest.approx(getattr(cls(), f.name), rel=1e-3), f.name


def test_section_config_rejects_unknown_keys() -> None:
    from grip_baselines.common import section_config
    from grip_baselines.grabnet_method import GrabNetTrainConfig

    assert section_config(GrabNetTrainConfig, {}, "grabnet") == GrabNetTrainConfig()
    assert section_config(GrabNetTrainConfig, {"grabnet": {"width": 8}}, "grabnet").width == 8
    with pytest.raises(InputError, match="widht"):
        section_config(GrabNetTrainConfig, {"grabnet": {"widht": 8}}, "grabnet")


def test_mirror_pose_is_the_hand_mirror() -> None:
    from grip_baselines.common import mirror_pose

    from grip_bench.bodies.hand import ProceduralHand

    rng = np.random.default_rng(0)
    pose = rng.normal(0, 0.3, size=(2, 45))
    np.testing.assert_allclose(mirror_pose(mirror_pose(pose)), pose)
    # The left hand at the mirrored pose is the x-mirror of the right hand.
    right, left = ProceduralHand("right"), ProceduralHand("left")
    with torch.no_grad():
        vr = right(None, torch.tensor(pose, dtype=torch.float32).reshape(2, 15, 3), None)[0]
        vl = left(
            None, torch.tensor(mirror_pose(pose), dtype=torch.float32).reshape(2, 15, 3), None
        )[0]
    np.testing.assert_allclose(vl.numpy(), vr.numpy() * [-1, 1, 1], atol=1e-5)


def test_bps_codes_agree_with_bps_encode_under_rotation() -> None:
    from grip_baselines.bps import basis_points, bps_encode, object_centre
    from grip_baselines.grabnet_method import bps_codes

    class Lib:
        def mesh(self, name: str) -> trimesh.Trimesh:
            return box

    box = trimesh.creation.box(extents=(0.08, 0.03, 0.05))
    box.apply_translation([0.01, 0.02, -0.01])
    basis = basis_points(50, 0.15, seed=2)
    Q = Rotation.random(3, random_state=1).as_matrix()
    c = object_centre(box)
    # Model frame = the object rotated by Q about its centre: x = c + Q^T y.
    got = bps_codes(Lib(), ["box"], np.zeros(3, int), np.transpose(Q, (0, 2, 1)),
                    np.tile(c, (3, 1)), basis, (0.0, 0.0, 0.0))
    np.testing.assert_allclose(got, bps_encode(box, basis, rotations=Q), atol=1e-12)


def test_windows_of_cuts_runs() -> None:
    from grip_baselines.toch_method import windows_of

    mask = np.array([0, 1, 1, 1, 1, 1, 0, 0, 1, 1], bool)
    got = [w.tolist() for w in windows_of(mask, 3)]
    assert got == [[1, 2, 3], [4, 5], [8, 9]]
    assert windows_of(np.zeros(4, bool), 3) == []


def test_vertex_subset_and_batches() -> None:
    from grip_baselines.common import batches, vertex_subset

    class H:
        num_vertices = 10

    assert vertex_subset(H(), 0).tolist() == list(range(10))
    assert len(vertex_subset(H(), 4)) == 4
    parts = batches(9, 4, np.random.default_rng(0))
    assert sorted(np.concatenate(parts).tolist()) == list(range(9))
    assert min(len(p) for p in parts) >= 2  # never a batch of one (BatchNorm)


def test_nearest_index_retrieves_its_own_items() -> None:
    from grip_baselines.nearest import build_index

    rng = np.random.default_rng(0)
    feats = rng.normal(size=(40, 12))
    poses = rng.normal(size=(40, 45))
    index = build_index(feats, poses, 12)  # full rank: distances are preserved
    from scipy.spatial import cKDTree

    _, nn = cKDTree(index.keys.numpy()).query(index.reduce(feats[[3, 17]]))
    assert nn.tolist() == [3, 17]
    cfg = index.cfg
    assert (cfg.n_items, cfg.feat_dim, cfg.n_components) == (40, 12, 12)


def test_grabnet_refinenet_noise_leaves_tied_wrist_alone() -> None:
    from grip_baselines.grabnet_method import GrabNetTrainConfig, _noisy, pin_wrist, to_grasp

    g = to_grasp(np.tile(np.eye(3), (4, 1, 1)), np.zeros((4, 3)), np.zeros((4, 45)))
    gen = torch.Generator().manual_seed(0)
    tied = _noisy(g, GrabNetTrainConfig(), True, gen)
    torch.testing.assert_close(tied.global_orient, g.global_orient)
    torch.testing.assert_close(tied.transl, g.transl)
    assert not torch.allclose(tied.hand_pose, g.hand_pose)
    free = _noisy(g, GrabNetTrainConfig(), False, gen)
    assert not torch.allclose(free.transl, g.transl)
    pinned = pin_wrist(free)
    torch.testing.assert_close(pinned.global_orient, g.global_orient)
    torch.testing.assert_close(pinned.transl, g.transl)


def test_untrained_method_refuses_to_predict() -> None:
    methods = load_all()
    for name in NAMES:
        with pytest.raises(InputError, match="load a checkpoint"):
            methods.get(name).build().predict(None, None)


def test_manipnet_contact_terms_match_the_numpy_hand_and_field(tmp_path: Path) -> None:
    """ContactTerms' differentiable distances = the hand posed in numpy and the field's exact
    distances; its penetration term is zero on the ground truth's own (touching) frames."""
    import numpy as np
    import torch
    from grip_baselines import common as U
    from grip_baselines.manipnet_method import ContactTerms, SeqData

    from grip_bench.data.grab_io import list_sequences, read_grab
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.geometry.rotations import axis_angle_to_rotation_6d
    from tests.baseline_fixtures import baseline_dataset

    root = baseline_dataset(tmp_path / "data", T=12)
    lib = ObjectLibrary(root)
    seqs = [read_grab(f) for f in list_sequences(root)[:2]]
    data = [SeqData(s, lib) for s in seqs]
    terms = ContactTerms(data, lib, n_vertices=64)
    rows = np.arange(sum(len(d.pose) for d in data))
    pose6 = torch.as_tensor(axis_angle_to_rotation_6d(np.concatenate([d.pose for d in data])),
                            dtype=torch.float32)
    got = terms.signed_distance(pose6, rows).numpy()  # (N, 64)
    at = 0
    for seq, d in zip(seqs, data, strict=True):
        world = U.seq_vertices(seq, "right")[:, U.vertex_subset(terms.hand.hand, 64)]
        local = np.einsum("tji,tkj->tki", d.obj_rot, world - d.obj_pos[:, None])
        want = lib.field(seq.obj_name).signed_distance(local)
        near = np.abs(want) < 0.02
        np.testing.assert_allclose(got[at:at + len(d.pose)][near], want[near], atol=1e-3)
        at += len(d.pose)
    prox, pen = terms(pose6, pose6, rows)
    assert prox.item() == 0.0 and pen.item() < 1e-3


def test_resolve_device_accepts_the_cpu_and_refuses_unknown_devices() -> None:
    from grip_baselines.common import resolve_device

    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")
    assert resolve_device("cpu:0").type == "cpu"
    for bad in ("gpu", "tpu0", "", "meta"):
        with pytest.raises(InputError, match="device") as err:
            resolve_device(bad)
        assert err.value.where == "--device"


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_resolve_device_refuses_cuda_without_cuda() -> None:
    from grip_baselines.common import resolve_device

    for dev in ("cuda", "cuda:0", torch.device("cuda", 1)):
        with pytest.raises(InputError, match="CUDA is not available"):
            resolve_device(dev)


def test_hand_model_is_cached_per_device() -> None:
    from grip_baselines.common import SubsetHand, hand_model

    right = hand_model("right")
    assert hand_model("right", 1.0, "cpu") is right
    assert hand_model("right", device=torch.device("cpu")) is right
    sub = SubsetHand(right, [0, 5, 9])
    assert sub.skin.device == right.weights.device


def test_world_to_object_copies_agree_with_the_old_transforms() -> None:
    """The baselines' world -> object transforms now go through core.frames; they are the
    column-rotation einsums they replaced (R^T (x - t), R = the transpose of GRAB's)."""
    from grip_baselines.manipnet import _to_object

    from grip_bench.core.frames import world_to_object

    rng = np.random.default_rng(0)
    R_row = Rotation.random(5, random_state=3).as_matrix()  # GRAB's row-vector matrices
    R_col = np.transpose(R_row, (0, 2, 1))
    t = rng.normal(size=(5, 3))
    pts = rng.normal(size=(5, 7, 3))
    old = np.einsum("fji,fvj->fvi", R_col, pts - t[:, None])  # toch / common copies
    np.testing.assert_allclose(world_to_object(pts, R_row, t), old, rtol=0, atol=1e-15)
    grid = rng.normal(size=(5, 2, 3, 4, 3))  # manipnet's voxel grids (F, r, r, r, 3)
    old = np.einsum("f...j,fjk->f...k", grid - t[:, None, None, None], R_col)
    np.testing.assert_allclose(_to_object(grid, R_col, t), old, rtol=0, atol=1e-15)
    # and back: world = local @ R_row + t
    np.testing.assert_allclose(world_to_object(pts, R_row, t) @ R_row + t[:, None], pts,
                               atol=1e-14)


def test_kept_fields_build_each_field_once_and_delegate(tmp_path: Path) -> None:
    """The training library keeps every field it handed out (the library's LRU may drop
    them: a cycle over more objects than its 64 rebuilt each one on every visit) and is
    the wrapped library for everything else."""
    from grip_baselines import common as U

    from grip_bench.data.library import ObjectLibrary
    from tests.baseline_fixtures import baseline_dataset

    root = baseline_dataset(tmp_path / "data", T=6)
    lib = ObjectLibrary(root)
    kept = U.KeptFields(lib)
    name = sorted(p.stem for p in (root / "tools").rglob("*.ply"))[0]
    first = kept.field(name)
    assert first is lib.field(name)  # the library's own field, the same arrays
    lib.field.cache_clear()  # what an LRU eviction does
    assert kept.field(name) is first
    assert lib.field(name) is not first  # the bare library would rebuild it
    assert kept.mesh is lib.mesh and kept.data_dir == lib.data_dir
    built = U.train_library(root)
    assert isinstance(built, U.KeptFields) and built.data_dir == Path(root)


def test_manipnet_precomputed_targets_equal_the_per_batch_ones(tmp_path: Path) -> None:
    """The targets' vertices and proximity attention, computed once for all rows, equal
    what the loss computed per batch before (the naive reference), to float32 rounding."""
    from grip_baselines import common as U
    from grip_baselines.manipnet_method import ContactTerms, SeqData, _gt_vertices

    from grip_bench.data.grab_io import list_sequences, read_grab
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.geometry.rotations import axis_angle_to_rotation_6d, rotation_6d_to_axis_angle
    from tests.baseline_fixtures import baseline_dataset

    root = baseline_dataset(tmp_path / "data", T=12)
    lib = ObjectLibrary(root)
    data = [SeqData(read_grab(f), lib) for f in list_sequences(root)[:3]]
    target = torch.as_tensor(
        axis_angle_to_rotation_6d(np.concatenate([d.pose for d in data])), dtype=torch.float32
    )
    hand = U.hand_model("right")
    vhand = U.SubsetHand(hand, U.vertex_subset(hand, 64))
    gt_v = _gt_vertices(vhand, target, chunk=7)
    plain, kept = ContactTerms(data, lib, n_vertices=64), ContactTerms(data, lib, n_vertices=64)
    # the fixture's hands may not touch: mark every other row as a contact row in both
    plain.contact[::2] = kept.contact[::2] = True
    kept.precompute_gt(target, chunk=5)
    assert kept.gt_attention is not None and len(kept.gt_attention) == kept.contact.sum()
    pred = target + 0.05 * torch.randn(target.shape, generator=torch.Generator().manual_seed(0))
    rng = np.random.default_rng(0)
    for _ in range(4):
        idx = np.sort(rng.choice(len(target), 9, replace=False))
        with torch.no_grad():
            want = vhand(None, rotation_6d_to_axis_angle(target[idx]), None)[0]
        torch.testing.assert_close(gt_v[idx], want, rtol=1e-6, atol=1e-9)
        for a, b in zip(plain(pred[idx], target[idx], idx), kept(pred[idx], target[idx], idx),
                        strict=True):
            # to float32 rounding: on an AVX2 CPU chunked and per-batch GEMMs round differently
            # in the last bit (bit for bit on the AVX-512 machines of earlier sessions)
            torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-9)


def test_manipnet_scheduled_sampling_equals_full_feature_recomputation(tmp_path: Path) -> None:
    """Scheduled sampling recomputes only the pose-dependent inputs of the picked frames;
    the result equals recomputing all four inputs of those frames (the naive reference)."""
    from grip_baselines import common as U
    from grip_baselines.manipnet import ManipNetConfig
    from grip_baselines.manipnet_method import _build, _predict_all, _scheduled

    from grip_bench.geometry.rotations import rotation_6d_to_axis_angle
    from tests.baseline_fixtures import baseline_dataset

    root = baseline_dataset(tmp_path / "data", T=12)
    lib = U.train_library(root)
    seqs = U.load_split(root, "train")[:3]
    cfg = ManipNetConfig(n_past=2, n_future=2, width=32, hidden=32, n_blocks=1)
    data, feats, _, _ = _build(seqs, lib, cfg, 0.1, np.random.default_rng(0))
    net = cfg.build()
    torch.nn.init.normal_(net.net.head.weight, std=0.1)  # a non-trivial previous pose
    got = _scheduled(net, data, feats, cfg, 0.5, np.random.default_rng(1))
    pred = rotation_6d_to_axis_angle(_predict_all(net, feats).double()).numpy()
    want = [x.clone() for x in feats]
    rng, start = np.random.default_rng(1), 0
    for d in data:
        n = len(d.pose)
        pick = np.flatnonzero(rng.random(n) < 0.5)
        pick = pick[pick > 0]
        prev = np.concatenate([d.pose[:1], d.pose[:-1]])
        prev[pick] = pred[start + pick - 1]
        for x, y in zip(want, d.features(prev, pick, cfg), strict=True):
            x[start + pick] = y.to(x.dtype)
        start += n
    assert all(torch.equal(a, b) for a, b in zip(got, want, strict=True))
    assert not torch.equal(got[2], feats[2])  # some distances did change
