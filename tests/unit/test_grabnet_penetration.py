"""GrabNet's contact and penetration losses on the object distance field (GRAB Sec. 4)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from grip_baselines import grabnet
from grip_baselines.grabnet_method import DistanceFeed, field_distance_and_gradient

from grip_bench.bodies.hand import ProceduralHand
from grip_bench.geometry.distance import DistanceField

RADIUS = 0.04


pytestmark = pytest.mark.usefixtures("one_thread")  # the 2 test cores are shared


class _Library:
    """The two things DistanceFeed reads of an ObjectLibrary, for one sphere."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        self._mesh, self._field = mesh, DistanceField(mesh)

    def field(self, name: str) -> DistanceField:
        return self._field

    def mesh(self, name: str) -> trimesh.Trimesh:
        return self._mesh


@pytest.fixture(scope="module")
def hand() -> ProceduralHand:
    return ProceduralHand("right")


@pytest.fixture(scope="module")
def ball() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)


def flat_grasp(transl: np.ndarray) -> grabnet.GraspParams:
    """Flat right hands (identity wrist) at wrist positions ``transl (B, 3)``, float64."""
    transl = torch.as_tensor(np.asarray(transl, float))
    b = len(transl)
    eye = torch.tensor(grabnet.IDENTITY_6D, dtype=torch.float64)
    return grabnet.GraspParams(eye.repeat(b, 1), transl, eye.repeat(b, 15, 1))


def naive_penetration(mesh: trimesh.Trimesh, vertices: np.ndarray) -> float:
    """Mean depth of the vertices inside ``mesh``: trimesh's exact signed distance
    (positive inside), per vertex, the slow way."""
    depth = np.stack([trimesh.proximity.signed_distance(mesh, v) for v in vertices])
    return float(np.maximum(depth, 0.0).mean())


def test_penetration_loss_zero_outside_and_positive_inside(
    hand: ProceduralHand, ball: trimesh.Trimesh
) -> None:
    """Penetration loss through the training pipeline's distance feed (object library
    field, model -> object frame map), against a naive per-vertex computation."""
    ids = np.arange(0, hand.num_vertices, 7)
    hand_fn = grabnet.make_hand_fn(hand, ids)
    centre = hand.template_vertices.double().numpy()[ids].mean(0)
    # Wrist positions that put the hand's centre 30 cm away (outside), on the ball's
    # surface (some vertices inside) and at the ball's centre (deep inside).
    place = np.array([[0.3, 0.0, 0.0], [0.0, RADIUS, 0.0], [0.0, 0.0, 0.0]]) - centre
    grasp = flat_grasp(place)
    # Model frame = object frame shifted by b; a rotated A must not matter for distances.
    A = np.tile(np.eye(3), (3, 1, 1))
    b = np.zeros((3, 3))
    feed = DistanceFeed(_Library(ball), ["ball"], np.zeros(3, int), A, b, hand, hand.proximity_ids)
    with torch.no_grad():
        verts = hand_fn(grasp)  # (3, K, 3)
    pen = [
        grabnet.penetration_loss(feed.subset([i]).sdf(verts[i : i + 1])).item() for i in range(3)
    ]
    naive = [naive_penetration(ball, verts[i : i + 1].numpy()) for i in range(3)]
    assert pen[0] == 0.0 and naive[0] == 0.0
    assert 0 < pen[1] < pen[2]
    np.testing.assert_allclose(pen, naive, atol=2e-4)  # the field's grid vs exact (< 0.2 mm)

    # The gradient pushes inside vertices outwards: one step of gradient descent lowers it.
    one = feed.subset([1])
    pts = verts[1:2].clone().requires_grad_(True)
    grabnet.penetration_loss(one.sdf(pts)).backward()
    inside = one.distance(pts.detach())[0] < 0
    outward = pts.detach()[0, inside] / pts.detach()[0, inside].norm(dim=-1, keepdim=True)
    assert ((-pts.grad[0, inside] * outward).sum(-1) > 0).all()
    assert (pts.grad[0, ~inside] == 0).all()
    moved = pts.detach() - 0.002 * pts.grad / pts.grad.abs().max()
    assert grabnet.penetration_loss(one.sdf(moved)).item() < pen[1]


def test_contact_loss_reads_gt_contact_vertices_only() -> None:
    d = torch.tensor([[0.01, -0.002, 0.3], [0.0, 0.5, 0.02]])
    contact = torch.tensor([[True, True, False], [False, False, True]])
    assert grabnet.contact_loss(d, contact).item() == pytest.approx((0.01 + 0.002 + 0.02) / 3)
    assert grabnet.contact_loss(d, torch.zeros_like(contact)).item() == 0.0


def test_field_gradient_near_and_far(ball: trimesh.Trimesh) -> None:
    field = DistanceField(ball)
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    radii = np.concatenate([rng.uniform(0.0, 0.5, 100), rng.uniform(0.025, 0.06, 100)])
    q = dirs * radii[:, None]
    d, g = field_distance_and_gradient(field, q)
    near = np.abs(radii - RADIUS) < 0.015  # within the field's exact band
    assert near.sum() > 50
    np.testing.assert_allclose(d[near], radii[near] - RADIUS, atol=5e-4)
    near = radii < RADIUS + 0.02
    assert (d[~near] > 0).all() and (d[~near] <= radii[~near] - RADIUS + 5e-4).all()  # a bound
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-6)
    away = radii > 0.01  # the gradient points away from the centre (box or sphere)
    assert ((g[away] * dirs[away]).sum(1) > 0.5).all()
