"""The hold test in MuJoCo: does the hand hold the object? (docs/contract.md, "Physics: the
hold test").

In the physics table as ``hold_sim`` / ``hold_sim_disp`` / ``hold_sim_settle``
(``metrics.evaluate``), with the design's gates printed under it; on SynthGRAB ground truth
it does not pass them yet, so the table's verdict is the quasi-static check
(docs/physics_hold.md). ``metrics.physics`` keeps GRIP's 5-step support test.

Two tests share one scene per frame:

- **Hold test** (the verdict). The hand is articulated: a fixed wrist body and one body per
  finger bone at its posed joint, three hinges per joint with capped position servos
  (``HOLD_FINGER_*``). Finger bones within ``HOLD_TOUCH`` of the object are driven
  ``HOLD_TIGHTEN`` further toward it (the servos' targets, solved through MuJoCo's contact
  Jacobians), so the hand squeezes with at most the servo torque. The object settles
  ``HOLD_SETTLE_SECONDS`` without gravity (a penetrating grasp is pushed out: a settle
  displacement beyond ``HOLD_SETTLE_FAIL`` fails), then holds ``SIM_HOLD_SECONDS`` under the
  frame's gravity, or under each of the six axis directions as a robustness variant.
  Success: the object moves less than ``HOLD_DISP`` and turns less than ``HOLD_ROT``
  during the hold, and no hand vertex started more than ``HOLD_MAX_DEPTH`` inside the
  object (the force check's rule: the damped settle lets a penetrating hand wedge the
  object instead of pushing it out, so the settle rule alone passed fingers closed 0.4 rad
  into it). A diverged run is a failure with the capped displacement, never dropped; so
  is a frame that fails a rule before the hold (depth, settle, wedge; since s50 its hold is
  not simulated: a sunk or wedged hand's small displacement measured no grasp).
- **Support test** (GRIP supp. Sec. 11): from rest, under gravity, with the hand as it is,
  the object moves < 1 mm in 5 steps of 1/240 s. Free fall alone moves it 2.55 mm
  (``SIM_FREE_FALL_5``), so the test tells "something supports it" from "nothing does".

- **Force check** (quasi-static, no simulation; the reported ``hold_qs`` metric):
  :func:`plan_forces` finds contact forces inside linearised friction cones that cancel a
  load with zero torque (least largest normal force, a linear programme); :func:`can_hold`
  applies it to the hand vertices within ``HOLD_TOUCH`` of the object (a hand more than
  ``HOLD_MAX_DEPTH`` inside fails) and :func:`force_ratio` reports the force it needs.
  Measurements: docs/physics_hold.md.

Collision geometry is ``geometry.pieces``: the object's and the hand's pieces stick out at
most ``PIECE_MAX_ERROR`` (measured; the hand's on each frame's pose, :func:`posed_pieces`),
so a concave object stays concave and contacts start where the surfaces are. Pieces
farther than ``HOLD_REACH`` from the other body are left out
of a frame's scene: the object would have to move that far relative to the hand, beyond the
success threshold, to reach them (a rotation about a far pivot could; so could a large
object slowly turning around the hand, which then fails on rotation).

``mujoco`` is imported inside the functions to keep ``grip_bench.metrics`` light.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from ..core import constants as C
from ..geometry.pieces import (
    ExactDistance,
    SurfacePieces,
    outward_errors,
    refine_pieces,
    surface_pieces,
    vertex_normals,
)
from ..geometry.wrench import plan_forces

if TYPE_CHECKING:  # trimesh costs 0.5 s to import; `grip-bench ls` should not pay it
    import mujoco
    import trimesh

AXES = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass(frozen=True)
class HoldResult:
    """One hold test: ``settle`` (m) object displacement while settling; ``displacement`` (m)
    and ``rotation`` (degrees) during the hold (``HOLD_DISP_CAP`` / 180 when diverged; at
    least ``HOLD_DISP_CAP`` where the object fell free and the run stopped early);
    ``held`` the verdict; ``diverged`` NaN or runaway velocity; ``wedge`` the settled
    contacts' force pushing the hands *into* the object, in object weights (see
    :func:`inward_force`; NaN when not measured); ``ruled_out`` failed after the settle,
    before the hold, by the depth, settle or wedge rule (its hold not simulated)."""

    settle: float
    displacement: float
    rotation: float
    held: bool
    diverged: bool
    wedge: float = float("nan")
    ruled_out: bool = False


@dataclass(frozen=True)
class SupportResult:
    """GRIP's 5-step support test: ``displacement`` (m, NaN when diverged) and ``stable``."""

    displacement: float
    stable: bool
    diverged: bool


@dataclass
class PosedHand:
    """One hand of one frame, world frame: vertices (V, 3) m, faces (F, 3), its 16 joints
    (16, 3) m (wrist first, MANO order), ``parents`` (16,), ``bone_ids`` (V,) (skinning bone
    per vertex), ``pieces`` (the hand model's :class:`SurfacePieces`, labelled by bone) and
    signed distances (V,) m of the vertices to the object (which bones to tighten)."""

    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    parents: tuple[int, ...]
    bone_ids: np.ndarray
    pieces: SurfacePieces
    signed_dist: np.ndarray

    @cached_property
    def normals(self) -> np.ndarray:
        """Unit vertex normals (V, 3)."""
        return vertex_normals(self.vertices, self.faces)


