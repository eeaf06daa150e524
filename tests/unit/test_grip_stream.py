"""GripStream: frame-by-frame GRIP equals the pipeline's online mode; reset; frame errors;
the int8 path and the stream's precision choice."""

import numpy as np
import pytest
import torch

from grip_bench.core.cpu import CpuInfo
from grip_bench.core.errors import InputError
from grip_bench.data.grab_io import list_sequences, read_grab
from grip_bench.data.library import ObjectLibrary
from grip_bench.grip.frozen import (
    PRECISION_CHOICES,
    STREAM_PRECISION_CHOICES,
    freeze,
    resolve_stream_precision,
)
from grip_bench.grip.method import GripMethod
from grip_bench.grip.pipeline import GripPipeline, Options
from grip_bench.grip.stream import GripStream, frame_of, parse_frame


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def root(tiny_grip_root):
    return tiny_grip_root


@pytest.fixture(scope="module")
def method(tiny_grip_checkpoint):
    m = GripMethod()
    m.load(tiny_grip_checkpoint)
    return m


@pytest.fixture(scope="module")
def seqs(root):
    return [read_grab(f) for f in list_sequences(root)]


def _stream(m, lib, seq, **kw):
    return GripStream(m.nets, m.variant, lib, seq.obj_name, height=seq.height,
                      hand_scale=seq.hand_scale, fps=seq.fps, **kw)


def _play(stream, seq):
    return [stream.step(frame_of(seq, t)) for t in range(seq.n_frames)]


def _assert_matches(outs, ref, atol=1e-4):
    for side, part in (("left", "lhand"), ("right", "rhand")):
        for key, tol in (("hand_pose", atol), ("global_orient", 1e-6), ("transl", 1e-6)):
            got = np.stack([o[side][key] for o in outs])
            np.testing.assert_allclose(got, getattr(ref, part)[key], atol=tol, err_msg=key)
    body = np.stack([o["body_pose"] for o in outs])
    np.testing.assert_allclose(body, ref.body["body_pose"], atol=1e-6)


@pytest.mark.parametrize("use_anet,use_rnet", [(True, True), (False, True), (True, False)])
def test_stream_equals_the_online_pipeline(root, method, seqs, use_anet, use_rnet):
    lib = ObjectLibrary(root)
    opt = Options(method.variant, use_anet=use_anet, use_rnet=use_rnet, online=True)
    for seq in seqs[:2]:
        ref = GripPipeline(method.nets, opt).run(seq, lib)
        outs = _play(_stream(method, lib, seq, use_anet=use_anet, use_rnet=use_rnet), seq)
        # batch-1 GEMMs sum in another order than the pipeline's batched ones (float rounding)
        _assert_matches(outs, ref)
        if not use_anet:  # the input wrists pass through
            np.testing.assert_allclose(np.stack([o["right"]["transl"] for o in outs]),
                                       seq.rhand["transl"], atol=1e-6)


def test_reset_starts_a_new_take(root, method, seqs):
    lib = ObjectLibrary(root)
    a, b = seqs[0], seqs[3]
    stream = _stream(method, lib, a)
    _play(stream, a.frames(0, 7))  # a take cut short
    assert stream.frame_index == 7
    stream.reset(b.obj_name, height=b.height, hand_scale=b.hand_scale)
    assert stream.frame_index == 0 and stream.obj_name == b.obj_name
    ref = GripPipeline(method.nets, Options(method.variant, online=True)).run(b, lib)
    _assert_matches(_play(stream, b), ref)


def test_warm_up_leaves_no_state(root, method, seqs):
    lib = ObjectLibrary(root)
    seq = seqs[1]
    cold, warm = _stream(method, lib, seq), _stream(method, lib, seq)
    warm.warm_up()
    assert warm.frame_index == 0
    for a, b in zip(_play(cold, seq), _play(warm, seq), strict=True):
        np.testing.assert_array_equal(a["right"]["hand_pose"], b["right"]["hand_pose"])
        np.testing.assert_array_equal(a["left"]["transl"], b["left"]["transl"])


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_batch1_kernels_match_addmm(precision):
    from grip_bench.grip import RNetConfig

    torch.manual_seed(0)
    net = RNetConfig(width=64, hidden=128).build().eval()
    torch.nn.init.normal_(net.net.head.weight, std=0.05)
    x = torch.randn(1, net.cfg.in_dim)
    mm, gemv = freeze(net, precision).net, freeze(net, precision, gemv=True).net
    tol = 1e-5 if precision == "fp32" else 2e-2
    torch.testing.assert_close(gemv(x), mm(x), atol=tol, rtol=tol)
    torch.testing.assert_close(gemv(x.repeat(3, 1)), mm(x.repeat(3, 1)), atol=0, rtol=0)


