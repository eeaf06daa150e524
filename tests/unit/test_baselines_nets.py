"""Baseline networks and features: BPS, GrabNet (CoarseNet / RefineNet), TOCH pieces, ManipNet."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
import torch
import trimesh
from grip_baselines import bps, grabnet, manipnet, toch

from grip_bench.core.errors import InputError

if TYPE_CHECKING:
    from grip_bench.bodies.hand import ProceduralHand
    from grip_bench.geometry.distance import DistanceField

pytestmark = pytest.mark.usefixtures("one_thread")  # the 2 test cores are shared


@pytest.fixture(scope="module")
def sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=3, radius=0.05)


@pytest.fixture(scope="module")
def sphere_field(sphere: trimesh.Trimesh) -> DistanceField:
    from grip_bench.geometry.distance import DistanceField

    return DistanceField(sphere)


def n_params(m: torch.nn.Module) -> int:
    return sum(p.numel() for p in m.parameters())


# ----------------------------------------------------------------------------- BPS


def closest_on_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact closest point of triangle abc to p (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return a
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return b
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return a + d1 / (d1 - d3) * ab
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return c
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return a + d2 / (d2 - d6) * ac
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)
    denom = 1.0 / (va + vb + vc)
    return a + ab * (vb * denom) + ac * (vc * denom)


def brute_distance(p: np.ndarray, mesh: trimesh.Trimesh) -> tuple[float, np.ndarray | None]:
    best = (np.inf, None)
    for f in mesh.faces:
        q = closest_on_triangle(p, *mesh.vertices[f])
        d = np.linalg.norm(p - q)
        if d < best[0]:
            best = (d, q)
    return best


def test_basis_points_deterministic_and_uniform() -> None:
    a = bps.basis_points(4096, 0.15, seed=3)
    assert a.shape == (4096, 3)
    assert np.linalg.norm(a, axis=1).max() <= 0.15
    np.testing.assert_array_equal(a, bps.basis_points(4096, 0.15, seed=3))
    assert not np.allclose(a, bps.basis_points(4096, 0.15, seed=4))
    # Uniform in volume: 1/8 of the points lie within half the radius.
    inner = (np.linalg.norm(a, axis=1) < 0.075).mean()
    assert abs(inner - 0.125) < 0.02
    with pytest.raises(InputError):
        bps.basis_points(0)


def test_bps_matches_brute_force_on_a_small_mesh() -> None:
    mesh = trimesh.creation.box(extents=(0.1, 0.04, 0.06))
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.4, [1, 2, 3]))
    basis = bps.basis_points(40, 0.15, seed=1)
    rots = np.stack([np.eye(3), trimesh.transformations.rotation_matrix(1.1, [0, 1, 1])[:3, :3]])
    dist, delta = bps.bps_encode(mesh, basis, rotations=rots, return_deltas=True)
    assert dist.shape == (2, 40) and delta.shape == (2, 40, 3)
    c = bps.object_centre(mesh)
    for r, rot in enumerate(rots):
        rotated = mesh.copy().apply_translation(-c)
        rotated.apply_transform(np.block([[rot, np.zeros((3, 1))], [np.zeros((1, 3)), 1]]))
        for i in range(40):
            d_ref, q_ref = brute_distance(basis[i], rotated)
            assert dist[r, i] == pytest.approx(d_ref, abs=1e-9)
            np.testing.assert_allclose(basis[i] + delta[r, i], q_ref, atol=1e-9)
    # Without rotations: the plain (n,) code, equal to the identity rotation's row.
    np.testing.assert_allclose(bps.bps_encode(mesh, basis), dist[0], atol=1e-12)


def test_bps_many_stacks_objects(sphere: trimesh.Trimesh) -> None:
    basis = bps.basis_points(64)
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    codes = bps.bps_encode_many([sphere, box], basis)
    assert codes.shape == (2, 64)
    # A sphere at the centre: distance = | |b| - r |, up to the facets' sag (< 0.3 mm).
    np.testing.assert_allclose(codes[0], np.abs(np.linalg.norm(basis, axis=1) - 0.05), atol=4e-4)


# ----------------------------------------------------------------------------- GrabNet

TINY_COARSE = dict(bps_dim=32, width=64, hidden=64, latent=4)


def random_grasp(b: int, seed: int = 0) -> grabnet.GraspParams:
    g = torch.Generator().manual_seed(seed)
    return grabnet.GraspParams(
        torch.randn(b, 6, generator=g),
        0.1 * torch.randn(b, 3, generator=g),
        torch.randn(b, 15, 6, generator=g),
    )


def test_coarsenet_shapes_and_size() -> None:
    net = grabnet.CoarseNetConfig(**TINY_COARSE).build()
    bps_code = torch.rand(5, 32)
    out = net(bps_code, random_grasp(5))
    assert out.grasp.global_orient.shape == (5, 6)
    assert out.grasp.transl.shape == (5, 3)
    assert out.grasp.hand_pose.shape == (5, 15, 6)
    assert out.mu.shape == out.logvar.shape == (5, 4)
    full = grabnet.CoarseNetConfig().build()
    assert full.cfg.grasp_dim == 99
    assert 9e6 < n_params(full) < 11e6  # the two 4096-wide BPS inputs dominate
    with pytest.raises(InputError):
        net.encode(torch.rand(5, 31), random_grasp(5))


def test_coarsenet_sampling_is_seeded() -> None:
    net = grabnet.CoarseNetConfig(**TINY_COARSE).build().eval()
    code = torch.rand(3, 32)
    with torch.no_grad():
        a, b, c = (net.sample(code, seed=s).flat() for s in (7, 7, 8))
        g1, g2 = torch.Generator().manual_seed(7), torch.Generator().manual_seed(7)
        d, e = net.sample(code, generator=g1).flat(), net.sample(code, generator=g2).flat()
    torch.testing.assert_close(a, b)
    torch.testing.assert_close(a, d)
    torch.testing.assert_close(d, e)
    assert not torch.allclose(a, c)
    # Decoded rotations are valid 6D: a zero decoder output gives the identity.
    assert torch.isfinite(a).all()


def test_tiny_coarsenet_overfits() -> None:
    torch.manual_seed(0)
    net = grabnet.CoarseNetConfig(**TINY_COARSE).build()
    code = torch.rand(4, 32)
    target = random_grasp(4, seed=1)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    cfg = grabnet.GrabNetLossConfig(w_kl=1e-4)
    first = None
    for _ in range(300):
        out = net(code, target)
        total, terms = grabnet.losses(out.grasp, target, cfg, mu=out.mu, logvar=out.logvar)
        opt.zero_grad()
        total.backward()
        opt.step()
        first = first if first is not None else (terms["pose"] + terms["transl"]).item()
    assert set(terms) == {"pose", "transl", "kl"}
    assert (terms["pose"] + terms["transl"]).item() < 0.05 * first


def test_refinenet_identity_at_init_and_feedback() -> None:
    cfg = grabnet.RefineNetConfig(n_verts=7, width=32, hidden=32)
    net = cfg.build()
    grasp = random_grasp(3)
    seen = []

    def dist_fn(g: grabnet.GraspParams) -> torch.Tensor:
        seen.append(g.transl.clone())
        return g.transl[:, 1:2].expand(-1, 7)

    out = net(grasp, dist_fn)
    assert len(out.steps) == len(out.distances) == 3 == len(seen)
    torch.testing.assert_close(out.grasp.flat(), grasp.flat())  # zero-initialised head
    assert out.distances[0].shape == (3, 7)


def test_refinenet_learns_a_translation_correction() -> None:
    """Distances = height above a plane; the target grasp sits on it. RefineNet must
    learn to remove the height it reads from the distances."""
    torch.manual_seed(0)
    net = grabnet.RefineNetConfig(n_verts=4, width=64, hidden=64, n_iters=2).build()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    on_plane = torch.tensor([1.0, 0.0, 1.0])
    up = torch.tensor([0.0, 1.0, 0.0])

    def dist_fn(g: grabnet.GraspParams) -> torch.Tensor:
        return g.transl[:, 1:2].expand(-1, 4)

    def grasps(b: int, seed: int) -> grabnet.GraspParams:
        # identity rotations, random positions on the plane y = 0
        g = torch.Generator().manual_seed(seed)
        eye = torch.tensor(grabnet.IDENTITY_6D)
        transl = 0.1 * torch.randn(b, 3, generator=g) * on_plane
        return grabnet.GraspParams(eye.repeat(b, 1), transl, eye.repeat(b, 15, 1))

    for i in range(200):
        target = grasps(64, seed=i)
        noisy = target._replace(transl=target.transl + up * 0.03 * torch.randn(64, 1))
        loss = sum(grabnet.losses(s, target)[0] for s in net(noisy, dist_fn).steps)
        opt.zero_grad()
        loss.backward()
        opt.step()
    net.eval()
    target = grasps(16, seed=10**6)
    for offset in (0.02, -0.02):
        with torch.no_grad():
            refined = net(target._replace(transl=target.transl + up * offset), dist_fn).grasp
        assert refined.transl[:, 1].abs().mean() < 0.2 * 0.02


def test_grabnet_losses_terms(hand: ProceduralHand) -> None:
    hand_fn = grabnet.make_hand_fn(hand)
    eye = torch.tensor(grabnet.IDENTITY_6D)
    target = grabnet.GraspParams(eye.repeat(2, 1), torch.zeros(2, 3), eye.repeat(2, 15, 1))
    shifted = target._replace(transl=torch.tensor([[0.0, 0.01, 0.0]] * 2, requires_grad=True))

    def sdf(points: torch.Tensor) -> torch.Tensor:
        # a ball of radius 3 cm around the palm, differentiable
        return (points - torch.tensor([-0.05, -0.01, 0.0])).norm(dim=-1) - 0.03

    cfg = grabnet.GrabNetLossConfig(w_contact=1.0, w_penetration=1.0, w_edge=1.0)
    zeros = torch.zeros(2, 16)
    total, terms = grabnet.losses(
        shifted, target, cfg, hand_fn=hand_fn, mu=zeros, logvar=zeros, sdf=sdf, faces=hand.faces
    )
    total.backward()  # every term is differentiable in the prediction
    assert shifted.transl.grad is not None
    terms = {k: v.item() for k, v in terms.items()}
    assert terms["vertex"] == pytest.approx(0.01 / 3, rel=1e-4)  # one axis of three moved 1 cm
    assert terms["transl"] == pytest.approx(1e-4, rel=1e-4)
    assert terms["edge"] == pytest.approx(0.0, abs=1e-7)  # a translation keeps edges
    assert terms["kl"] == pytest.approx(0.0)
    assert terms["penetration"] > 0 and terms["contact"] > 0


def test_distance_fn_and_differentiable_sdf(
    hand: ProceduralHand, sphere_field: DistanceField
) -> None:
    ids = hand.proximity_ids
    grasp = grabnet.GraspParams(
        torch.tensor([grabnet.IDENTITY_6D]).double(),
        torch.tensor([[0.03, 0.07, 0.0]]).double(),
        torch.tensor(grabnet.IDENTITY_6D).repeat(1, 15, 1).double(),
    )
    d = grabnet.make_distance_fn(hand, sphere_field.exact_signed_distance, ids)(grasp)
    assert d.shape == (1, 99)
    verts = hand(torch.zeros(1, 3), torch.zeros(1, 15, 3), grasp.transl.float())[0][
        0, list(ids)
    ].double()
    np.testing.assert_allclose(
        d[0].numpy(), sphere_field.exact_signed_distance(verts.numpy()), atol=1e-4
    )
    pts = torch.tensor(
        [[0.07, 0.01, 0.0], [0.0, -0.02, 0.08]], dtype=torch.float64, requires_grad=True
    )
    sdf = grabnet.sdf_with_gradient(sphere_field)
    sdf(pts).sum().backward()
    unit = pts.detach() / pts.detach().norm(dim=-1, keepdim=True)
    torch.testing.assert_close(pts.grad, unit, atol=0.02, rtol=0)


# ----------------------------------------------------------------------------- TOCH


def reference_hits(
    mesh: trimesh.Trimesh, origins: np.ndarray, dirs: np.ndarray, max_dist: float
) -> tuple[np.ndarray, np.ndarray]:
    """trimesh ray casting + containment: the module's rule written the slow way."""
    inside = mesh.contains(origins)
    t = np.full(len(origins), np.nan)
    face = np.full(len(origins), -1)
    for sign in (1.0, -1.0):
        loc, ray, tri = mesh.ray.intersects_location(origins, sign * dirs, multiple_hits=True)
        for i in range(len(origins)):
            if inside[i] != (sign < 0):
                continue
            sel = ray == i
            if sel.any():
                ts = (loc[sel] - origins[i]) @ (sign * dirs[i])
                k = np.argmin(ts)
                if ts[k] <= max_dist:
                    t[i], face[i] = sign * ts[k], tri[sel][k]
    return t, face