# ---------------------------------------------------------------- collision pieces
_OBJECT_PIECES: OrderedDict[str, SurfacePieces] = OrderedDict()


def _piece_params() -> dict:
    from ..geometry.cache import package_version

    return {"max_error": C.PIECE_MAX_ERROR, "depth": C.PIECE_DEPTH,
            "hand_depth": C.PIECE_HAND_DEPTH, "min_depth": C.PIECE_MIN_DEPTH,
            "patch_faces": C.PIECE_PATCH_FACES, "scipy": package_version("scipy"),
            "igl": package_version("libigl"), "algorithm": 1}


def object_pieces(mesh: trimesh.Trimesh) -> SurfacePieces:
    """The object's collision pieces (object frame), cached by mesh content in memory and in
    the on-disk geometry cache (a few seconds for a concave mesh, once per machine)."""
    from ..geometry.cache import cached_arrays, mesh_key

    key = mesh_key("surface_pieces", mesh.vertices, mesh.faces, _piece_params())
    if key not in _OBJECT_PIECES:
        a = cached_arrays("surface_pieces", key, lambda: surface_pieces(
            mesh.vertices, mesh.faces).to_arrays(), names=("ids", "sizes", "depth", "error"))
        _remember(_OBJECT_PIECES, key, SurfacePieces.from_arrays(a))
    return _OBJECT_PIECES[key]


def hand_pieces(template: np.ndarray, faces: np.ndarray, bone_ids: np.ndarray,
                poses: list[np.ndarray] = ()) -> SurfacePieces:
    """A hand model's pieces, one bone each, error bounded on ``template`` (V, 3) and on each
    extra posed vertex set in ``poses``. Cached like :func:`object_pieces`. A scene re-poses
    them with its frame's hand and rebuilds there whichever a bend took past the bound
    (:func:`posed_pieces`)."""
    from ..geometry.cache import cached_arrays, mesh_key

    h = hashlib.sha256(np.ascontiguousarray(bone_ids, np.int64).tobytes())
    for p in poses:
        h.update(np.ascontiguousarray(p, np.float64).tobytes())
    extra = {"refine": 2} if len(poses) else {}  # refine_pieces: whole-surface normals
    key = mesh_key("hand_pieces", template, faces,
                   {**_piece_params(), "poses": h.hexdigest(), **extra})
    if key in _OBJECT_PIECES:
        return _OBJECT_PIECES[key]

    def build() -> dict[str, np.ndarray]:
        pieces = surface_pieces(template, faces, labels=bone_ids, depth=C.PIECE_HAND_DEPTH)
        for _ in range(4):  # split further where a pose bends a piece past the bound
            err = pieces.error.copy()
            for p in poses:
                err = np.maximum(err, _errors_on(pieces, p, faces))
            if not (err > C.PIECE_MAX_ERROR).any():
                break
            pieces = refine_pieces(pieces, err, template, faces)
        return pieces.to_arrays()

    a = cached_arrays("hand_pieces", key, build, names=("ids", "sizes", "depth", "error"))
    _remember(_OBJECT_PIECES, key, SurfacePieces.from_arrays(a))
    return _OBJECT_PIECES[key]


