"""One SynthGRAB sequence: a subject reaches for an object on a table, grasps it, acts and
puts it back.

:func:`make_episode` runs the steps, each in its own module:

- :mod:`.scene`: table, object rest pose and body landmarks (:func:`make_scene`), and the
  shared vocabulary (sides, rigid-transform helpers, :class:`Cast`, :class:`EpisodeFailed`);
- :mod:`.grasp_plan`: the grasps the intent needs (:func:`make_cast`);
- :mod:`.choreography`: the motion as key frames (:mod:`.script`), following GRAB's protocol;
- :mod:`.solve`: the key frames as a whole-body motion (torso lean, head turn, arm IK), the
  object following the carrying hand's forward-kinematics wrist;
- :mod:`.contact`: hand-object contacts and GRAB contact labels;
- :mod:`.caches`: what episodes reuse (per-object :class:`ObjectTools`, body and hand models).

A drawn share of one-handed ``use`` episodes regrasp (``REGRASP_SHARE``, drawn from a
stream of its own, :func:`draws_regrasp`): the hand first picks the object up with another
grasp, puts it back down and lets go, then takes the use grasp (:class:`.scene.Regrasp`);
when that cannot be made the episode is the one without it, unchanged.

Here the motion is retried until every target is reachable (stepping the body closer,
leaning more, shrinking the intent) and hands and object stay out of the table top
(:func:`plan_motion`), and the result is written as a GRAB-layout :class:`Sequence`.

World frame: y up, body faces +z, pelvis above x = z = 0 (docs/architecture.md).
Units: metres, radians, frames at ``constants.FPS``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ...core import constants as C
from ...core.frames import SIDES
from ..grab_io import object_mesh_relpath
from ..sequence import Sequence, make_body_params, make_hand_params, make_rigid_params
from .caches import ObjectTools, body_model, hand_models
from .choreography import choreograph
from .contact import _min, _posed_hands, contact_labels, hand_contact, object_clearance
from .grasp_plan import make_cast, with_regrasp
from .objects import ObjectInstance
from .scene import (
    Cast,
    EpisodeFailed,
    hold_spans,
    make_scene,
    shifted,
    table_clearance,
    to_axis_angle,
)
from .script import Script
from .solve import Motion, solve
from .world import Subject

# m; the pelvis stays this far behind the table edge (thighs and hanging hands clear it)
BODY_TABLE_GAP = 0.2
AMPLITUDES = (1.0, 0.75, 0.5)  # intent motion scales tried until every target is reachable
TABLE_TOLERANCE = 0.001  # m; a hand or the object may touch this deep into the table (rounding)
# Idle (relaxed) hands, SynthGRAB v2: the model's relaxed pose with a drawn overall curl
# (factor), an ulnar cascade (extra flexion per finger towards the little finger, deg), a
# finger spread (MCP abduction, deg) and a thumb posture (CMC abduction and flexion, deg),
# so that idle hands vary between sequences and segments instead of sitting at one pose.
IDLE_CURL = (0.3, 1.9)
IDLE_CASCADE_DEG = (0.0, 8.0)
IDLE_SPREAD_DEG = (-4.0, 8.0)
IDLE_THUMB_DEG = ((-10.0, 15.0), (-10.0, 20.0))
# SynthGRAB 2.2's thumb-CMC abduction and flexion axes in the CMC's opposition frame
# (``bodies.hand_template._joint_frames``): the idle thumb varies as it did in 2.2.
_THUMB_ABDUCTION_22 = np.array([0.4195, -0.3824, -0.8233])
_THUMB_FLEXION_22 = np.array([0.1736, 0.9240, -0.3407])
# Stream tags of the draws that must not depend on the intent or on the other draws:
# the grasp type, the idle hands, whether a use episode regrasps and the regrasp itself.
KIND_STREAM, IDLE_STREAM, REGRASP_DRAW_STREAM, REGRASP_STREAM = 1, 2, 3, 4
REGRASP_SHARE = 1 / 3  # of one-handed ``use`` episodes (drawn per episode)


# --- seeded sub-streams and idle hands ---------------------------------------------------------
def sub_stream(seed: int | np.random.SeedSequence, tag: int) -> np.random.Generator:
    """A generator of its own for ``(seed, tag)``: draws from it depend on the seed alone,
    neither on the intent nor on how much the episode's main stream was used."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return np.random.default_rng(
        np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, 1000 + tag))
    )


