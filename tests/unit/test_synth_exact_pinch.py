"""SynthGRAB's exact pinches (``grasp.EXACT_PINCHES``, on since 2.4): opposing contact pairs on
an analytic box, the wrist frames that put the pads on them, and whole pinches of a cube and a
cylinder whose pads press on opposite faces (reference: the box's own geometry)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from grip_bench.core.constants import CONTACT_THRESHOLD
from grip_bench.data.synth import grasp as G
from grip_bench.geometry.distance import DistanceField

from .test_synth_grasp import _approach_dirs, _synth

BOX = (0.05, 0.04, 0.06)  # m: x, y (up), z


@pytest.fixture(scope="module")
def box():
    mesh = trimesh.creation.box(extents=BOX)
    df = DistanceField(mesh)
    return mesh, G.GraspSynthesizer(mesh, df, 1.0, rest_height=BOX[1] / 2,
                                    grasp_hint="precision")


def test_opposing_pairs_of_a_box_are_across_opposite_faces(box):
    mesh, gs = box
    p1, p2 = gs.opposing_pairs("precision")
    assert 0 < len(p1) <= G.EXACT_PAIRS
    half = np.asarray(BOX) / 2
    for a, b in zip(p1, p2, strict=True):
        axis = int(np.argmax(np.abs(b - a)))
        # a face point and its mirror across the box, the pinch line along the face normal
        assert abs(abs(a[axis]) - half[axis]) < 1e-6
        assert abs(b[axis] + a[axis]) < 1.5e-3
        np.testing.assert_allclose(np.delete(b - a, axis), 0.0, atol=1e-9)
        assert np.linalg.norm(b - a) <= G.PINCH_WIDTH["precision"] + 1e-9
        assert min(a[1], b[1]) > -half[1] + G.EXACT_TABLE_ROOM  # room above the table
    # the y extent (40 mm) is a pinch from above and below: the table's face is not one
    assert not any(int(np.argmax(np.abs(b - a))) == 1 for a, b in zip(p1, p2, strict=True))
    # nearest the centre of mass first (a box's centre: the axis offset from the origin)
    u = (p2 - p1) / np.linalg.norm(p2 - p1, axis=1, keepdims=True)
    off = np.linalg.norm(-p1 - np.einsum("ij,ij->i", -p1, u)[:, None] * u, axis=1)
    assert np.all(np.diff(off) >= -1e-12) and off[0] < 4e-3  # 800 samples: a few mm off
    q1, q2 = gs.opposing_pairs("precision")
    np.testing.assert_array_equal(p1, q1)  # deterministic (and cached)


def test_pinch_frames_put_the_pads_on_the_pair(monkeypatch):
    monkeypatch.setattr(G, "EXACT_MAX_ROLL", np.pi)  # the geometry here; the roll cap below
    thumb = np.array([[0.0, -0.05, 0.03], [0.0, -0.05, 0.04]])
    index = np.array([[-0.03, -0.06, 0.05], [-0.04, -0.07, 0.07]])
    width = np.linalg.norm(index - thumb, axis=1)
    a, b = np.array([[0.01, 0.0, 0.0]]), np.array([[-0.01, 0.0, 0.0]])
    dirs = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    R, t, pose, roll = G._pinch_frames("right", a, b, dirs, np.array([0.0, 0.0, 1.0]),
                                       thumb, index, width)
    assert len(R) == 2  # the approach along the axis (+x) is skipped
    for Ri, ti, k in zip(R, t, pose, strict=True):
        assert k == int(np.argmin(np.where(width >= 0.02 + 2 * G.EXACT_CLEARANCE, width, 9)))
        np.testing.assert_allclose(Ri @ Ri.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(Ri) == pytest.approx(1.0)
        th, ix = Ri @ thumb[k] + ti, Ri @ index[k] + ti
        np.testing.assert_allclose(0.5 * (th + ix), 0.0, atol=1e-12)  # midpoint on the pair's
        u = (ix - th) / np.linalg.norm(ix - th)
        np.testing.assert_allclose(u, [-1.0, 0.0, 0.0], atol=1e-12)  # thumb at a, index at b
    # the palm faces along each approach (its normal, -y in the hand frame, across the axis)
    palms = R @ np.array([0.0, -1.0, 0.0])
    across = palms - palms[:, :1] * np.array([1.0, 0.0, 0.0])
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    np.testing.assert_allclose(across, [[0.0, -1.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-9)
    # the roll: the fingers' angle (-x in the hand frame) off finger_ref (+z) in the palm plane
    ref = np.array([0.0, 0.0, 1.0])
    f = R @ np.array([-1.0, 0.0, 0.0])
    f0 = ref - (palms @ ref)[:, None] * palms
    f0 /= np.linalg.norm(f0, axis=1, keepdims=True)
    np.testing.assert_allclose(roll, np.arccos(np.clip(np.einsum("ij,ij->i", f, f0), -1, 1)),
                               atol=1e-9)
    monkeypatch.setattr(G, "EXACT_MAX_ROLL", float(roll.min()) + 1e-9)
    assert len(G._pinch_frames("right", a, b, dirs, np.array([0.0, 0.0, 1.0]), thumb, index,
                               width)[0]) == 1  # the larger roll is left out


def test_turn_onto_takes_one_unit_vector_onto_another():
    rng = np.random.default_rng(0)
    for a, b in [rng.normal(size=(2, 3)) for _ in range(5)] + [
            (np.array([1.0, 0, 0]), np.array([-1.0, 0, 0])),
            (np.array([0.0, 1, 0]), np.array([0.0, 1, 0]))]:
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        R = G._turn_onto(a, b)
        np.testing.assert_allclose(R @ a, b, atol=1e-12)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("name,kind", [("cubesmall", "precision"), ("spheresmall", "tripod")])
def test_exact_pinch_presses_opposite_sides(monkeypatch, name, kind):
    torch.set_num_threads(1)
    monkeypatch.setattr(G, "EXACT_PINCHES", True)
    obj, df, gs = _synth(name)
    side = "right"
    dirs = gs._steepen(_approach_dirs(side))
    g = gs._exact_pinch(side, dirs, np.array([0.0, 0.0, 1.0]), np.random.default_rng(1), kind,
                        True, None, 1.0)
    assert g is not None and g.kind == kind
    hand = G._light_hand(side, 1.0)[0]
    local = hand.to_local(torch.as_tensor(g.hand_pose))[None].numpy()
    v = G._pose(hand, g.R[None], g.t[None], local)[0][0]
    sd = df.exact_signed_distance(v)  # independent of the search's grid
    assert -sd.min() <= G.MAX_PENETRATION + 2e-4
    assert v[:, 1].min() > -obj.rest_height  # above the table top
    thumb_pad, index_pad = G._pad_ids()
    # the two pads touch, on opposite sides of the object (their outward normals opposed)
    assert sd[thumb_pad] <= CONTACT_THRESHOLD and sd[index_pad] <= CONTACT_THRESHOLD
    n = df.gradient(v[[thumb_pad, index_pad]])
    assert float(n[0] @ n[1]) < np.cos(np.radians(150.0))
    # and the search picks it when exact pinches are on
    g2 = gs.search(side, _approach_dirs(side), np.array([0.0, 0.0, 1.0]),
                   np.random.default_rng(1), kind=kind)
    np.testing.assert_array_equal(g2.hand_pose, g.hand_pose)


def test_exact_pinches_are_on_since_2_4():
    assert G.EXACT_PINCHES is True