def _errors_on(pieces: SurfacePieces, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Outward errors (P,) m of ``pieces`` re-posed on ``vertices`` (V, 3)."""
    return outward_errors(pieces.points(vertices, vertex_normals(vertices, faces)),
                          ExactDistance(vertices, faces))


def posed_pieces(hand: PosedHand, obj_world: np.ndarray) -> SurfacePieces:
    """The pieces of ``hand`` within ``HOLD_REACH`` of the object's world vertices
    (N, 3), bounded on this frame's pose: the model's pieces re-posed, their outward error
    measured against the posed surface, and those past ``PIECE_MAX_ERROR`` (a bend: 12 % of
    a scene's pieces on the grasp fixture's frames, up to 2.1 mm) rebuilt there from smaller
    patches (:func:`geometry.pieces.refine_pieces`). ``error`` holds each piece's error on
    this pose; above the bound only where a single face is."""
    pts = hand.pieces.points(hand.vertices, hand.normals)
    keep = np.flatnonzero(_near(pts, obj_world, C.HOLD_REACH))
    near = SurfacePieces(tuple(hand.pieces.vertex_ids[i] for i in keep),
                         hand.pieces.depth[keep], np.zeros(len(keep)))
    if not len(near):
        return near
    sdf = ExactDistance(hand.vertices, hand.faces)
    err = outward_errors([pts[i] for i in keep], sdf)
    if not (err > C.PIECE_MAX_ERROR).any():
        return SurfacePieces(near.vertex_ids, near.depth, err)
    return refine_pieces(near, err, hand.vertices, hand.faces, sdf, hand.normals)


# ---------------------------------------------------------------- scene
_LRU_SIZE = 16


def _remember(cache: OrderedDict, key: str, value: object) -> None:
    cache[key] = value
    cache.move_to_end(key)
    if len(cache) > _LRU_SIZE:
        cache.popitem(last=False)


def _contact_params(geom: mujoco.MjsGeom, hand: bool) -> None:
    """Contact settings shared by hand and object geoms (the why lives in constants).

    Hand geoms collide with the object only (contype / conaffinity bits), never with each
    other; MuJoCo adds the margins of a pair, so only the hand carries one.
    """
    geom.friction = [C.SIM_FRICTION, C.SIM_TORSIONAL_FRICTION, C.SIM_ROLLING_FRICTION]
    geom.condim = C.SIM_CONDIM
    geom.solref = list(C.SIM_SOLREF)
    geom.solimp = list(C.SIM_SOLIMP)
    geom.margin = C.HOLD_CONTACT_MARGIN if hand else 0.0
    geom.gap = 0.0
    geom.contype, geom.conaffinity = (1, 2) if hand else (2, 1)
    geom.mass = 0.0  # bodies carry explicit inertia


def _add_pieces(spec: mujoco.MjSpec, body: mujoco.MjsBody, pieces: list[np.ndarray],
                prefix: str, hand: bool, origin: np.ndarray | None = None) -> None:
    import mujoco

    for i, pts in enumerate(pieces):
        mesh = spec.add_mesh()
        mesh.name = f"{prefix}{i}"
        local = pts if origin is None else pts - origin
        mesh.uservert = np.asarray(local, dtype=np.float64).ravel().tolist()
        geom = body.add_geom()
        geom.type = mujoco.mjtGeom.mjGEOM_MESH
        geom.meshname = mesh.name
        _contact_params(geom, hand)


def _near(points: list[np.ndarray], other: np.ndarray, reach: float) -> list[bool]:
    """Whether each point set (n_i >= 1, 3) comes within ``reach`` of the point cloud
    ``other``: one tree query for all the sets' points (a query per set cost a frame
    ~25 ms of Python overhead)."""
    from scipy.spatial import cKDTree

    if len(other) == 0 or not points:
        return [False] * len(points)
    d, _ = cKDTree(other).query(np.concatenate(points), k=1, distance_upper_bound=reach)
    starts = np.cumsum([0] + [len(p) for p in points[:-1]])
    return np.logical_or.reduceat(np.isfinite(d), starts).tolist()


@dataclass
class Scene:
    """A compiled frame: the model, which finger joints belong to which hand bone, and the
    servo targets that tighten the grasp, and the measured bound of its hand pieces."""

    model: mujoco.MjModel
    targets: np.ndarray
    n_hands: int
    hand_error: float = 0.0  # m, the largest outward error of the hands' pieces on this pose
    depth: float = 0.0  # m, the deepest hand vertex inside the object (0: none inside)
    # per object geom (in the order they were added): its surface patch's vertices and
    # outward normals (n_i, 3) in the object's frame, for the wedge rule (inward_force)
    patches: tuple[tuple[np.ndarray, np.ndarray], ...] = ()


def _spec(up: tuple[float, float, float], friction: float = C.SIM_FRICTION) -> mujoco.MjSpec:
    import mujoco

    spec = mujoco.MjSpec()
    spec.option.timestep = C.SIM_DT
    spec.option.gravity = (-C.GRAVITY * np.asarray(up, dtype=np.float64)).tolist()
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST  # servo damping implicit
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC  # no pyramid bias on pinch grasps
    spec.option.impratio = C.SIM_IMPRATIO  # stiffer friction than normal: less creep in a hold
    return spec


def _add_object(spec: mujoco.MjSpec, obj: trimesh.Trimesh, pieces: list[np.ndarray],
                pose: tuple[np.ndarray, np.ndarray] | None, density: float) -> None:
    from .physics import add_free_object

    _add_pieces(spec, add_free_object(spec, obj, pose, density), pieces, "obj", hand=False)


_Patch = tuple[np.ndarray, np.ndarray]  # a piece's surface vertices and normals (n, 3)


def _object_world_pieces(obj: trimesh.Trimesh, pose: tuple[np.ndarray, np.ndarray] | None
                         ) -> tuple[list[np.ndarray], np.ndarray, list[_Patch]]:
    """The object's pieces in its own frame, its vertices in the world (N, 3), and each
    piece's surface patch (vertices, outward vertex normals; object frame): where the
    piece's outside is, for :func:`inward_force`."""
    pieces = object_pieces(obj)
    v = np.asarray(obj.vertices, dtype=np.float64)
    n = vertex_normals(v, obj.faces)
    local = pieces.points(v, n)
    world = v if pose is None else v @ np.asarray(pose[0]).T + np.asarray(pose[1])
    return local, world, [(v[ids], n[ids]) for ids in pieces.vertex_ids]


def _to_world(local: list[np.ndarray], pose: tuple[np.ndarray, np.ndarray] | None
              ) -> list[np.ndarray]:
    if pose is None:
        return local
    R, t = np.asarray(pose[0]), np.asarray(pose[1])
    return [p @ R.T + t for p in local]