def idle_pose(hand, rng: np.random.Generator) -> np.ndarray:
    """A relaxed finger pose (15, 3) axis-angles for ``hand`` (a ``ProceduralHand``):
    the model's relaxed pose varied as ``IDLE_*`` say, clamped into the joint limits."""
    import torch

    with torch.no_grad():
        base = hand.to_local(hand.named_pose("relaxed").double()).numpy()
    local = base.copy()
    local[:12, 0] *= rng.uniform(*IDLE_CURL)
    for k, chain in enumerate(((0, 1, 2), (3, 4, 5), (9, 10, 11), (6, 7, 8))):  # index -> pinky
        local[list(chain), 0] += np.radians(k * rng.uniform(*IDLE_CASCADE_DEG))
    spread = np.radians(rng.uniform(*IDLE_SPREAD_DEG))
    local[[0, 3, 9, 6], 1] += spread * np.array([1.0, 0.2, -0.6, -1.0])
    # the thumb's CMC abducts and flexes about 2.2's bone-frame axes (in its opposition frame)
    local[12] += np.radians(rng.uniform(*IDLE_THUMB_DEG[0])) * _THUMB_ABDUCTION_22
    local[12] += np.radians(rng.uniform(*IDLE_THUMB_DEG[1])) * _THUMB_FLEXION_22
    with torch.no_grad():
        pose = hand.from_local(torch.as_tensor(local))
        return hand.clamp(pose).double().numpy()


def idle_poses(hands: dict, seed: int | np.random.SeedSequence) -> dict:
    """Per side (2, 15, 3): the idle pose before the grasp and the one after the release
    (an idle hand drifts from the first to the second), drawn from their own stream."""
    rng = sub_stream(seed, IDLE_STREAM)
    return {s: np.stack([idle_pose(hands[s], rng), idle_pose(hands[s], rng)]) for s in SIDES}


def draws_regrasp(seed: int | np.random.SeedSequence, intent: str, inst: ObjectInstance) -> bool:
    """Whether the episode of ``seed`` regrasps: a one-handed ``use`` with probability
    ``REGRASP_SHARE``, drawn from a stream of its own (no other draw of the episode moves)."""
    if intent != "use" or inst.large:
        return False
    return bool(sub_stream(seed, REGRASP_DRAW_STREAM).random() < REGRASP_SHARE)


# --- one episode -------------------------------------------------------------------------------
def plan_motion(cast: Cast, relaxed: dict) -> tuple[Motion, Script, Cast, dict, dict]:
    """A reachable motion that keeps hands and object out of the table (raising the edge
    crossing if not).

    Returns the motion, its script, the cast it was solved for, the posed hand vertices
    (side -> (T, V, 3)) and their table clearances (side -> (T,)).
    """
    hands = hand_models(cast.subject.hand_scale)
    for _ in range(4):
        mo, sc, trial = _reachable_motion(cast, relaxed)
        verts = _posed_hands(hands, mo)
        gaps = {s: table_clearance(verts[s], trial.scene) for s in SIDES}
        held = min(_min(gaps[s][mo.attached[s]]) for s in SIDES)
        obj = _min(object_clearance(mo, trial.inst, trial.scene))
        if min(held, obj) <= -TABLE_TOLERANCE:
            raise EpisodeFailed(
                f"{cast.inst.name}: the held object goes {-min(held, obj) * 1000:.0f} mm "
                "into the table"
            )
        gap = min(_min(gaps[s][~mo.attached[s]]) for s in SIDES)
        if gap > -TABLE_TOLERANCE:
            return mo, sc, trial, verts, gaps
        cast = Cast(**{**cast.__dict__, "lift_extra": cast.lift_extra + 0.02 - gap})
    raise EpisodeFailed(f"{cast.inst.name}: a hand passes {-gap * 1000:.0f} mm into the table")


