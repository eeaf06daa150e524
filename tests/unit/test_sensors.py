"""GRIP's hand sensors against brute-force references (analytic box distance, loops)."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from grip_bench import sensors as S
from grip_bench.bodies.hand import ProceduralHand
from grip_bench.core import constants as C
from tests.grab_fixtures import BOX_EXTENTS
from tests.grip_fixtures import write_grip_dataset


@pytest.fixture(autouse=True)
def _threads():
    torch.set_num_threads(1)


def box_sdf(p):
    """Exact signed distance of one point to the centred fixture box (loops call this)."""
    q = np.abs(p) - np.asarray(BOX_EXTENTS) / 2
    return np.linalg.norm(np.maximum(q, 0.0)) + min(q.max(), 0.0)


def brute_distance(seq, world):
    """(T, N) unsigned distances, one point at a time, GRAB's row-vector object transform."""
    R, t = seq.object_rotations(), np.asarray(seq.object["transl"], float)
    out = np.zeros(world.shape[:2])
    for f in range(world.shape[0]):
        for n in range(world.shape[1]):
            local = np.linalg.solve(R[f].T, world[f, n] - t[f])  # world = local @ R + t
            out[f, n] = max(box_sdf(local), 0.0)
    return out


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from grip_bench.data.grab_io import list_sequences, read_grab
    from grip_bench.data.library import ObjectLibrary

    root = write_grip_dataset(tmp_path_factory.mktemp("grip"), T=6)
    seq = read_grab(list_sequences(root)[0])
    return ObjectLibrary(root), seq


def test_hemisphere_geometry():
    p = S.hemisphere()
    r = np.linalg.norm(p, axis=1)
    assert p.shape == (C.AMBIENT_N_POINTS, 3)
    assert r.max() <= C.AMBIENT_RADIUS + 1e-12
    assert (p[:, 1] <= 0).all()  # the dome is on the palm side (-y)
    # uniform in volume: P(r < R/2) = 1/8, P(r < 0.8 R) = 0.512 (binomial 3-sigma bands)
    assert abs((r < C.AMBIENT_RADIUS / 2).mean() - 0.125) < 0.035
    assert abs((r < 0.8 * C.AMBIENT_RADIUS).mean() - 0.512) < 0.05
    np.testing.assert_array_equal(p, S.hemisphere())  # deterministic


def test_ambient_points_sit_on_the_mean_hand():
    for side in ("right", "left"):
        hand = ProceduralHand(side)
        with torch.no_grad():
            _, joints = hand(None, hand.named_pose("relaxed")[None], None)
        centre = joints[0, 4].numpy()  # MANO middle1
        pts = S.ambient_points(side)
        np.testing.assert_allclose(
            pts - centre, S.hemisphere() * ([-1, 1, 1] if side == "left" else 1), atol=1e-6
        )
        assert ((pts - centre) @ hand.palm_normal >= 0).all()
    np.testing.assert_allclose(
        S.ambient_points("left"), S.ambient_points("right") * [-1, 1, 1], atol=1e-6
    )


def test_voxel_cells_cover_the_hemisphere_box():
    v = S.voxel_points("right") - S.ambient_points("right")[0] + S.hemisphere()[0]
    assert len(v) == np.prod(C.VOXEL_CELLS)
    assert (np.abs(v[:, [0, 2]]) < C.AMBIENT_RADIUS).all() and (v[:, 1] < 0).all()


def test_ambient_matches_brute_force(data):
    lib, seq = data
    rot, transl = S.wrist_frames(seq, "right")
    feat = S.ambient_feature(lib, seq, rot, transl, "right")
    pts = S.to_world(S.ambient_points("right", seq.hand_scale), rot, transl)
    sub = np.arange(0, C.AMBIENT_N_POINTS, 16)  # 64 points x 6 frames by loops
    ref = np.exp(-5 * brute_distance(seq, pts[:, sub]))
    assert feat.shape == (seq.n_frames, C.AMBIENT_N_POINTS)
    np.testing.assert_allclose(feat[:, sub], ref, atol=0.03)  # coarse far grid: see constants
    assert np.abs(feat[:, sub] - ref).mean() < 4e-3