def static_scene(hand_meshes: list[trimesh.Trimesh], obj: trimesh.Trimesh,
                 obj_pose: tuple[np.ndarray, np.ndarray] | None = None,
                 up: tuple[float, float, float] = C.UP,
                 density: float = C.DEFAULT_DENSITY) -> Scene:
    """Static "hands" (any closed meshes, world frame, bounded-error pieces each) and the free
    object (own frame, placed by ``obj_pose`` = (R, t), world = R @ local + t)."""
    spec = _spec(up)
    local, obj_world, patches = _object_world_pieces(obj, obj_pose)
    hand_world = []
    for i, h in enumerate(hand_meshes):
        v = np.asarray(h.vertices, dtype=np.float64)
        pts = surface_pieces(v, h.faces).points(v, vertex_normals(v, h.faces))
        keep = _near(pts, obj_world, C.HOLD_REACH)
        _add_pieces(spec, spec.worldbody, [p for p, k in zip(pts, keep, strict=True) if k],
                    f"hand{i}_", hand=True)
        hand_world.extend(pts)
    patches = _add_object_pieces(spec, obj, obj_pose, density, local, patches, hand_world)
    return Scene(spec.compile(), np.zeros(0), len(hand_meshes),
                 depth=_mesh_depth(hand_meshes, obj, obj_pose), patches=patches)


def _mesh_depth(hand_meshes: list[trimesh.Trimesh], obj: trimesh.Trimesh,
                pose: tuple[np.ndarray, np.ndarray] | None) -> float:
    """The deepest hand vertex inside the object (m, 0: none inside), as ``PosedHand``'s
    signed distances give it for the articulated hands: the depth rule of :func:`hold`."""
    verts = [np.asarray(h.vertices, dtype=np.float64) for h in hand_meshes]
    if not verts:
        return 0.0
    world = np.concatenate(verts)
    local = world if pose is None else (world - np.asarray(pose[1])) @ np.asarray(pose[0])
    return max(0.0, -float(ExactDistance(obj.vertices, obj.faces)(local).min()))


def _select_object(local: list[np.ndarray], pose: tuple[np.ndarray, np.ndarray] | None,
                   hand_world: list[np.ndarray]) -> list[int]:
    """The indices of the object's pieces within reach of the hands (the first alone when
    none is: the object then falls freely whatever its pieces are, but a body needs one
    geom)."""
    cloud = np.concatenate(hand_world) if hand_world else np.zeros((0, 3))
    keep = _near(_to_world(local, pose), cloud, C.HOLD_REACH)
    return [i for i, k in enumerate(keep) if k] or [0]


def _add_object_pieces(spec: mujoco.MjSpec, obj: trimesh.Trimesh,
                       pose: tuple[np.ndarray, np.ndarray] | None, density: float,
                       local: list[np.ndarray], patches: list[_Patch],
                       hand_world: list[np.ndarray]) -> tuple[_Patch, ...]:
    """The free object with its pieces within reach of ``hand_world``; returns their
    surface patches (of :func:`_object_world_pieces`), in the order their geoms were added."""
    ids = _select_object(local, pose, hand_world)
    _add_object(spec, obj, [local[i] for i in ids], pose, density)
    return tuple(patches[i] for i in ids)


def hand_scene(hands: list[PosedHand], obj: trimesh.Trimesh,
               obj_pose: tuple[np.ndarray, np.ndarray] | None = None,
               up: tuple[float, float, float] = C.UP,
               density: float = C.DEFAULT_DENSITY) -> Scene:
    """Articulated hands (world frame) and the free object, with tightened servo targets."""
    import mujoco

    spec = _spec(up)
    local, obj_world, patches = _object_world_pieces(obj, obj_pose)
    hand_world, error = [], 0.0
    for k, hand in enumerate(hands):
        pts, err = _add_hand(spec, hand, f"h{k}", obj_world)
        hand_world.extend(pts)
        error = max(error, err)
    patches = _add_object_pieces(spec, obj, obj_pose, density, local, patches, hand_world)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    targets = np.concatenate([_tighten(model, data, hand, f"h{k}")
                              for k, hand in enumerate(hands)]) if hands else np.zeros(0)
    depth = max([0.0, *(-float(np.min(h.signed_dist)) for h in hands if len(h.signed_dist))])
    return Scene(model, targets, len(hands), error, depth, patches)