def test_vertices_sit_on_the_wrists(root, method, seqs):
    lib = ObjectLibrary(root)
    seq = seqs[0]
    out = _stream(method, lib, seq, vertices=True).step(frame_of(seq, 0))
    for side in ("left", "right"):
        v = out[side]["vertices"]
        assert v.ndim == 2 and v.shape[1] == 3 and np.isfinite(v).all()
        # a hand spans ~20 cm around its wrist
        assert np.linalg.norm(v - out[side]["transl"], axis=1).max() < 0.3


def test_malformed_frames_name_the_field(root, method, seqs):
    seq = seqs[0]
    good = frame_of(seq, 0)
    parse_frame(good)
    bad_cases = [
        ({**good, "body": {**good["body"], "body_pose": [0.0] * 62}}, "body.body_pose"),
        ({k: v for k, v in good.items() if k != "object"}, "object"),
        ({**good, "object": {"global_orient": [0, 0, 0]}}, "object.transl"),
        ({**good, "hands": {**good["hands"], "left": {"global_orient": [0, 0, float("nan")],
                                                      "transl": [0, 0, 0]}}},
         "hands.left.global_orient"),
        ({**good, "body": {**good["body"], "transl": "abc"}}, "body.transl"),
        ([1, 2, 3], "frame"),
    ]
    stream = _stream(method, ObjectLibrary(root), seq)
    for frame, where in bad_cases:
        with pytest.raises(InputError) as e:
            stream.step(frame)
        assert e.value.where == where
    assert stream.frame_index == 0  # a refused frame changes nothing


def test_unknown_object_and_method_are_refused(root, method, seqs, tmp_path):
    lib = ObjectLibrary(root)
    with pytest.raises(InputError, match="mesh not found"):
        GripStream(method.nets, method.variant, lib, "no_such_object")
    with pytest.raises(InputError, match="GRIP variant"):
        GripStream.from_checkpoint(tmp_path / "x.pt", lib, "mug", method="toch")


def test_int8_stream_is_close_to_fp32(root, method, seqs):
    lib = ObjectLibrary(root)
    diffs = []
    for seq in seqs[:2]:
        runs = [_play(_stream(method, lib, seq, precision=p, vertices=True), seq)
                for p in ("fp32", "int8")]
        for a, b in zip(*runs, strict=True):
            for side in ("left", "right"):
                diffs.append(np.linalg.norm(a[side]["vertices"] - b[side]["vertices"], axis=1))
    mean_mm = 1e3 * np.mean(np.concatenate(diffs))
    assert 0 < mean_mm < 2.0  # measured 0.3 mm on this fixture (docs/streaming.md)


def test_frozen_int8_mlp_tracks_fp32():
    from grip_bench.grip import RNetConfig

    torch.manual_seed(0)
    net = RNetConfig(width=64, hidden=64).build().eval()
    torch.nn.init.normal_(net.net.head.weight, std=0.05)  # a non-zero head
    x = torch.randn(5, net.cfg.in_dim)
    a, b = freeze(net, "fp32").net(x), freeze(net, "int8").net(x)
    assert b.dtype == torch.float32 and b.shape == a.shape
    assert 0 < (a - b).abs().max() < 0.05 * a.abs().max()


def test_stream_precision_choice():
    vnni = CpuInfo(model="vnni", capability="AVX512", flags=("avx512_vnni",),
                   native_bf16=False, native_int8=True)
    old = CpuInfo(model="old", capability="AVX2", flags=(), native_bf16=False, native_int8=False)
    assert resolve_stream_precision("auto", vnni) == ("int8", None)
    assert resolve_stream_precision("auto", old) == ("fp32", None)
    prec, warning = resolve_stream_precision("int8", old)
    assert prec == "int8" and "emulated" in warning
    assert resolve_stream_precision("fp32", old) == ("fp32", None)
    with pytest.raises(ValueError, match="int8"):
        resolve_stream_precision("fp16", vnni)
    assert PRECISION_CHOICES == ("auto", "fp32", "bf16")  # offline's choices are unchanged
    assert STREAM_PRECISION_CHOICES == ("auto", "fp32", "bf16", "int8")


