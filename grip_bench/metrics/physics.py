"""Physics stability in MuJoCo: hand fixed, object free under gravity (GRIP supp. 11).

Definitions: docs/contract.md, "Definitions".

MuJoCo collides every mesh geom as its convex hull, so both bodies enter as convex pieces:
the hand as one hull per bone (posed rigidly from the current frame's vertices, with a
one-ring overlap so no gaps open between bones) and the object as a CoACD convex
decomposition computed once per mesh and cached. A concave object is never one hull: a ball
resting in a bowl would start deep inside the bowl's hull and be thrown out.

``mujoco`` and ``coacd`` are imported inside the functions to keep ``grip_bench.metrics`` light.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

if TYPE_CHECKING:  # trimesh costs 0.5 s to import; `grip-bench ls` should not pay it
    import mujoco
    import trimesh

from ..core import constants as C


@dataclass(frozen=True)
class StabilityResult:
    """Outcome of one simulation: ``displacement`` (m) of the object's centre of mass,
    ``stable`` (displacement < constants.SIM_STABLE_DISP), ``diverged`` (NaN or runaway
    velocity; displacement is NaN and stable False then)."""

    displacement: float
    stable: bool
    diverged: bool


# ---------------------------------------------------------------- convex pieces
_PIECE_CACHE: dict[str, list[np.ndarray]] = {}


def _mesh_key(mesh: trimesh.Trimesh, threshold: float) -> str:
    h = hashlib.sha1(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    h.update(repr(threshold).encode())
    return h.hexdigest()


def _hull_volume(points: np.ndarray) -> float:
    """Convex hull volume, 0 for degenerate (flat, collinear, < 4) point sets."""
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 4:
        return 0.0
    try:
        return float(ConvexHull(points).volume)
    except (QhullError, ValueError):
        return 0.0


def _usable(points: np.ndarray) -> bool:
    """Whether the hull of ``points`` is thicker than ``SIM_MIN_PIECE_VOLUME``.

    MuJoCo refuses flat hulls; a piece thinner than this holds nothing anyway. The answer is
    ``_hull_volume(points) > SIM_MIN_PIECE_VOLUME``; Qhull only runs when two cheap bounds
    leave it open: the bounding box's volume (an upper bound) and the volume of a tetrahedron
    of extreme points (a lower bound; decides every real hand piece, ~1e-6 m^3).
    """
    p = np.asarray(points, dtype=np.float64)
    if len(p) < 4:
        return False
    limit = C.SIM_MIN_PIECE_VOLUME
    if _tetra_volume(p) > limit * (1.0 + 1e-9):
        return True
    ext = p.max(0) - p.min(0)
    if ext[0] * ext[1] * ext[2] <= limit * (1.0 - 1e-9):
        return False
    return _hull_volume(p) > limit


def _tetra_volume(p: np.ndarray) -> float:
    """Volume of a tetrahedron spanned by four of the points (N >= 4, 3): a hull lower bound."""
    d = p - p[0]
    d2 = np.einsum("ij,ij->i", d, d)
    b = d[np.argmax(d2)]
    bb = float(b @ b)
    if bb == 0.0:
        return 0.0
    db = d @ b
    c = d[np.argmax(d2 * bb - db * db)]  # farthest from the line through p[0] along b
    n = np.array([b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2], b[0] * c[1] - b[1] * c[0]])
    return float(np.abs(d @ n).max()) / 6.0


def convex_decomposition(
    mesh: trimesh.Trimesh, threshold: float = C.SIM_COACD_THRESHOLD
) -> list[np.ndarray]:
    """Convex pieces of a closed mesh as vertex arrays [(n_i, 3)], cached by mesh content.

    A mesh within 1% of its hull's volume is its own single piece (no CoACD run). CoACD runs
    with reduced search settings (see constants.SIM_COACD_*): about 1 s for a torus, 3-4 s for
    a thin bowl, once per object and machine: the pieces are kept in memory and in the on-disk
    geometry cache (``grip_bench.geometry.cache``), byte for byte as CoACD returned them.
    """
    key = _mesh_key(mesh, threshold)
    if key not in _PIECE_CACHE:
        _PIECE_CACHE[key] = _cached_pieces(mesh, threshold)
    return _PIECE_CACHE[key]


def _decompose(mesh: trimesh.Trimesh, threshold: float) -> list[np.ndarray]:
    """The uncached work of ``convex_decomposition``."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if abs(mesh.volume) >= (1.0 - C.SIM_CONVEX_TOL) * _hull_volume(v):
        pieces = [v]
    else:
        pieces = _run_coacd(v, np.asarray(mesh.faces), threshold)
    return [p for p in pieces if _usable(p)] or [v]