def _add_hand(spec: mujoco.MjSpec, hand: PosedHand, name: str,
              obj_world: np.ndarray) -> tuple[list[np.ndarray], float]:
    """Bodies, hinges, servos and pieces of one posed hand; returns its kept world pieces
    and their largest outward error (m) on this pose."""
    import mujoco

    pieces = posed_pieces(hand, obj_world)
    pts = pieces.points(hand.vertices, hand.normals)
    bone_of = [int(np.bincount(hand.bone_ids[i]).argmax()) for i in pieces.vertex_ids]
    bodies: dict[int, mujoco.MjsBody] = {}
    for b in range(16):
        parent = spec.worldbody if hand.parents[b] < 0 else bodies[hand.parents[b]]
        offset = hand.joints[b] - (0.0 if hand.parents[b] < 0 else hand.joints[hand.parents[b]])
        body = parent.add_body()
        body.name = f"{name}_b{b}"
        body.pos = offset.tolist()
        if b > 0:  # the wrist is fixed; each finger joint turns about three world axes
            body.explicitinertial = True
            body.mass = C.HOLD_BONE_MASS
            body.inertia = [1e-7, 1e-7, 1e-7]
            body.gravcomp = 1.0
            for a, axis in enumerate(np.eye(3)):
                j = body.add_joint()
                j.name = f"{name}_j{b}_{a}"
                j.type = mujoco.mjtJoint.mjJNT_HINGE
                j.axis = axis.tolist()
                j.armature = C.HOLD_ARMATURE
                act = spec.add_actuator()
                act.name = j.name
                act.target = j.name
                act.trntype = mujoco.mjtTrn.mjTRN_JOINT
                act.set_to_position(kp=C.HOLD_FINGER_KP, kv=C.HOLD_FINGER_KV)
                act.forcelimited = True
                act.forcerange = [-C.HOLD_FINGER_TORQUE, C.HOLD_FINGER_TORQUE]
        mine = [p for p, bb in zip(pts, bone_of, strict=True) if bb == b]
        _add_pieces(spec, body, mine, f"{name}_p{b}_", hand=True, origin=hand.joints[b])
        bodies[b] = body
    return pts, float(pieces.error.max(initial=0.0))


def _tighten(model: mujoco.MjModel, data: mujoco.MjData, hand: PosedHand,
             name: str) -> np.ndarray:
    """Servo targets (45,) rad of one hand: each finger's touching bones (a vertex within
    ``HOLD_TOUCH``) drive their closest vertex ``HOLD_TIGHTEN`` past the object's surface
    along its outward normal (toward the object), the minimum-norm joint motion of that
    finger's chain; a vertex that starts inside moves ``HOLD_TIGHTEN`` further in (its
    depth plus ``HOLD_TIGHTEN`` past the surface: ending exactly ``HOLD_TIGHTEN`` past it
    changed no verdict on the smoke data, docs/physics_hold.md, s41). The servo then
    presses with ``HOLD_FINGER_KP`` times what the surface leaves unreached, capped at
    ``HOLD_FINGER_TORQUE``: a squeeze, as a hand holds."""
    import mujoco

    targets = np.zeros(45)
    touching = hand.signed_dist <= C.HOLD_TOUCH
    for chain in _chains(hand.parents):
        rows, dofs, depth = [], [], []
        for b in chain:
            dofs.extend(model.jnt_dofadr[model.joint(f"{name}_j{b}_{a}").id] for a in range(3))
        for b in chain:
            on = np.flatnonzero(touching & (hand.bone_ids == b))
            if len(on) == 0:
                continue
            v = on[np.argmin(hand.signed_dist[on])]
            jacp = np.zeros((3, model.nv))
            mujoco.mj_jac(model, data, jacp, None, hand.vertices[v],
                          model.body(f"{name}_b{b}").id)
            rows.append(hand.normals[v] @ jacp[:, dofs])  # outward from the hand: toward it
            depth.append(max(float(hand.signed_dist[v]), 0.0) + C.HOLD_TIGHTEN)
        if rows:
            J = np.asarray(rows)
            dq = J.T @ np.linalg.solve(J @ J.T + 1e-9 * np.eye(len(J)), np.asarray(depth))
            for i, b in enumerate(chain):
                targets[(b - 1) * 3:(b - 1) * 3 + 3] = dq[3 * i:3 * i + 3]
    return targets


def _chains(parents: tuple[int, ...]) -> list[list[int]]:
    """Finger chains (bone ids from the knuckle out) of a 16-joint hand."""
    roots = [b for b in range(16) if parents[b] == 0]
    out = []
    for r in roots:
        chain, b = [r], r
        while True:
            kids = [c for c in range(16) if parents[c] == b]
            if not kids:
                break
            b = kids[0]
            chain.append(b)
        out.append(chain)
    return out


# ---------------------------------------------------------------- simulation
class _Diverged:
    """Whether a run of ``model`` has diverged (a non-finite position, the object faster than
    ``SIM_MAX_SPEED``, or MuJoCo's bad-acceleration warning), tested after every step. The
    lookups are made once per model: by name at every step they cost about a tenth of one."""

    def __init__(self, model: mujoco.MjModel):
        import mujoco

        adr = int(model.jnt_dofadr[model.body("object").jntadr[0]])
        self._linear = slice(adr, adr + 3)
        self._bad_qacc = int(mujoco.mjtWarning.mjWARN_BADQACC)

    def __call__(self, data: mujoco.MjData) -> bool:
        return (not np.isfinite(data.qpos).all()
                or np.abs(data.qvel[self._linear]).max() > C.SIM_MAX_SPEED
                or data.warning[self._bad_qacc].number > 0)