def test_proximity_and_voxel_match_brute_force(data):
    lib, seq = data
    rot, transl = S.wrist_frames(seq, "right")
    pts = S.to_world(S.mean_hand_points("right", seq.hand_scale), rot, transl)
    feat, d = S.proximity_feature(lib, seq, pts)
    ref = brute_distance(seq, pts)
    # fine grid: 0.5 mm; the far tiers beyond it: spacing^2 / (4 d) <= 0.016 d (constants)
    np.testing.assert_allclose(d, ref, atol=5e-4, rtol=0.02)
    assert (ref > C.SDF_GRID_PADDING).mean() > 0.3  # the far tiers are exercised
    np.testing.assert_allclose(feat, np.exp(-50 * ref), atol=0.02)
    occ = S.ambient_feature(lib, seq, rot, transl, "right", "voxel")
    cells = S.to_world(S.voxel_points("right", seq.hand_scale), rot, transl)
    R, t = seq.object_rotations(), seq.object["transl"]
    inside = [
        [box_sdf(np.linalg.solve(R[f].T, cells[f, n] - t[f])) < 0 for n in range(cells.shape[1])]
        for f in range(len(cells))
    ]
    np.testing.assert_array_equal(occ, np.array(inside, np.float32))


def test_stage_one_shapes_and_kinds(data):
    lib, seq = data
    one = S.stage_one(lib, seq)
    assert one.ambient.shape == (seq.n_frames, 2, 1024) and one.proximity.shape == (
        seq.n_frames,
        2,
        99,
    )
    assert 0 <= one.ambient.min() and one.ambient.max() <= 1
    assert S.stage_one(lib, seq, ambient="none").ambient.shape == (seq.n_frames, 2, 0)
    with pytest.raises(Exception, match="ambient"):
        S.stage_one(lib, seq, ambient="sdf")