def _cached_pieces(mesh: trimesh.Trimesh, threshold: float) -> list[np.ndarray]:
    """``_decompose`` through the on-disk geometry cache (``grip_bench.geometry.cache``):
    CoACD takes seconds per object and every evaluation process needs it."""
    from ..geometry.cache import cached_arrays, mesh_key, package_version

    params = {"threshold": float(threshold), "convex_tol": C.SIM_CONVEX_TOL,
              "min_volume": C.SIM_MIN_PIECE_VOLUME, "max_hulls": C.SIM_COACD_MAX_HULLS,
              "resolution": C.SIM_COACD_RESOLUTION, "mcts_iterations": C.SIM_COACD_MCTS_ITERATIONS,
              "mcts_nodes": C.SIM_COACD_MCTS_NODES, "coacd": package_version("coacd"),
              "scipy": package_version("scipy")}

    def build() -> dict[str, np.ndarray]:
        pieces = _decompose(mesh, threshold)
        return {
            "points": np.concatenate(pieces),
            "sizes": np.array([len(p) for p in pieces], np.int64),
        }

    key = mesh_key("convex_pieces", mesh.vertices, mesh.faces, params)
    def ok(a: dict) -> bool:
        return (a["points"].ndim == 2 and a["points"].shape[1] == 3 and a["sizes"].ndim == 1
                and len(a["sizes"]) > 0 and (a["sizes"] > 0).all()
                and int(a["sizes"].sum()) == len(a["points"]))

    a = cached_arrays("convex_pieces", key, build, names=("points", "sizes"), validate=ok)
    points = np.asarray(a["points"], dtype=np.float64)
    return [np.ascontiguousarray(p) for p in np.split(points, np.cumsum(a["sizes"])[:-1])]


def _run_coacd(v: np.ndarray, f: np.ndarray, threshold: float) -> list[np.ndarray]:
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(v, f),
        threshold=threshold,
        max_convex_hull=C.SIM_COACD_MAX_HULLS,
        resolution=C.SIM_COACD_RESOLUTION,
        mcts_iterations=C.SIM_COACD_MCTS_ITERATIONS,
        mcts_nodes=C.SIM_COACD_MCTS_NODES,
        seed=0,
    )
    return [np.asarray(pv, dtype=np.float64) for pv, _ in parts]