def _step(model: mujoco.MjModel, data: mujoco.MjData, n: int,
          diverged: _Diverged | None = None) -> bool:
    """n steps; False when the run diverged."""
    import mujoco

    diverged = diverged or _Diverged(model)
    for _ in range(n):
        mujoco.mj_step(model, data)
        if diverged(data):
            return False
    mujoco.mj_kinematics(model, data)  # mj_step leaves xipos at the pre-integration positions
    return True


def _pose_of(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    b = model.body("object").id
    return data.xipos[b].copy(), data.xquat[b].copy()


def _angle(q0: np.ndarray, q1: np.ndarray) -> float:
    """Angle (degrees) between two unit quaternions (w, x, y, z)."""
    c = min(1.0, abs(float(np.dot(q0, q1))))
    return float(np.degrees(2.0 * np.arccos(c)))


def gravity_along(direction: str | None, up: np.ndarray) -> np.ndarray:
    """Gravity (3,) m/s^2: ``-g up`` for None, else ``g`` along one of :data:`AXES`
    ("+x" ... "-z", world axes)."""
    if direction is None:
        return -C.GRAVITY * up
    axis = np.eye(3)["xyz".index(direction[1])]
    return C.GRAVITY * (1.0 if direction[0] == "+" else -1.0) * axis


def hold(scene: Scene, up: tuple[float, float, float] = C.UP,
         directions: tuple[str | None, ...] = (None,),
         friction: float = C.SIM_FRICTION, grip: float = 1.0) -> list[HoldResult]:
    """The hold test of a compiled scene: settle once, then one hold per gravity direction
    (None: the world's, ``-g up``; else an axis such as "+x", the direction gravity pulls).
    ``friction``: sliding friction of every geom for this run; ``grip``: the finger servos'
    strength for this run (:func:`servo_strength`; 1 = ``HOLD_FINGER_*``). A scene whose hands start
    more than ``HOLD_MAX_DEPTH`` inside the object, or whose settled contacts push the hands
    into it with more than ``HOLD_WEDGE_WEIGHTS`` object weights (:func:`inward_force`: a
    finger wedged inside a thin wall), or whose settle moved the object more than
    ``HOLD_SETTLE_FAIL``, has failed before the hold: its holds are not simulated and
    report the capped displacement and 180 degrees, as a diverged run's (since s50; such
    a hand's small displacement came from wedging or sinking into the object, not from
    a grasp, and flattered ``hold_sim_disp``)."""
    import mujoco

    model = scene.model
    saved = model.geom_friction[:, 0].copy()
    servos = _servo_params(model)
    try:
        model.geom_friction[:, 0] = friction
        servo_strength(model, grip)
        data = mujoco.MjData(model)
        model.opt.gravity[:] = 0.0
        mujoco.mj_forward(model, data)
        start, _ = _pose_of(model, data)
        if not _settle(model, data, scene.targets):
            return [_failed(np.nan) for _ in directions]
        p0, q0 = _pose_of(model, data)
        settle = float(np.linalg.norm(p0 - start))
        wedge = inward_force(model, data, scene.patches, up)
        if not _may_hold(scene.depth, settle, wedge):
            return [HoldResult(settle, C.HOLD_DISP_CAP, 180.0, False, False, wedge, True)
                    for _ in directions]
        out = []
        for d in directions:
            run = mujoco.MjData(model)
            mujoco.mj_copyData(run, model, data)
            model.opt.gravity[:] = gravity_along(d, np.asarray(up, np.float64))
            if not _hold_steps(model, run, p0):
                out.append(_failed(settle))
                continue
            p1, q1 = _pose_of(model, run)
            disp, rot = float(np.linalg.norm(p1 - p0)), _angle(q0, q1)
            ok = disp < C.HOLD_DISP and rot < C.HOLD_ROT
            out.append(HoldResult(settle, disp, rot, bool(ok), False, wedge))
        return out
    finally:
        model.geom_friction[:, 0] = saved
        _set_servo_params(model, servos)
        model.opt.gravity[:] = -C.GRAVITY * np.asarray(up, np.float64)


def servo_strength(model: mujoco.MjModel, factor: float) -> None:
    """Scale the finger servos of a compiled scene, from ``HOLD_FINGER_*``, by ``factor``:
    the gain (N m/rad) and the torque cap (N m) by ``factor``, the damping by its square
    root (the joints' armature is fixed, so that keeps the damping ratio). The tightened
    targets do not depend on it: a stronger grip presses harder toward the same pose. The
    grip-strength sensitivity rows (``HOLD_GRIP_SENSITIVITY``) run with it."""
    if not factor > 0.0:
        raise ValueError(f"grip strength factor must be > 0, got {factor}")
    kp, kv, cap = (C.HOLD_FINGER_KP * factor, C.HOLD_FINGER_KV * np.sqrt(factor),
                   C.HOLD_FINGER_TORQUE * factor)
    n = model.nu
    _set_servo_params(model, (np.full(n, kp), np.full(n, -kp), np.full(n, -kv),
                              np.tile([-cap, cap], (n, 1))))


def _servo_params(model: mujoco.MjModel) -> tuple[np.ndarray, ...]:
    """The servos' gain, position bias, velocity bias and force range (copies)."""
    return (model.actuator_gainprm[:, 0].copy(), model.actuator_biasprm[:, 1].copy(),
            model.actuator_biasprm[:, 2].copy(), model.actuator_forcerange.copy())


def _set_servo_params(model: mujoco.MjModel, params: tuple[np.ndarray, ...]) -> None:
    model.actuator_gainprm[:, 0], model.actuator_biasprm[:, 1] = params[0], params[1]
    model.actuator_biasprm[:, 2], model.actuator_forcerange[:] = params[2], params[3]


HOLD_RULES = ("depth", "settle", "wedge")  # in the order broken_rules reports them


def broken_rules(depth: float, settle: float, wedge: float) -> tuple[str, ...]:
    """The rules of :data:`HOLD_RULES` a settled scene breaks, failing it before its hold:
    a hand vertex more than ``HOLD_MAX_DEPTH`` inside (depth), a settle past
    ``HOLD_SETTLE_FAIL`` (settle), more than ``HOLD_WEDGE_WEIGHTS`` object weights of
    inward force (wedge: :func:`inward_force`; NaN, not measured, breaks nothing; a NaN
    depth or settle breaks its rule)."""
    broken = (not depth <= C.HOLD_MAX_DEPTH, not settle <= C.HOLD_SETTLE_FAIL,
              wedge > C.HOLD_WEDGE_WEIGHTS)
    return tuple(r for r, b in zip(HOLD_RULES, broken, strict=True) if b)


def _may_hold(depth: float, settle: float, wedge: float) -> bool:
    """Whether a settled scene's hold can count: it breaks none of :func:`broken_rules`."""
    return not broken_rules(depth, settle, wedge)


def inward_force(model: mujoco.MjModel, data: mujoco.MjData,
                 patches: tuple[tuple[np.ndarray, np.ndarray], ...],
                 up: tuple[float, float, float] = C.UP) -> float:
    """The normal force (in weights of the object under ``-g up``) of the contacts that push
    a hand into the object: each contact's object-to-hand normal more than 90 degrees from
    the outward normal of its object piece's surface patch at the patch vertex nearest the
    contact (``patches``: per object geom, in order, its vertices and normals (n, 3) in the
    object's frame). A hand piece touching an object piece from the piece's back, through
    the object, is pushed in. 0 without contacts; NaN without patches (not measured)."""
    import mujoco

    if not patches:
        return float("nan")
    ob = model.body("object").id
    index = {int(g): i for i, g in enumerate(np.flatnonzero(model.geom_bodyid == ob))}
    rot, origin = data.xmat[ob].reshape(3, 3), data.xpos[ob]
    f6, total = np.zeros(6), 0.0
    for k in range(data.ncon):
        c = data.contact[k]
        on_obj = c.geom1 in index
        normal = c.frame[:3] if on_obj else -c.frame[:3]  # the frame's normal: geom1 -> geom2
        verts, normals = patches[index[int(c.geom1 if on_obj else c.geom2)]]
        local = (c.pos - origin) @ rot
        j = int(np.argmin(np.einsum("ij,ij->i", verts - local, verts - local)))
        if (rot @ normals[j]) @ normal < 0.0:
            mujoco.mj_contactForce(model, data, k, f6)
            total += float(f6[0])
    weight = float(model.body_mass[ob]) * C.GRAVITY * float(np.linalg.norm(up))
    return total / weight


def _hold_steps(model: mujoco.MjModel, data: mujoco.MjData, start: np.ndarray) -> bool:
    """The hold's ``SIM_HOLD_SECONDS`` of steps; False when the run diverged.

    Stops early once the object has fallen free: no contact left, at least
    ``HOLD_DISP_CAP`` from ``start`` (its centre of mass after the settle) along gravity
    and still moving along it. While it touches nothing, gravity is the only force on it and
    that distance only grows (a hand part below could stop it, not lift it back), so the
    verdict (failed) and the capped displacement are those of the whole run, and a falling
    object (most failures) costs about 0.15 s of simulated time, not 1 s.
    Checked every ``_FALL_CHECK`` steps."""
    import mujoco

    b = model.body("object").id
    g = model.opt.gravity / max(float(np.linalg.norm(model.opt.gravity)), 1e-12)
    vel = np.zeros(6)
    diverged = _Diverged(model)
    for k in range(int(round(C.SIM_HOLD_SECONDS / C.SIM_DT))):
        mujoco.mj_step(model, data)
        if diverged(data):
            return False
        # contacts, centre of mass and its velocity as mj_step found them, one consistent state
        if (k + 1) % _FALL_CHECK == 0 and data.ncon == 0:
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, vel, 0)
            if vel[3:] @ g >= 0.0 and (data.xipos[b] - start) @ g >= C.HOLD_DISP_CAP:
                break
    mujoco.mj_kinematics(model, data)  # mj_step leaves xipos at the pre-integration positions
    return True


