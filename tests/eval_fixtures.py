"""Small grasping datasets for the evaluation tests: a procedural hand really holding an object.

:func:`grasp_dataset` writes ``DATA/`` (grab/s<k>/*.npz, contact meshes, splits.json) with
short sequences: the right hand approaches, closes onto a grasp found by
:class:`GraspSynthesizer` and lifts the object (hand rigid in the object's frame); for
``bimanual`` specs the left hand grasps too. Grasps are cached per (object, side, seed), so
a test session searches each one once (~2 s).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from grip_bench.data.grab_io import object_mesh_path, object_mesh_relpath, write_grab
from grip_bench.data.sequence import Sequence, make_body_params, make_hand_params, make_rigid_params
from grip_bench.data.splits import write_splits

# (subject, object family, intent, bimanual)
DEFAULT_SPECS = (("s1", "mug", "lift", False), ("s2", "cylindermedium", "pass", True))
TABLE_Y = 0.75  # m, table top height
APPROACH = 0.06  # m, how far back along the approach the wrist starts


@functools.cache
def object_and_grasps(family: str, seed: int = 0):
    """(ObjectInstance, {side: Grasp}) for one object family; deterministic."""
    import torch

    from grip_bench.data.synth import grasp as G
    from grip_bench.data.synth.objects import make_instance
    from grip_bench.geometry.distance import DistanceField

    torch.set_num_threads(1)
    obj = make_instance(family, np.random.default_rng(seed), 0)
    gs = G.GraspSynthesizer(obj.mesh, DistanceField(obj.mesh), 1.0, rest_height=obj.rest_height,
                            grasp_hint=obj.grasp_hint, handles=obj.handles, large=obj.large)
    grasps = {}
    for side, sx in (("right", -1.0), ("left", 1.0)):
        dirs = np.array([[sx * np.sin(a) * np.cos(e), np.sin(e), -np.cos(a) * np.cos(e)]
                         for a in np.radians([60, 90]) for e in np.radians([0, 30])])
        grasps[side] = gs.search(
            side, dirs, np.array([0.0, 0.0, 1.0]), np.random.default_rng(seed + 1)
        )
    return obj, grasps


def _object_track(T: int, rest_height: float) -> tuple[np.ndarray, np.ndarray]:
    """Column-convention object poses R_o (T, 3, 3), p_o (T, 3): rests, then lifts and turns."""
    s = np.clip((np.arange(T) - T // 2) / max(T // 2 - 1, 1), 0.0, 1.0)
    p = np.stack([np.zeros(T), TABLE_Y + rest_height + 0.15 * s, 0.45 + 0.05 * s], axis=1)
    R = Rotation.from_rotvec(np.outer(s, [0.0, 0.4, 0.2])).as_matrix()
    return R, p


def _hand_track(g, R_o, p_o, T: int) -> dict[str, np.ndarray]:
    """Hand params: the wrist slides in along the approach during the first third, then holds."""
    u = np.clip(np.arange(T) / max(T // 3, 1), 0.0, 1.0)
    t_local = g.t[None] + (1.0 - u)[:, None] * APPROACH * g.approach[None]  # object frame
    R_w = np.einsum("tij,jk->tik", R_o, g.R)
    p_w = np.einsum("tij,tj->ti", R_o, t_local) + p_o
    pose = np.tile(np.asarray(g.hand_pose, float).reshape(1, 45), (T, 1))
    return make_hand_params(Rotation.from_matrix(R_w).as_rotvec(), pose, p_w)


def _parked_hand(side: str, T: int) -> dict[str, np.ndarray]:
    x = -0.35 if side == "right" else 0.35
    return make_hand_params(np.zeros((T, 3)), np.zeros((T, 45)), np.tile([x, 0.9, 0.1], (T, 1)))


def grasp_sequence(family: str, sbj: str, intent: str, bimanual: bool, T: int) -> Sequence:
    """One sequence of ``T`` frames (float64 params) over the cached grasps of ``family``."""
    obj, grasps = object_and_grasps(family)
    R_o, p_o = _object_track(T, obj.rest_height)
    hands = {
        "right": _hand_track(grasps["right"], R_o, p_o, T),
        "left": _hand_track(grasps["left"], R_o, p_o, T) if bimanual else _parked_hand("left", T),
    }
    z3 = np.zeros((T, 3))
    body = make_body_params(z3, np.zeros((T, 63)), np.tile([0.0, 0.9, 0.0], (T, 1)),
                            hands["left"]["hand_pose"], hands["right"]["hand_pose"])
    # GRAB's row-vector convention: local @ R + t == R_o @ local + p_o, so R = R_o^T
    objp = make_rigid_params(Rotation.from_matrix(np.transpose(R_o, (0, 2, 1))).as_rotvec(), p_o)
    table = make_rigid_params(z3, np.tile([0.0, TABLE_Y, 0.45], (T, 1)))
    return Sequence(
        name=f"{sbj}/{family}_{intent}_1", sbj_id=sbj, gender="female", obj_name=family,
        motion_intent=intent, body=body, rhand=hands["right"], lhand=hands["left"], object=objp,
        table=table, contact={"object": np.zeros((T, len(obj.mesh.vertices)), np.int32)},
        body_model="procedural", hand_scale=1.0, object_mesh=object_mesh_relpath(family),
    ).validate()


def grasp_dataset(root: Path, specs=DEFAULT_SPECS, T: int = 24, split: str = "test") -> list[Path]:
    """Write ``DATA/`` with one grasping sequence per spec; all objects in ``split``."""
    root = Path(root)
    files = []
    for sbj, family, intent, bimanual in specs:
        seq = grasp_sequence(family, sbj, intent, bimanual, T)
        files.append(write_grab(seq, root / "grab" / sbj / f"{family}_{intent}_1.npz"))
        mesh_path = object_mesh_path(root, family)
        if not mesh_path.exists():
            mesh_path.parent.mkdir(parents=True, exist_ok=True)
            object_and_grasps(family)[0].mesh.export(mesh_path)
    objects = sorted({s[1] for s in specs})
    splits = {"train": [], "val": [], "test": []}
    splits[split] = objects
    write_splits(root, splits)
    (root / "manifest.json").write_text(
        json.dumps({"generator": "test-fixture", "dataset": "fixture"})
    )
    return files
