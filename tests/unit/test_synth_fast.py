"""SynthGRAB's shortcuts give the answers of the plain computations."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from grip_bench.core.constants import CONTACT_THRESHOLD
from grip_bench.core.frames import SIDES
from grip_bench.data.synth import episode as E
from grip_bench.data.synth import grasp as G
from grip_bench.data.synth import scene as S
from grip_bench.data.synth.caches import ObjectTools, hand_models
from grip_bench.data.synth.contact import _posed_hands, contact_labels, repeats, to_object_rows
from grip_bench.data.synth.grasp_plan import approach_dirs
from grip_bench.data.synth.objects import make_instance
from grip_bench.data.synth.world import make_subjects


@pytest.fixture(scope="module")
def episode():
    """A one-hand lift of a cube: the episode, its posed hands (side -> (T, V, 3)), the
    object's tools and the subject."""
    inst = make_instance("cubemedium", np.random.default_rng(0), 0)
    tools = ObjectTools(inst)
    sub = make_subjects(4, 0)[0]
    ep = E.make_episode(sub, inst, "lift", 3, tools)
    return ep, _posed_hands(hand_models(sub.hand_scale), ep.motion), tools, sub


def test_distance_bound_is_below_the_field_and_exact_under_the_threshold():
    inst = make_instance("mug", np.random.default_rng(0), 0)
    tools = ObjectTools(inst)
    rng = np.random.default_rng(1)
    lo, hi = inst.mesh.bounds
    p = rng.uniform(lo - 0.06, hi + 0.06, size=(20000, 3))
    sd = tools.df.signed_distance(p, far="bound")
    near = sd < 0.03  # (beyond 3 cm the bound may read a nearer node: above any threshold anyway)
    assert near.sum() > 3000 and (tools.bound.lower(p[near]) <= sd[near] + 1e-12).all()
    for above in (G.GAP, CONTACT_THRESHOLD):
        fast = tools.bound.signed_distance(tools.df, p, above)
        assert np.array_equal(fast <= above, sd <= above)
        assert np.array_equal(fast[sd <= above], sd[sd <= above])


def test_contact_labels_from_repeated_frames_equal_the_frame_by_frame_labels(episode):
    ep, verts, tools, sub = episode
    hands = hand_models(sub.hand_scale)
    v_obj = {
        s: np.einsum("tvj,tjk->tvk", verts[s] - ep.motion.obj_p[:, None], ep.motion.obj_R)
        for s in SIDES
    }
    plain = contact_labels(v_obj, ep.contacts, hands, np.asarray(tools.contact_mesh.vertices))
    assert np.array_equal(plain, ep.sequence.contact["object"])
    rep = repeats(v_obj[sub.dominant])
    held = ep.motion.attached[sub.dominant]
    assert len(np.unique(rep[held])) < held.sum() / 3  # a held hand does not move on the object


def test_sphere_tracing_stops_at_the_gap():
    inst = make_instance("cylindermedium", np.random.default_rng(0), 0)
    tools = ObjectTools(inst)
    synth = tools.synth(1.0)
    dirs = approach_dirs("right", False)
    R, _ = synth._orientations("right", dirs, np.array([0.0, 0.0, 1.0]), "power")
    full, _, sub = G._light_hand("right", 1.0)
    local0 = np.broadcast_to(G.preshape_local("power"), (len(R), 15, 3)).copy()
    t = synth._place(sub, R, local0, synth.centre, R @ full.palm_normal, "power")
    ok = np.isfinite(t).all(1)
    assert ok.sum() > len(R) // 2
    v, _ = G._pose(sub, R[ok], t[ok], local0[ok])
    gap = tools.df.signed_distance(v.reshape(-1, 3), far="bound").reshape(ok.sum(), -1).min(1)
    # (the grid field is 1-Lipschitz up to its interpolation: some um of undershoot)
    assert (gap > G.GAP - 5e-5).all() and (gap < G.GAP + 3e-4).all()