_FALL_CHECK = 6  # steps between the free-fall checks of _hold_steps (25 ms of simulated time)


def _settle(model: mujoco.MjModel, data: mujoco.MjData, targets: np.ndarray) -> bool:
    """Settle without gravity, the servo targets ramping from the frame's pose to the
    tightened one over ``HOLD_RAMP_SECONDS`` (a step would strike the object); False when
    the run diverged."""
    n = int(round(C.HOLD_SETTLE_SECONDS / C.SIM_DT))
    ramp = max(1, int(round(C.HOLD_RAMP_SECONDS / C.SIM_DT)))
    dofs = _object_dofs(model)
    saved = model.dof_damping[dofs].copy()
    model.dof_damping[dofs] = np.repeat(C.HOLD_SETTLE_DAMPING, 3)
    diverged = _Diverged(model)
    try:
        for k in range(n):
            data.ctrl[:] = targets * min(1.0, (k + 1) / ramp)
            if not _step(model, data, 1, diverged):
                return False
    finally:
        model.dof_damping[dofs] = saved
    data.qvel[dofs] = 0.0  # the hold starts from rest
    return True


def _object_dofs(model: mujoco.MjModel) -> np.ndarray:
    """The object's six free-joint dof indices (translation first)."""
    adr = model.jnt_dofadr[model.body("object").jntadr[0]]
    return np.arange(adr, adr + 6)