def _reachable_motion(cast: Cast, relaxed: dict) -> tuple[Motion, Script, Cast]:
    """Choreograph and solve, stepping the body closer and shrinking the intent until all is
    reachable."""
    body = body_model(cast.subject)
    base = cast.scene
    front = base.stage.table_front - BODY_TABLE_GAP
    # (an off-hand pass has no intent motion to shrink: one amplitude)
    for amp in AMPLITUDES[:1] if cast.intent == "offhand" else AMPLITUDES:
        pelvis, gain, best = base.pelvis.copy(), 1.0, np.inf
        for _ in range(9):
            trial = Cast(**{**cast.__dict__, "scene": shifted(base, pelvis), "lean_gain": gain})
            sc = choreograph(trial, amp, relaxed)
            mo = solve(body, sc, trial)
            if mo.reached.all():
                return mo, sc, trial
            # stepping stalls when the table is in the way, or when two hands far apart pull
            # the body to and fro (an off-hand pass): bend more
            stalled = mo.deficit > best - 0.005
            best = min(best, mo.deficit)
            step = pelvis + (mo.deficit + 0.02) * mo.push
            step[2] = min(step[2], front)
            step[0] = float(np.clip(step[0], -0.25, 0.25))
            if np.linalg.norm(step - pelvis) < 0.005 or stalled:
                if gain >= 3.0:
                    break
                gain *= 1.6
            pelvis = step
    raise EpisodeFailed(f"{cast.inst.name}: targets out of reach (by {mo.deficit * 100:.1f} cm)")


@dataclass
class Episode:
    """A generated sequence with what made it (for statistics, tests and pictures)."""

    sequence: Sequence
    motion: Motion
    script: Script
    cast: Cast
    contacts: dict  # side -> HandContact
    mesh: trimesh.Trimesh  # the canonical (written) object mesh


def make_episode(
    subject: Subject,
    inst: ObjectInstance,
    intent: str,
    seed: int | np.random.SeedSequence,
    tools: ObjectTools | None = None,
    index: int = 1,
    *,
    grasp_kind: str | None = None,
    varied_idle: bool = True,
    regrasp: bool | None = False,
) -> Episode:
    """One SynthGRAB sequence.

    seed: int or ``np.random.SeedSequence``; every random choice comes from it (the grasp
    type and the idle hands from sub-streams of their own, :func:`sub_stream`).
    tools: the object's cached distance field and grasp synthesizer (built if None).
    index: the ``n`` of the sequence name ``<sbj>/<object>_<intent>_<n>``.
    grasp_kind: try this grasp type first instead of drawing one (one-handed intents).
    varied_idle: idle hands in drawn relaxed poses (:func:`idle_poses`); False: the hand
    model's relaxed pose (SynthGRAB v1).
    regrasp: give a one-handed ``use`` a regrasp (:func:`.grasp_plan.with_regrasp`; its
    draws come from a sub-stream of their own); None: draw whether (:func:`draws_regrasp`).
    Without a different grasp, or when the regrasp's motion fails :func:`check_regrasp`,
    the episode is the one without it (``cast.regrasp`` is None).
    Raises :class:`EpisodeFailed` when no grasp or no reachable motion exists.
    """
    tools = tools or ObjectTools(inst)
    rng = np.random.default_rng(seed)
    scene = make_scene(subject, inst, rng, intent)
    cast = make_cast(subject, inst, scene, intent, rng, tools,
                     kind_rng=sub_stream(seed, KIND_STREAM), grasp_kind=grasp_kind)
    hands = hand_models(subject.hand_scale)
    if varied_idle:
        relaxed = idle_poses(hands, seed)
    else:
        relaxed = {s: hands[s].named_pose("relaxed").double().numpy() for s in SIDES}
    if regrasp is None:
        regrasp = draws_regrasp(seed, intent, inst)
    if regrasp:
        again = with_regrasp(cast, tools, sub_stream(seed, REGRASP_STREAM))
        if again.regrasp is not None:
            try:
                return _finish(again, relaxed, tools, index)
            except EpisodeFailed:
                pass  # the episode without the regrasp
    return _finish(cast, relaxed, tools, index)


