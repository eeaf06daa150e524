"""SynthGRAB's shortcuts give the answers of the plain computations."""

from __future__ import annotations

import numpy as np

from grip_bench.core.constants import CONTACT_THRESHOLD
from grip_bench.core.frames import SIDES
from grip_bench.data.synth import episode as E
from grip_bench.data.synth import grasp as G
from grip_bench.data.synth.caches import ObjectTools, hand_models
from grip_bench.data.synth.contact import _posed_hands, contact_labels, repeats
from grip_bench.data.synth.grasp_plan import approach_dirs
from grip_bench.data.synth.objects import make_instance
from grip_bench.data.synth.world import make_subjects


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


def test_contact_labels_from_repeated_frames_equal_the_frame_by_frame_labels():
    inst = make_instance("cubemedium", np.random.default_rng(0), 0)
    tools = ObjectTools(inst)
    sub = make_subjects(4, 0)[0]
    ep = E.make_episode(sub, inst, "lift", 3, tools)
    hands = hand_models(sub.hand_scale)
    verts = _posed_hands(hands, ep.motion)
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