def _failed(settle: float) -> HoldResult:
    return HoldResult(settle, C.HOLD_DISP_CAP, 180.0, False, True)


def support(scene: Scene, up: tuple[float, float, float] = C.UP) -> SupportResult:
    """GRIP supp. 11: the object from rest under gravity, servos holding the frame's pose
    (no tightening), ``SIM_PAPER_STEPS`` steps; stable when it moves < ``SIM_STABLE_DISP``."""
    import mujoco

    model = scene.model
    model.opt.gravity[:] = -C.GRAVITY * np.asarray(up, np.float64)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start, _ = _pose_of(model, data)
    if not _step(model, data, C.SIM_PAPER_STEPS):
        return SupportResult(float("nan"), False, True)
    disp = float(np.linalg.norm(_pose_of(model, data)[0] - start))
    return SupportResult(disp, disp < C.SIM_STABLE_DISP, False)


# ---------------------------------------------------------------- quasi-static force check
# The check itself (cone_wrenches, plan_forces, can_balance, can_hold) lives in
# geometry.wrench: SynthGRAB's grasp choice uses it too. Its names stay importable from here.


def force_ratio(hands: list[PosedHand], obj: trimesh.Trimesh,
                obj_pose: tuple[np.ndarray, np.ndarray] | None = None,
                up: tuple[float, float, float] = C.UP, mu: float = C.SIM_FRICTION,
                density: float = C.DEFAULT_DENSITY, gravity: np.ndarray | None = None) -> float:
    """Quasi-static check: the largest contact normal force (in units of the object's weight)
    that the hands' vertices within ``HOLD_TOUCH`` of the object need to hold it against
    gravity (``gravity`` (3,) m/s^2, default ``-g up``) with friction ``mu``; ``inf`` when
    they cannot (friction cones too narrow, contacts on one side, no contact).

    Contacts are the closest object-surface points of those vertices with the object's inward
    normals there (the palm counts as a contact like a finger).
    """
    from ..geometry.pieces import ExactDistance
    from .physics import _object_inertia

    R, t = (np.eye(3), np.zeros(3)) if obj_pose is None else (np.asarray(obj_pose[0]),
                                                               np.asarray(obj_pose[1]))
    mass, com, _ = _object_inertia(obj, density)
    verts = [h.vertices[h.signed_dist <= C.HOLD_TOUCH] for h in hands]
    local = (np.concatenate(verts) - t) @ R if verts else np.zeros((0, 3))
    if len(local) == 0:
        return float("inf")
    import igl

    sdf = ExactDistance(obj.vertices, obj.faces)
    _, _, closest, normal = igl.signed_distance(
        np.ascontiguousarray(local), sdf.V, sdf.F,
        sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
    g = -C.GRAVITY * np.asarray(up, np.float64) if gravity is None else np.asarray(gravity)
    weight = mass * float(np.linalg.norm(g))
    f = plan_forces(closest @ R.T + t, -normal @ R.T, R @ com + t, mass * g, mu)
    if f is None:
        return float("inf")
    return float(np.einsum("kc,kc->k", f, -normal @ R.T).max() / weight)


def static_hold(hand_meshes: list[trimesh.Trimesh], obj: trimesh.Trimesh,
              obj_pose: tuple[np.ndarray, np.ndarray] | None = None,
              up: tuple[float, float, float] = C.UP,
              density: float = C.DEFAULT_DENSITY) -> HoldResult:
    """The hold test against static hands (any closed meshes, world frame; no squeeze):
    settle, then 1 s under gravity ``-g up``. ``obj`` in its own frame, placed by
    ``obj_pose`` = (R, t), world = R @ local + t. As for articulated hands, a hand vertex
    more than ``HOLD_MAX_DEPTH`` inside the object fails the test (a wedged object is not
    held). Never raises on a diverging simulation."""
    return hold(static_scene(hand_meshes, obj, obj_pose, up, density), up)[0]