def test_batch1_rotations_match_geometry_rotations():
    """The stream's float64 numpy rotations against geometry.rotations (torch), including
    the identity, tiny angles (series branches) and half turns (Shepperd's other rows)."""
    from grip_bench.geometry import rotations as R
    from grip_bench.grip import stream as S

    rng = np.random.default_rng(0)
    axes = rng.normal(size=(40, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    aa = np.concatenate([rng.normal(size=(200, 3)), 1e-5 * rng.normal(size=(20, 3)),
                         np.zeros((1, 3)), (np.pi - 1e-6) * axes, np.pi * np.eye(3)])
    m = R.axis_angle_to_matrix(aa)
    np.testing.assert_allclose(S._aa_to_matrix(aa), m, atol=1e-14)
    np.testing.assert_allclose(S._aa_to_matrix(aa[5]), m[5], atol=1e-14)  # no batch axis
    np.testing.assert_allclose(S._matrix_to_aa(m[:-3]), R.matrix_to_axis_angle(m[:-3]),
                               atol=1e-12)
    # at exactly pi the axis' sign is arbitrary: compare the rotations
    np.testing.assert_allclose(S._aa_to_matrix(S._matrix_to_aa(m[-3:])), m[-3:], atol=1e-12)
    d6 = rng.normal(size=(3, 15, 6))
    np.testing.assert_allclose(S._6d_to_matrix(d6), R.rotation_6d_to_matrix(d6), atol=1e-14)
    np.testing.assert_array_equal(S._to_6d(m), R.matrix_to_rotation_6d(m))


def test_batch1_kinematics_match_the_pipeline(root, seqs):
    """The take's numpy FK (the body's chain to the wrists, the hands' proximity vertices)
    against the pipeline's helpers (ProceduralBody FK, HandModel skinning)."""
    from grip_bench.grip.data import arms_6d, hand_proximity_points
    from grip_bench.grip.pipeline import moved_wrists, set_arms
    from grip_bench.grip.stream import _frame_rotations, _Take
    from grip_bench.sensors import wrist_frames

    lib = ObjectLibrary(root)
    seq = seqs[0]
    take = _Take(lib.field(seq.obj_name), seq.height, seq.hand_scale, "distance")
    rng = np.random.default_rng(1)
    for t in (0, seq.n_frames // 2, seq.n_frames - 1):
        f = parse_frame(frame_of(seq, t))
        pose = f["body"]["body_pose"]
        np.testing.assert_allclose(take.arms_6d(pose), arms_6d(pose[None])[0], atol=1e-7)
        arms = arms_6d(pose[None])[0] + rng.normal(scale=0.05, size=(4, 6)).astype(np.float32)
        _, rot = _frame_rotations(f)
        transl = np.stack([f["hands"][s]["transl"] for s in ("left", "right")])
        new, local, rot2, transl2 = take.move_arms(f["body"], arms, rot, transl)
        ref_pose = set_arms(pose[None], arms[None])
        np.testing.assert_allclose(new, ref_pose[0], atol=1e-12)
        one = seq.take([t])
        ref = moved_wrists(one, pose[None], ref_pose,
                           {s: wrist_frames(one, s) for s in ("left", "right")})
        for h, s in enumerate(("left", "right")):
            np.testing.assert_allclose(rot2[h], ref[s][0][0], atol=1e-12)
            np.testing.assert_allclose(transl2[h], ref[s][1][0], atol=1e-12)
        poses = rng.normal(size=(2, 15, 6)).astype(np.float32)
        got = take.hand_points(poses) @ rot2.swapaxes(-1, -2) + transl2[:, None]
        want = hand_proximity_points(poses[None], rot2[None], transl2[None], seq.hand_scale)[0]
        np.testing.assert_allclose(got, want, atol=1e-6)  # the pipeline skins in float32


@pytest.mark.parametrize("variant", [
    dict(ambient="voxel"), dict(ambient="none", proximity=False, future_frames=0),
    dict(consistency="none"),
    dict(geometry=False, ambient="none", proximity=False, future_frames=0),
])
def test_stream_variants_equal_the_online_pipeline(root, seqs, variant):
    """Every ablation's inputs go through the stream's batch-1 path (grip-blind through the
    pipeline's pieces): seeded untrained networks of the variant's shapes (RNet's head,
    zero at initialisation, made non-zero so that refinement shows)."""
    from grip_bench.grip.train import Variant, build_configs
    from tests.grip_fixtures import tiny_profile

    v = Variant(**variant)
    torch.manual_seed(0)
    nets = {k: c.build().eval() for k, c in build_configs(tiny_profile()["grip"], v).items()}
    torch.nn.init.normal_(nets["rnet"].net.head.weight, std=0.02)  # RNet's starts at zero
    lib, seq = ObjectLibrary(root), seqs[1]
    opt = Options(v, use_rnet=v.geometry, online=True)
    ref = GripPipeline(nets, opt).run(seq, lib)
    stream = GripStream(nets, v, lib, seq.obj_name, use_rnet=v.geometry, height=seq.height,
                        hand_scale=seq.hand_scale, fps=seq.fps)
    _assert_matches(_play(stream, seq), ref)
