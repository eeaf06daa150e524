"""SynthGRAB hook grasps: the fingers curled round a handle, the palm and thumb off it.

Hooks are admitted on free bars (a frying pan's handle); a mug's loop is not hooked (measured:
the curled fingers clear its thin bar and close on the body behind it)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from grip_bench.core.constants import CONTACT_THRESHOLD
from grip_bench.data.synth import grasp as G
from grip_bench.data.synth.caches import ObjectTools
from grip_bench.data.synth.objects import make_instance

FINGERS = {"index": 2, "middle": 3, "ring": 4, "pinky": 5}  # HAND_PARTS ids


@pytest.fixture(scope="module")
def pan():
    inst = make_instance("fryingpan", np.random.default_rng(1), 0, variation=True)
    return inst, ObjectTools(inst)


def _handle_dirs(synth: G.GraspSynthesizer) -> np.ndarray:
    """Object->hand directions (9, 3) around the handle's outward side (the scene turns the
    handle towards the hand), three azimuths, three elevations (m: unit vectors)."""
    u = np.asarray(synth.handles[0].point) - synth.centre
    u[1] = 0.0
    u /= np.linalg.norm(u)
    side, y = np.cross([0.0, 1.0, 0.0], u), np.array([0.0, 1.0, 0.0])
    return np.array([np.cos(e) * (np.cos(a) * u + np.sin(a) * side) + np.sin(e) * y
                     for a in np.radians([-30, 0, 30]) for e in np.radians([0, 35, 70])])


def _search(synth, seed=1):
    return synth.search("right", _handle_dirs(synth), np.array([0.0, 0.0, 1.0]),
                        np.random.default_rng(seed), kind="hook")


def test_hook_is_admitted_where_a_handle_stands_clear():
    types = {}
    for name in ("mug", "fryingpan", "knife", "cylindersmall"):
        inst = make_instance(name, np.random.default_rng(0), 0)
        types[name] = ObjectTools(inst).synth(1.0).grasp_types()
    assert "hook" in types["fryingpan"]
    assert "hook" not in types["knife"]  # its handle lies on the table: no room under it
    assert "hook" not in types["mug"] and "handle" in types["mug"]  # a loop: not hooked
    assert "hook" not in types["cylindersmall"]  # no handle
    assert "hook" in G.GRASP_TYPES


def test_hook_curls_the_fingers_round_the_pan_handle(pan):
    torch.set_num_threads(1)
    inst, tools = pan
    synth = tools.synth(1.0)
    g = _search(synth)
    assert g is not None and g.kind == "hook"
    hand = G._light_hand("right", 1.0)[0]
    local = hand.to_local(torch.as_tensor(g.hand_pose))[None].numpy()
    v, j = G._pose(hand, g.R[None], g.t[None], local)
    v, j = v[0], j[0]
    sd = tools.df.exact_signed_distance(v)  # independent of the grids used by the search
    assert -sd.min() <= G.MAX_PENETRATION + 2e-4
    parts = hand.part_labels
    h = synth.handles[0]
    axis, point = np.asarray(h.axis), np.asarray(h.point)
    closest, _, _ = trimesh.proximity.closest_point(inst.mesh, v)
    along = (closest - point) @ axis  # m, along the handle from its grip centre
    for name, p in FINGERS.items():
        m = parts == p
        k = np.argmin(sd[m])
        assert sd[m][k] <= 0.002, name  # within 2 mm of the surface...
        assert abs(along[m][k]) <= 0.5 * h.length + 0.01, name  # ...of the handle
    assert sd[parts == 0].min() > CONTACT_THRESHOLD  # palm off the object
    assert sd[parts == 1].min() > CONTACT_THRESHOLD  # the thumb does not oppose
    # a hook, not a rest: the index and middle tips curled under the bar (the pan hangs)
    across = lambda x: x - point - ((x - point) @ axis)[..., None] * axis  # noqa: E731
    assert across(j[17])[1] < 0 and across(j[18])[1] < 0
    assert set(g.contact_parts) >= {"index", "middle", "ring"}
    assert v[:, 1].min() > -inst.rest_height + G.TABLE_CLEARANCE
    assert bool(hand.within_limits(torch.as_tensor(g.hand_pose)))


def test_hook_is_deterministic_for_a_seed(pan):
    synth = pan[1].synth(1.0)
    a, b = _search(synth, 4), _search(synth, 4)
    np.testing.assert_array_equal(a.hand_pose, b.hand_pose)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.R, b.R)


def test_hook_ignores_a_target_off_the_handle(pan):
    # an off-hand pass aims its hands at parts of the object; a hook holds the handle only
    synth = pan[1].synth(1.0)
    a = _search(synth, 2)
    b = synth.search("right", _handle_dirs(synth), np.array([0.0, 0.0, 1.0]),
                     np.random.default_rng(2), kind="hook", target=synth.centre)
    np.testing.assert_array_equal(a.t, b.t)