def _table_clearance_whole(v: np.ndarray, scene) -> np.ndarray:
    """Reference: scene.table_clearance's formula on every frame (the pre-shortcut code)."""
    local = (v - scene.table_p) @ scene.table_R
    y = local[..., 1]
    inset = np.minimum(S.TABLE_SIZE[0] / 2 - np.abs(local[..., 0]),
                       S.TABLE_SIZE[1] / 2 - np.abs(local[..., 2]))
    over = inset >= 0
    above = over & (y >= 0)
    inside = over & (y < 0) & (y > -S.TABLE_THICKNESS)
    depth = np.minimum(np.minimum(-y, y + S.TABLE_THICKNESS), inset)
    gap = np.where(above, y, np.where(inside, -depth, np.inf)).min(-1)
    if len(v) > 1:
        below = over & (y <= -S.TABLE_THICKNESS)
        crossed = ((above[1:] & below[:-1]) | (below[1:] & above[:-1])).any(-1)
        gap[1:] = np.where(crossed, np.minimum(gap[1:], -S.TABLE_THICKNESS / 2), gap[1:])
    return gap


def test_table_clearance_equals_the_whole_formula_bit_for_bit(episode):
    ep, verts, _, _ = episode
    scene = ep.cast.scene
    cases = [verts[s] for s in SIDES]
    # table-frame points on and around every boundary: the footprint's edges (|x| = w/2 in
    # the table frame), the top (y = 0, -0.0), the slab's bottom, under it, NaN, and frames
    # that step from above the top to under the slab and back (the crossing term)
    rng = np.random.default_rng(5)
    hx, hz, th = S.TABLE_SIZE[0] / 2, S.TABLE_SIZE[1] / 2, S.TABLE_THICKNESS
    xs = np.array([-hx, hx, np.nextafter(hx, 1), np.nextafter(hx, 0), 0.0, 0.3, -1.0])
    ys = np.array([0.0, -0.0, 1e-4, -1e-4, -th, np.nextafter(-th, 0), -th - 0.01, 0.2, -0.5])
    zs = np.array([-hz, hz, np.nextafter(hz, 1), 0.0, -0.2, 0.9])
    for T in (1, 2, 40):
        local = np.stack([rng.choice(xs, (T, 60)), rng.choice(ys, (T, 60)),
                          rng.choice(zs, (T, 60))], -1)
        local[rng.random((T, 60)) < 0.02, 1] = np.nan
        # back to the world: local = (v - p) @ R, so v = local @ R^T + p (rounding moves the
        # points by ulps, which is what every frame of the pipeline sees too)
        cases.append(local @ scene.table_R.T + scene.table_p)
        cases.append(local)  # table-frame numbers as given, with an identity-like scene
    swing = np.zeros((6, 3, 3))
    swing[:, :, 0] = 0.1
    swing[:, :, 1] = np.array([0.05, -0.06, 0.05, -0.01, -0.06, 0.2])[:, None]
    cases.append(swing @ scene.table_R.T + scene.table_p)
    deep = 0
    for v in cases:
        for sc in (scene, dataclasses.replace(scene, table_R=np.eye(3), table_p=np.zeros(3))):
            want = _table_clearance_whole(v, sc)
            got = S.table_clearance(v, sc)
            assert got.tobytes() == want.tobytes()
            deep += int((want < 0).sum())
    assert deep > 50  # the slab and crossing terms were exercised


def test_object_rows_equal_einsum_bit_for_bit(episode):
    ep, verts, _, _ = episode
    mo = ep.motion
    rng = np.random.default_rng(2)
    cases = [(verts[s], mo.obj_R, mo.obj_p) for s in SIDES]
    R = np.linalg.qr(rng.normal(size=(7, 3, 3)))[0]
    cases.append((rng.normal(size=(7, 300, 3)), R, rng.normal(size=(7, 3))))
    zeros = np.zeros((2, 4, 3))
    zeros[0] = -0.0  # -0.0 products: einsum's sum starts from +0.0
    cases.append((zeros, -np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3))))
    for v, R, p in cases:
        want = np.einsum("tvj,tjk->tvk", v - p[:, None], R)
        assert to_object_rows(v, R, p).tobytes() == want.tobytes()