def test_future_cue_by_hand():
    d = np.array([[0.4, 1.0], [0.3, 1.0], [0.1, 0.9], [0.0, 0.9]])  # (T=4, hands)
    cue = S.future_cue(d, 2, fps=10.0).reshape(4, 2, 2, 2)  # (T, hand, k, [d, rate])
    # frame 0, left hand: d[1] = 0.3 (rate -1.0 m/s), d[2] = 0.1 (rate -2.0 m/s)
    np.testing.assert_allclose(cue[0, 0], [[0.3, -1.0], [0.1, -2.0]], atol=1e-6)
    np.testing.assert_allclose(cue[0, 1], [[1.0, 0.0], [0.9, -1.0]], atol=1e-6)
    # frame 3 is the last: the future repeats it (rate 0)
    np.testing.assert_allclose(cue[3, 0], [[0.0, 0.0], [0.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(cue[2, 0], [[0.0, -1.0], [0.0, 0.0]], atol=1e-6)
    online = S.future_cue(d, 2, online=True).reshape(4, 2, 2, 2)
    np.testing.assert_allclose(online[1, 0], [[0.3, 0.0], [0.3, 0.0]], atol=1e-6)
    assert S.future_cue(d, 0).shape == (4, 0)


def test_wrist_frames_follow_global_orient(data):
    _, seq = data
    rot, transl = S.wrist_frames(seq, "left")
    np.testing.assert_allclose(
        rot, Rotation.from_rotvec(seq.lhand["global_orient"]).as_matrix(), atol=1e-6
    )
    np.testing.assert_array_equal(transl, seq.lhand["transl"])


def test_hand_to_object_is_hand_to_world_to_object(data):
    """The composed map (one 3 x 3 per hand and frame) against hand -> world (to_world) ->
    object (world_to_object), and a hand-built analytic case."""
    from grip_bench.core.frames import world_to_object

    _, seq = data
    wr = [S.wrist_frames(seq, s) for s in ("left", "right")]
    rot, transl = np.stack([w[0] for w in wr], 1), np.stack([w[1] for w in wr], 1)
    R_o, t_o = seq.object_rotations(), np.asarray(seq.object["transl"], float)
    M, c = S.hand_to_object(R_o, t_o, rot, transl)
    local = np.random.default_rng(0).normal(scale=0.1, size=(2, 7, 3))
    got = S.apply_rigid(M, c, local)  # (T, 2, 7, 3)
    for h in range(2):
        ref = world_to_object(S.to_world(local[h], rot[:, h], transl[:, h]), R_o, t_o)
        np.testing.assert_allclose(got[:, h], ref, atol=1e-15)
    # a quarter turn about z of the object at (1, 0, 0), the wrist at the origin unrotated:
    # world -> object is R_o (p - t_o), so the hand-frame point (1, 0, 0) maps to R_o (0, 0, 0)
    qz = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()
    M1, c1 = S.hand_to_object(qz[None], np.array([[1.0, 0, 0]]), np.eye(3)[None, None].repeat(2, 1),
                              np.zeros((1, 2, 3)))
    np.testing.assert_allclose(S.apply_rigid(M1, c1, np.array([[[1.0, 0, 0]]] * 2)),
                               np.zeros((1, 2, 1, 3)), atol=1e-15)
    np.testing.assert_allclose(S.apply_rigid(M1, c1, np.zeros((2, 1, 3)))[0, 0, 0],
                               qz @ [-1.0, 0, 0], atol=1e-15)


@pytest.mark.parametrize("kind", ["distance", "voxel", "none"])
def test_stage_one_rigid_equals_stage_one(data, kind):
    """The batched form (both hands per query, composed maps) gives stage_one's features up
    to float rounding (measured: 0 on this fixture and on the bench scene's 300 frames)."""
    lib, seq = data
    wr = [S.wrist_frames(seq, s) for s in ("left", "right")]
    M, c = S.hand_to_object(seq.object_rotations(), np.asarray(seq.object["transl"], float),
                            np.stack([w[0] for w in wr], 1), np.stack([w[1] for w in wr], 1))
    got = S.stage_one_rigid(lib.field(seq.obj_name), M, c, seq.hand_scale or 1.0, kind)
    ref = S.stage_one(lib, seq, ambient=kind)
    assert got.ambient.shape == ref.ambient.shape and got.ambient.dtype == np.float32
    np.testing.assert_allclose(got.ambient, ref.ambient, atol=1e-6)
    np.testing.assert_allclose(got.proximity, ref.proximity, atol=1e-6)
    np.testing.assert_allclose(got.mean_dist, ref.mean_dist, atol=1e-9)


def test_sensor_points_are_built_once_and_read_only():
    a = S.ambient_points("left", 0.9)
    assert a is S.ambient_points("left", 0.9) and not a.flags.writeable
    amb, prox = S.hand_sensor_points(0.9)
    np.testing.assert_array_equal(amb[0], a)
    np.testing.assert_array_equal(prox[1], S.mean_hand_points("right", 0.9))
    assert S.hand_sensor_points(0.9, "none")[0].shape == (2, 0, 3)
    assert S.hand_sensor_points(0.9, "voxel")[0].shape == (2, np.prod(C.VOXEL_CELLS), 3)
    with pytest.raises(Exception, match="ambient"):
        S.hand_sensor_points(0.9, "sdf")
    with pytest.raises(ValueError):
        a[0, 0] = 1.0


@pytest.mark.parametrize("n", [1024, 99, 1014, 97, 1])
def test_apply_rigid_is_the_plain_broadcast_bit_for_bit(n):
    """The in-place tiled ``+ c`` gives ``matmul + c`` exactly, for point counts with many,
    few (97 is prime) or one divisor; other shapes and dtypes take the plain broadcast."""
    rng = np.random.default_rng(n)
    M = Rotation.random(14, random_state=n).as_matrix().reshape(7, 2, 3, 3)
    c, local = rng.normal(size=(7, 2, 3)), rng.normal(scale=0.1, size=(2, n, 3))
    ref = np.matmul(local, np.swapaxes(M, -1, -2)) + c[..., None, :]
    np.testing.assert_array_equal(S.apply_rigid(M, c, local), ref)
    c32 = c.astype(np.float32)
    np.testing.assert_array_equal(S.apply_rigid(M, c32, local),
                                  np.matmul(local, np.swapaxes(M, -1, -2)) + c32[..., None, :])
    np.testing.assert_array_equal(S.apply_rigid(M, c[0], local),  # c (2, 3) broadcast
                                  np.matmul(local, np.swapaxes(M, -1, -2)) + c[0][:, None, :])


def _maps_around(centre, T, rng, reach=0.8):
    """T random wrist maps (M (T, 2, 3, 3), c (T, 2, 3)) whose hands sit from 0 to ``reach``
    m from ``centre``, so both hands' points fall in every grid of the field and beyond."""
    M = Rotation.random(2 * T, random_state=rng.integers(1 << 31)).as_matrix()
    d = rng.normal(size=(T, 2, 3))
    d *= np.linspace(0.0, reach, T)[:, None, None] / np.linalg.norm(d, axis=2, keepdims=True)
    return M.reshape(T, 2, 3, 3), centre + d


@pytest.mark.parametrize("kind", ["distance", "voxel", "none"])
def test_stage_one_rigid_is_the_per_point_path_bit_for_bit(data, kind):
    """The rigid form's features equal, bit for bit, those of one far="coarse" query of the
    moved points (proximity included), a frame without wrists included."""
    lib, seq = data
    field = lib.field(seq.obj_name)
    M, c = _maps_around(np.zeros(3), 40, np.random.default_rng(9))
    M[5] = np.nan  # a frame without wrists
    amb_pts, prox_pts = S.hand_sensor_points(1.0, kind)

    def per_point(local, exact_cells):
        q = S.apply_rigid(M, c, local).reshape(-1, 3)
        return field.signed_distance(q, far="coarse", exact_cells=exact_cells).reshape(40, 2, -1)

    d = np.maximum(per_point(prox_pts, True), 0.0)
    got = S.stage_one_rigid(field, M, c, 1.0, kind)
    np.testing.assert_array_equal(got.proximity,
                                  S.attention(d, C.PROXIMITY_DECAY).astype(np.float32))
    np.testing.assert_array_equal(got.mean_dist, d.mean(axis=2))
    if kind != "none":
        sd = per_point(amb_pts, False)
        ref = (S.attention(np.maximum(sd, 0.0), C.AMBIENT_DECAY) if kind == "distance"
               else sd < 0).astype(np.float32)
        np.testing.assert_array_equal(got.ambient, ref)


@pytest.mark.parametrize("dtypes", [(np.float64, np.float64), (np.float32, np.float64),
                                    (np.float64, np.float32)])
def test_hand_points_in_object_is_to_world_then_world_to_object_bit_for_bit(dtypes):
    """The fused hand -> object map keeps the two-step form's every rounding (also when the
    wrists or the local points are float32: the result dtype is the two-step one)."""
    from grip_bench.core.frames import world_to_object

    rng = np.random.default_rng(3)
    T, N = 5, 37
    rot = Rotation.from_rotvec(rng.normal(size=(T, 3))).as_matrix().astype(dtypes[0])
    transl = rng.normal(size=(T, 3)).astype(dtypes[0])
    local = rng.normal(scale=0.1, size=(N, 3)).astype(dtypes[1])
    R_o, t_o = Rotation.from_rotvec(rng.normal(size=(T, 3))).as_matrix(), rng.normal(size=(T, 3))
    ref = world_to_object(S.to_world(local, rot, transl), R_o, t_o)
    got = S.hand_points_in_object(local, rot, transl, R_o, t_o)
    assert got.dtype == ref.dtype and got.shape == (T, N, 3)
    assert np.array_equal(got, ref)


def test_stage_one_is_the_world_path_bit_for_bit(data):
    """stage_one (points straight into the object frame) against the world path it replaced:
    to_world, then object_distance / proximity_feature of the world points."""
    lib, seq = data
    one, k = S.stage_one(lib, seq), seq.hand_scale or 1.0
    for h, side in enumerate(("left", "right")):
        rot, transl = S.wrist_frames(seq, side)
        d = S.object_distance(lib, seq, S.to_world(S.ambient_points(side, k), rot, transl), False)
        assert np.array_equal(one.ambient[:, h], S.attention(d, C.AMBIENT_DECAY).astype(np.float32))
        feat, dist = S.proximity_feature(lib, seq,
                                         S.to_world(S.mean_hand_points(side, k), rot, transl))
        assert np.array_equal(one.proximity[:, h], feat)
        assert np.array_equal(one.mean_dist[:, h], dist.mean(axis=1))
        vox = S.signed_object_distance(lib, seq, S.to_world(S.voxel_points(side, k), rot, transl),
                                       False)
        assert np.array_equal(S.ambient_sensor(lib, seq, None, "voxel")[:, h],
                              (vox < 0).astype(np.float32))


def test_stage_one_float32_wrists_keep_their_rounding(data):
    """float32 wrists (a caller's torch output) are moved in float32 as before, not through
    the compiled float64 pass: the world path's features bit for bit."""
    lib, seq = data
    k = seq.hand_scale or 1.0
    wrists = {side: tuple(a.astype(np.float32) for a in S.wrist_frames(seq, side))
              for side in ("left", "right")}
    one = S.stage_one(lib, seq, wrists)
    for h, side in enumerate(("left", "right")):
        rot, transl = wrists[side]
        d = S.object_distance(lib, seq, S.to_world(S.ambient_points(side, k), rot, transl), False)
        assert np.array_equal(one.ambient[:, h], S.attention(d, C.AMBIENT_DECAY).astype(np.float32))