def _finish(cast: Cast, relaxed: dict, tools: ObjectTools, index: int) -> Episode:
    """Plan the motion of ``cast``, label contacts and write the sequence."""
    hands = hand_models(cast.subject.hand_scale)
    mo, sc, cast, verts, gaps = plan_motion(cast, relaxed)
    contacts, v_obj, reps, close = {}, {}, {}, {}
    for s in SIDES:
        contacts[s], v_obj[s], reps[s], close[s] = hand_contact(
            verts[s], hands[s], mo, tools, cast.scene, gaps[s]
        )
    if cast.regrasp is not None:
        check_regrasp(cast, mo, sc, contacts)
    labels = contact_labels(
        v_obj, contacts, hands, np.asarray(tools.contact_mesh.vertices), reps, close
    )
    seq = build_sequence(cast, mo, labels, index)
    return Episode(seq, mo, sc, cast, contacts, tools.contact_mesh)


def check_regrasp(cast: Cast, mo: Motion, sc: Script, contacts: dict) -> None:
    """:class:`EpisodeFailed` unless each regrasping hand holds twice and touches the object
    nowhere on its way from the first grasp (backed off, open) to the use grasp's pre-grasp
    pose (the ``reach`` after ``regrasp_backoff``): a hand swept through or along the object
    there would be a contact no grasp explains."""
    names = [p[0] for p in sc.phases]
    k = names.index("regrasp_backoff") + 1
    if k >= len(names) or names[k] != "reach":
        raise EpisodeFailed(f"{cast.inst.name}: no reach after the regrasp's backoff")
    _, a, b = sc.phases[k]
    for s in cast.regrasp.grasps:
        spans = hold_spans(mo.attached[s])
        if len(spans) != 2:
            raise EpisodeFailed(f"{cast.inst.name}: regrasp with {len(spans)} holds")
        touch = contacts[s].grasp[a: b + 1]
        if touch.any():
            pen = float(contacts[s].penetration[a: b + 1].max())
            raise EpisodeFailed(
                f"{cast.inst.name}: the hand touches the object in {int(touch.sum())} frames "
                f"(up to {pen * 1000:.1f} mm deep) on its way to the use grasp")


def build_sequence(cast: Cast, mo: Motion, labels: np.ndarray, index: int) -> Sequence:
    """The GRAB-layout :class:`Sequence` (object/table rotations stored row-vector style)."""
    T, subj = mo.n_frames, cast.subject
    hands = {
        s: make_hand_params(
            to_axis_angle(mo.wrist[s][0]), mo.fingers[s].reshape(T, 45), mo.wrist[s][1]
        )
        for s in SIDES
    }
    body = make_body_params(mo.global_orient, mo.body_pose.reshape(T, 63), mo.transl,
                            mo.fingers["left"].reshape(T, 45), mo.fingers["right"].reshape(T, 45))
    scene = cast.scene
    table = make_rigid_params(
        np.tile(to_axis_angle(scene.table_R.T), (T, 1)), np.tile(scene.table_p, (T, 1))
    )
    obj = make_rigid_params(to_axis_angle(np.swapaxes(mo.obj_R, 1, 2)), mo.obj_p)
    name = cast.inst.name
    return Sequence(
        name=f"{subj.sid}/{name}_{cast.verb}_{index}",
        sbj_id=subj.sid,
        gender=subj.gender,
        obj_name=name,
        motion_intent=cast.verb,
        body=body,
        rhand=hands["right"],
        lhand=hands["left"],
        object=obj,
        table=table,
        contact={"object": labels},
        fps=C.FPS,
        body_model="procedural",
        height=subj.height,
        hand_scale=subj.hand_scale,
        object_mesh=object_mesh_relpath(name),
    )