def hand_convex_pieces(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    """Convex pieces of a posed hand from ``metadata["bone_ids"]`` (V,): bones split into clusters.

    A curled finger segment or a cupped palm is not convex: the hull of a whole bone's
    vertices bulges into a held object (measured: 2.5-3.6 mm into SynthGRAB objects whose
    hand vertices stay 0.8 mm outside). Each bone's vertices are therefore split into
    clusters of at most ``SIM_HAND_PIECE_POINTS`` (k-means, fixed seed) and each cluster
    is hulled on its own (measured: about 1.3 mm). Without bone ids (another hand model,
    a plain mesh) the hand goes through ``convex_decomposition``.
    """
    bone = mesh.metadata.get("bone_ids") if mesh.metadata else None
    if bone is None:
        return convex_decomposition(mesh)
    bone = np.asarray(bone)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    key = _hand_key(v, bone)
    if key in _HAND_CACHE:
        _HAND_CACHE.move_to_end(key)
        return list(_HAND_CACHE[key])
    pieces = []
    for b in np.unique(bone):
        idx = np.flatnonzero(bone == b)
        for cluster in _clusters(v[idx]):
            if _usable(v[idx[cluster]]):
                pieces.append(v[idx[cluster]])
    _remember(_HAND_CACHE, key, pieces)
    return list(pieces)


# Recently posed hands and compiled scenes by content: the evaluation simulates each tested
# frame under two protocols (same hands, same scene), so the second run reuses both.
_LRU_SIZE = 48
_HAND_CACHE: OrderedDict[str, list[np.ndarray]] = OrderedDict()
_MODEL_CACHE: OrderedDict[str, object] = OrderedDict()
_INERTIA_CACHE: OrderedDict[str, tuple] = OrderedDict()


def _remember(cache: OrderedDict, key: str, value: object) -> None:
    cache[key] = value
    if len(cache) > _LRU_SIZE:
        cache.popitem(last=False)


def _hand_key(v: np.ndarray, bone: np.ndarray) -> str:
    h = hashlib.sha1(np.ascontiguousarray(v, dtype=np.float64).tobytes())
    h.update(repr((v.shape, bone.dtype.str, bone.shape, C.SIM_HAND_PIECE_POINTS,
                   C.SIM_MIN_PIECE_VOLUME)).encode())
    h.update(np.ascontiguousarray(bone).tobytes())
    return h.hexdigest()


def _clusters(points: np.ndarray) -> list[np.ndarray]:
    """Index arrays splitting ``points`` (N, 3) into compact groups.

    Each group has about ``SIM_HAND_PIECE_POINTS`` points.
    """
    k = int(np.ceil(len(points) / C.SIM_HAND_PIECE_POINTS))
    if k <= 1:
        return [np.arange(len(points))]
    from scipy.cluster.vq import kmeans2

    _, label = kmeans2(points, k, minit="++", seed=0)
    return [np.flatnonzero(label == c) for c in range(k) if (label == c).any()]


# ---------------------------------------------------------------- model
def _contact_params(geom: mujoco.MjsGeom, margin: float = 0.0) -> None:
    """Contact settings shared by hand and object geoms (the why lives in constants)."""
    geom.friction = [C.SIM_FRICTION, C.SIM_TORSIONAL_FRICTION, C.SIM_ROLLING_FRICTION]
    geom.condim = C.SIM_CONDIM
    geom.solref = list(C.SIM_SOLREF)
    geom.solimp = list(C.SIM_SOLIMP)
    # MuJoCo adds the margins of the two geoms of a pair, so only the hand carries one.
    geom.margin = margin
    geom.gap = 0.0


def _add_pieces(
    spec: mujoco.MjSpec,
    body: mujoco.MjsBody,
    pieces: list[np.ndarray],
    prefix: str,
    margin: float = 0.0,
    assets: dict[str, bytes] | None = None,
) -> None:
    """One mesh geom per convex piece (hull computed by MuJoCo). ``assets``: give each piece
    as an in-memory MSH file (into that dict, for ``spec.assets``) named by its content, so
    MuJoCo's mesh cache processes it once per process (``_msh_asset``); otherwise as
    ``uservert``. Both hold the same float32 vertices and compile to the same model."""
    import mujoco

    for i, pts in enumerate(pieces):
        mesh = spec.add_mesh()
        mesh.name = f"{prefix}{i}"
        if assets is None:
            mesh.uservert = np.asarray(pts, dtype=np.float64).ravel().tolist()
        else:
            mesh.file, data = _msh_asset(pts)
            assets[mesh.file] = data
        geom = body.add_geom()
        geom.type = mujoco.mjtGeom.mjGEOM_MESH
        geom.meshname = mesh.name
        _contact_params(geom, margin)


def _msh_asset(points: np.ndarray) -> tuple[str, bytes]:
    """``points`` (n, 3) as a MuJoCo MSH file (int32 counts nvert, nnormal, ntexcoord, nface;
    then float32 xyz: a point cloud whose hull MuJoCo computes) and a name unique to its bytes.

    Why: compiling a scene processes every mesh (hull, graph, inertia, bounding volumes); the
    object's pieces are the same in every simulated frame of an object (~25 % of a compile),
    and MuJoCo caches processed meshes by file name, so a content-derived name makes each
    piece processed once per process and never confused with another. The float32 values are
    those ``uservert`` stores (round to nearest), so the compiled model is the same
    (``mesh_pathadr`` aside; checked in tests/unit/test_metrics_physics_speed.py).
    """
    v = np.ascontiguousarray(points, dtype=np.float64).astype(np.float32)
    data = np.array([len(v), 0, 0, 0], dtype="<i4").tobytes() + v.astype("<f4").tobytes()
    return f"gb-{hashlib.sha256(data).hexdigest()}.msh", data


def _object_inertia(obj: trimesh.Trimesh, density: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, centre of mass (3,) and full inertia [xx, yy, zz, xy, xz, yz] of the true shape.

    Taken from the closed mesh, not from the pieces: CoACD hulls overlap and overfill.
    Remembered per mesh content and density (every tested frame of a sequence needs it).
    """
    key = _mesh_key(obj, density)
    if key not in _INERTIA_CACHE:
        _remember(_INERTIA_CACHE, key, _mass_properties(obj, density))
    mass, com, full = _INERTIA_CACHE[key]
    return mass, com.copy(), full.copy()


def _mass_properties(obj: trimesh.Trimesh, density: float) -> tuple[float, np.ndarray, np.ndarray]:
    import trimesh

    props = trimesh.triangles.mass_properties(obj.triangles, density=density)
    inertia = np.asarray(props.inertia)  # about the centre of mass
    full = np.array(
        [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    )
    return float(props.mass), np.asarray(props.center_mass), full


def build_model(
    hand_pieces: list[np.ndarray],
    obj: trimesh.Trimesh,
    obj_pieces: list[np.ndarray],
    obj_pose: tuple[np.ndarray, np.ndarray] | None = None,
    up: tuple[float, float, float] = C.UP,
    density: float = C.DEFAULT_DENSITY,
) -> mujoco.MjModel:
    """Compile the scene: hand pieces static in the world, the object one free body.

    hand_pieces: world-frame vertex arrays; obj, obj_pieces: the object's own frame;
    obj_pose: (R (3, 3), t (3,)) with world = R @ local + t. Returns ``mujoco.MjModel``.
    """
    import mujoco

    spec = mujoco.MjSpec()
    spec.option.timestep = C.SIM_DT
    spec.option.gravity = (-C.GRAVITY * np.asarray(up, dtype=np.float64)).tolist()
    # Semi-implicit Euler: free fall after n steps is exactly g dt^2 n (n + 1) / 2.
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC  # no pyramid bias on pinch grasps
    spec.option.impratio = C.SIM_IMPRATIO  # stiffer friction than normal: less creep in a hold
    # Skin compliance: the hand's contacts act within SIM_CONTACT_MARGIN, as if it were 1 mm
    # thicker. Grasps (ground truth and methods alike) rest ~0.8 mm off the surface, and a
    # rigid hand that does not penetrate could otherwise never hold anything.
    # World geoms: fixed, never collide with each other.
    _add_pieces(spec, spec.worldbody, hand_pieces, "hand", margin=C.SIM_CONTACT_MARGIN)
    body = add_free_object(spec, obj, obj_pose, density)
    assets: dict[str, bytes] = {}
    _add_pieces(spec, body, obj_pieces, "obj", assets=assets)
    spec.assets = assets
    return spec.compile()


def add_free_object(spec: mujoco.MjSpec, obj: trimesh.Trimesh,
                    pose: tuple[np.ndarray, np.ndarray] | None,
                    density: float) -> mujoco.MjsBody:
    """The body "object": free joint, placed by ``pose`` = (R, t) (world = R @ local + t), with
    the mass and inertia of the true closed mesh (collision pieces overlap and overfill)."""
    body = spec.worldbody.add_body()
    body.name = "object"
    if pose is not None:
        rot, trans = pose
        body.pos = np.asarray(trans, dtype=np.float64).tolist()
        body.quat = _matrix_to_wxyz(np.asarray(rot, dtype=np.float64)).tolist()
    body.add_freejoint()
    mass, com, full = _object_inertia(obj, density)
    body.explicitinertial = True
    body.mass, body.ipos, body.fullinertia = mass, com.tolist(), full.tolist()
    return body


def _matrix_to_wxyz(rot: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return np.array([w, x, y, z])


# ---------------------------------------------------------------- simulation
def simulate(model: mujoco.MjModel, n_steps: int) -> tuple[float, bool]:
    """Step from rest; return (centre-of-mass displacement m, diverged)."""
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start = data.xipos[1].copy()
    for _ in range(n_steps):
        mujoco.mj_step(model, data)
        if not np.isfinite(data.qpos).all() or np.abs(data.qvel[:3]).max() > C.SIM_MAX_SPEED:
            return float("nan"), True
    mujoco.mj_kinematics(model, data)  # mj_step leaves xipos at the pre-integration positions
    if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0:
        return float("nan"), True  # MuJoCo reset the state after a NaN acceleration
    return float(np.linalg.norm(data.xipos[1] - start)), False


def protocol_steps(protocol: Literal["paper", "hold"]) -> int:
    """Number of steps of constants.SIM_DT for a protocol name."""
    from ..core.errors import InputError

    if protocol == "paper":
        return C.SIM_PAPER_STEPS
    if protocol == "hold":
        return int(round(C.SIM_HOLD_SECONDS / C.SIM_DT))
    raise InputError(f"unknown protocol '{protocol}' (known: paper, hold)", "protocol")


def _compiled(
    hand_pieces: list[np.ndarray],
    obj: trimesh.Trimesh,
    obj_pieces: list[np.ndarray],
    obj_pose: tuple[np.ndarray, np.ndarray] | None,
    up: tuple[float, float, float],
    density: float,
) -> mujoco.MjModel:
    """``build_model``, reusing the model compiled for an identical scene (content key: every
    piece, the object mesh, pose, up, density and the SIM_* constants). A model is never
    changed by simulating it (``simulate`` works on its own ``MjData``)."""
    h = hashlib.sha1()
    for group in (hand_pieces, [obj.vertices, obj.faces], obj_pieces):
        h.update(b"|group|")
        for a in group:
            a = np.ascontiguousarray(a)
            h.update(repr((a.dtype.str, a.shape)).encode())
            h.update(a.tobytes())
    pose = (
        None if obj_pose is None else [np.asarray(x, dtype=np.float64).tolist() for x in obj_pose]
    )
    sim = [(k, getattr(C, k)) for k in sorted(dir(C)) if k.startswith("SIM_") or k == "GRAVITY"]
    h.update(repr((pose, np.asarray(up, dtype=np.float64).tolist(), float(density), sim)).encode())
    key = h.hexdigest()
    if key in _MODEL_CACHE:
        _MODEL_CACHE.move_to_end(key)
        return _MODEL_CACHE[key]
    model = build_model(hand_pieces, obj, obj_pieces, obj_pose, up, density)
    _remember(_MODEL_CACHE, key, model)
    return model


def stability(
    hand_meshes: list[trimesh.Trimesh],
    obj: trimesh.Trimesh,
    protocol: Literal["paper", "hold"] = "paper",
    obj_pose: tuple[np.ndarray, np.ndarray] | None = None,
    up: tuple[float, float, float] = C.UP,
    density: float = C.DEFAULT_DENSITY,
    obj_pieces: list[np.ndarray] | None = None,
) -> StabilityResult:
    """Simulate the object under gravity against fixed hands and measure how far it moves.

    hand_meshes: posed hands in the world frame (one or two); obj: the object in its own frame,
    placed by obj_pose = (R, t) (None: identity); obj_pieces: precomputed convex pieces (the
    cached CoACD decomposition of ``obj`` by default). Never raises on a diverging simulation.
    """
    n_steps = protocol_steps(protocol)
    hand_pieces = [p for h in hand_meshes for p in hand_convex_pieces(h)]
    pieces = convex_decomposition(obj) if obj_pieces is None else obj_pieces
    model = _compiled(hand_pieces, obj, pieces, obj_pose, up, density)
    disp, diverged = simulate(model, n_steps)
    return StabilityResult(disp, bool(not diverged and disp < C.SIM_STABLE_DISP), diverged)


def stability_sequence(
    hand_meshes: list[list[trimesh.Trimesh]],
    obj: trimesh.Trimesh,
    obj_poses: list[tuple[np.ndarray, np.ndarray]] | None = None,
    protocol: Literal["paper", "hold"] = "paper",
    up: tuple[float, float, float] = C.UP,
    density: float = C.DEFAULT_DENSITY,
) -> list[StabilityResult]:
    """``stability`` for each frame of a sequence; the object's pieces are computed once.

    hand_meshes: per frame, the list of posed hands; obj_poses: per frame (R, t) or None.
    """
    pieces = convex_decomposition(obj)
    return [
        stability(
            hands, obj, protocol, None if obj_poses is None else obj_poses[t], up, density, pieces
        )
        for t, hands in enumerate(hand_meshes)
    ]