def test_ray_hits_match_trimesh(hand: ProceduralHand) -> None:
    v = hand.template_vertices.double().numpy()
    mesh = trimesh.Trimesh(v, hand.faces, process=False)
    rng = np.random.default_rng(0)
    o = rng.uniform([-0.2, -0.05, -0.06], [0.03, 0.03, 0.08], (300, 3))
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, face, bary = toch.ray_mesh_hits(o, d, v, hand.faces, max_dist=0.05)
    t_ref, face_ref = reference_hits(mesh, o, d, 0.05)
    assert (face >= 0).sum() > 30 and (t < 0).sum() > 5  # outside and inside cases both seen
    np.testing.assert_array_equal(face, face_ref)
    np.testing.assert_allclose(t[face >= 0], t_ref[face >= 0], atol=1e-12)
    hit_points = np.einsum("nk,nkc->nc", bary, v[hand.faces[np.maximum(face, 0)]])
    np.testing.assert_allclose(hit_points[face >= 0], (o + t[:, None] * d)[face >= 0], atol=1e-12)


def palm_setup(
    hand: ProceduralHand, gap: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Flat right hand (palm down, -y) with its chosen palm vertices ``gap`` above y = 0."""
    canon = hand.template_vertices.double().numpy()
    normals = trimesh.Trimesh(canon, hand.faces, process=False).vertex_normals
    palm = hand.part_labels == 0
    chosen = np.nonzero(
        palm & (normals[:, 1] < -0.97) & (canon[:, 2] < -0.005) & (canon[:, 0] > -0.06)
    )[0]
    lift = gap - canon[chosen, 1].min()
    return canon, canon + [0.0, lift, 0.0], chosen, lift


@pytest.mark.parametrize("gap", [0.01, -0.003])
def test_correspondence_field_palm_over_plane(hand: ProceduralHand, gap: float) -> None:
    canon, posed, chosen, lift = palm_setup(hand, gap)
    assert len(chosen) > 10
    under = canon[chosen] * [1.0, 0.0, 1.0]  # on the plate's top face y = 0
    far = np.array([[0.15, 0.0, 0.15], [-0.1, 0.0, 0.3]])  # outside the hand's footprint
    bottom = under[:3] - [0.0, 0.01, 0.0]  # the plate's bottom face, normal -y
    pts = np.concatenate([under, far, bottom])
    nrm = np.concatenate(
        [np.tile([0.0, 1.0, 0.0], (len(under) + 2, 1)), np.tile([0.0, -1.0, 0.0], (3, 1))]
    )
    field = toch.correspondence_field(pts, nrm, posed, hand.faces, canon)
    n = len(under)
    assert field.hit[:n].all() and not field.hit[n:].any()
    expected = canon[chosen, 1] + lift  # height of each vertex above the plate
    np.testing.assert_allclose(field.distance[:n], expected, atol=1e-9)
    assert field.distance[:n].min() == pytest.approx(gap, abs=1e-9)
    if gap < 0:
        assert (field.distance[:n] < 0).any()  # penetration reads negative
    np.testing.assert_allclose(field.canonical[:n], canon[chosen], atol=1e-7)
    assert (hand.part_labels[hand.faces[field.face[:n]]] == 0).all()  # on the palm
    assert field.as_array().shape == (len(pts), 5)


def test_temporal_ae_shapes_and_loss() -> None:
    torch.manual_seed(0)
    cfg = toch.TemporalAEConfig(local_dim=16, frame_dim=32, gru_hidden=16)
    net = cfg.build()
    b, t, n = 2, cfg.window, 64
    pts, nrm = (
        torch.randn(b, t, n, 3) * 0.05,
        torch.nn.functional.normalize(torch.randn(b, t, n, 3), dim=-1),
    )
    field = torch.cat([(torch.rand(b, t, n, 1) > 0.5).float(), 0.05 * torch.randn(b, t, n, 4)], -1)
    out = net(pts, nrm, field)
    assert out.shape == (b, t, n, 5)
    total, terms = toch.field_losses(out, field)
    total.backward()
    assert set(terms) == {"hit", "distance", "correspondence"}
    assert net.gru.weight_ih_l0.grad.abs().sum() > 0
    full = toch.TemporalAEConfig().build()
    assert n_params(full) > 5e5
    with pytest.raises(InputError):
        net(pts, nrm, field[..., :4])


def test_fit_recovers_translation_offset(hand: ProceduralHand) -> None:
    canon, posed, _, lift = palm_setup(hand, 0.01)
    xs, zs = np.meshgrid(np.linspace(-0.08, 0.0, 12), np.linspace(-0.04, 0.03, 10))
    pts = np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], 1)
    nrm = np.tile([0.0, 1.0, 0.0], (len(pts), 1))
    n_frames = 3
    gt_transl = torch.tensor(
        [[0.0, lift, 0.0], [0.002, lift + 0.001, 0.0], [0.004, lift + 0.002, 0.0]]
    )
    fields = [
        toch.correspondence_field(pts, nrm, canon + gt_transl[k].numpy(), hand.faces, canon)
        for k in range(n_frames)
    ]
    zeros = torch.zeros(n_frames, 3, dtype=torch.float64)
    pose = torch.zeros(n_frames, 15, 3, dtype=torch.float64)
    offset = torch.tensor([0.004, -0.003, 0.002], dtype=torch.float64)
    result = toch.fit_hand_to_field(
        np.stack([pts] * n_frames),
        np.stack([nrm] * n_frames),
        np.stack([f.hit for f in fields]),
        np.stack([f.distance for f in fields]),
        np.stack([f.canonical for f in fields]),
        lambda go, p, tr: hand(go, p, tr)[0],
        canon,
        hand.faces,
        zeros,
        pose,
        gt_transl.double() + offset,
        toch.FitConfig(n_iters=120),
    )
    err = (result.transl - gt_transl.double()).norm(dim=-1)
    assert err.max() < 3e-4, err  # from 5.4 mm to below 0.3 mm
    assert result.losses[-1] < 0.01 * result.losses[0]


# ----------------------------------------------------------------------------- ManipNet


def rotation(seed: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.random(random_state=seed).as_matrix()


def test_manipnet_voxels_match_brute_force(
    hand: ProceduralHand, sphere: trimesh.Trimesh, sphere_field: DistanceField
) -> None:
    n = 4
    wrist_rot = np.stack([rotation(s) for s in range(n)])
    wrist_pos = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.03, 0.02, 0.0], [0.05, 0.0, 0.01]])
    obj_rot = np.stack([rotation(10 + s) for s in range(n)])
    # Put the object where the grid is: the grid centre of each frame, nudged.
    centre = np.asarray(manipnet.voxel_centres()).reshape(-1, 3).mean(0)
    obj_pos = np.einsum("fij,j->fi", wrist_rot, centre) + wrist_pos + 0.01
    feats = manipnet.manipnet_features(
        wrist_rot,
        wrist_pos,
        obj_rot,
        obj_pos,
        np.zeros((n, 15, 3)),
        sphere_field.signed_distance,
        manipnet.hand_proximity_fn(hand),
    )
    cells = manipnet.voxel_centres()
    r = cells.shape[0]
    checked = 0
    for f in range(n):
        for i in range(r):
            for j in range(r):
                for k in range(r):
                    world = wrist_rot[f] @ cells[i, j, k] + wrist_pos[f]
                    local = obj_rot[f].T @ (world - obj_pos[f])
                    sd = float(sphere_field.exact_signed_distance(local[None])[0])
                    if abs(sd) > 1e-4:  # the grid SDF may round cells on the surface
                        assert feats.voxels[f, i, j, k] == float(sd < 0), (f, i, j, k, sd)
                        checked += 1
    assert checked > 0.99 * n * r**3
    assert 0 < feats.voxels.sum() < feats.voxels.size  # both occupied and free cells


def test_manipnet_features_and_forward(hand: ProceduralHand, sphere_field: DistanceField) -> None:
    n = 6
    t = np.linspace(0, 1, n)
    wrist_rot = np.stack([rotation(0)] * n)
    wrist_pos = np.stack([t * 0.1, np.zeros(n), np.zeros(n)], 1)
    obj_rot, obj_pos = np.stack([np.eye(3)] * n), np.tile([0.0, -0.1, 0.0], (n, 1))
    cfg = manipnet.ManipNetConfig(n_past=2, n_future=3, width=32, hidden=32, dropout=0.0)
    feats = manipnet.manipnet_features(
        wrist_rot,
        wrist_pos,
        obj_rot,
        obj_pos,
        np.zeros((n, 15, 3)),
        sphere_field.signed_distance,
        manipnet.hand_proximity_fn(hand),
        frames=[0, 3],
        cfg=cfg,
    )
    assert feats.traj.shape == (2, 5, 9)
    assert feats.voxels.shape == (2, 8, 8, 8)
    assert feats.distances.shape == (2, 4, 99)
    assert feats.prev_pose.shape == (2, 15, 6)
    # Frame 0: past frames clamp to frame 0 -> zero offset and identity rotation.
    np.testing.assert_allclose(feats.traj[0, :2, :3], 0.0, atol=1e-12)
    np.testing.assert_allclose(feats.traj[0, :2, 3:], [grabnet.IDENTITY_6D] * 2, atol=1e-12)
    # Frame 3, one frame ahead: the world step (0.02, 0, 0) seen from the wrist.
    np.testing.assert_allclose(feats.traj[1, 2, :3], wrist_rot[0].T @ [0.02, 0.0, 0.0], atol=1e-12)
    assert np.abs(feats.distances).max() <= 0.1
    net = cfg.build()
    out = net(*feats.torch())
    assert out.shape == (2, 15, 6)
    torch.testing.assert_close(out, feats.torch()[3])  # zero-initialised residual head
    full = manipnet.ManipNetConfig().build()
    assert full.cfg.in_dim == 20 * 9 + 512 + 11 * 99 + 90


def test_manipnet_motion_features_of_all_frames_equal_the_per_frame_features(
    hand: ProceduralHand, sphere_field: DistanceField
) -> None:
    """The rollout's trajectory and occupancy, computed for every frame at once, are
    bit for bit what ``manipnet_features(frames=[t])`` (the naive per-frame reference the
    rollout called before) gives for each frame; so are the pose features of one frame."""
    n = 9
    wrist_rot = np.stack([rotation(s) for s in range(n)])
    wrist_pos = np.cumsum(np.full((n, 3), 0.01), 0)
    obj_rot = np.stack([rotation(20 + s) for s in range(n)])
    centre = np.asarray(manipnet.voxel_centres()).reshape(-1, 3).mean(0)
    obj_pos = np.einsum("fij,j->fi", wrist_rot, centre) + wrist_pos + 0.01
    prev = 0.2 * np.random.default_rng(0).normal(size=(n, 15, 3))
    cfg = manipnet.ManipNetConfig(n_past=3, n_future=2)
    args = (wrist_rot, wrist_pos, obj_rot, obj_pos)
    prox = manipnet.hand_proximity_fn(hand)
    traj, voxels = manipnet.motion_features(*args, sphere_field.signed_distance, np.arange(n), cfg)
    assert 0 < voxels.sum() < voxels.size
    for t in range(n):
        want = manipnet.manipnet_features(*args, prev, sphere_field.signed_distance, prox,
                                          frames=[t], cfg=cfg)
        assert np.array_equal(traj[t : t + 1], want.traj)
        assert np.array_equal(voxels[t : t + 1], want.voxels)
        dist, prev6 = manipnet.pose_features(*args, prev, sphere_field.signed_distance, prox,
                                             np.array([t]), cfg)
        assert np.array_equal(dist, want.distances) and np.array_equal(prev6, want.prev_pose)
