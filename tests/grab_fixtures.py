"""Small format-faithful GRAB fixtures written by the tests themselves (no licensed data).

- :func:`make_sequence`: a random but plausible :class:`Sequence` (SynthGRAB-style, 30 fps).
- :func:`write_dataset`: a ``DATA/`` folder (grab/s<k>/*.npz, contact meshes, splits.json).
- :func:`write_real_grab_file`: a file shaped like a released GRAB file (120 fps,
  24 PCA hand coefficients, no ``body_model`` key), written with plain ``np.savez``.
- :class:`FakeMano`: a stand-in MANO backend with random orthonormal PCA components and a
  MANO-layout model per side (:func:`mano_model_arrays`: 778-vertex tube whose rest wrist
  J0 lies 13 cm from the origin), written as model files by :func:`write_mano_models`.
- :func:`write_subject_templates`: the subject hand templates a GRAB file names, as .ply.
- :func:`full_size_grab_arrays`: a file shaped like a full-size GRAB sequence (memory tests).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from grip_bench.data.grab_io import object_mesh_path, object_mesh_relpath, write_grab
from grip_bench.data.sequence import (
    Sequence,
    contact_label,
    make_body_params,
    make_hand_params,
    make_rigid_params,
)
from grip_bench.data.splits import write_splits

BOX_EXTENTS = (0.08, 0.05, 0.12)


def box_mesh() -> trimesh.Trimesh:
    """A tiny watertight box object (8 vertices), metres."""
    return trimesh.creation.box(extents=BOX_EXTENTS)


def _poses(rng, T, k, scale=0.3, dtype=np.float32):
    return (rng.normal(0, scale, size=(T, k))).astype(dtype)


def _transl(rng, T, centre, dtype=np.float32):
    walk = np.cumsum(rng.normal(0, 0.002, size=(T, 3)), axis=0)
    return (np.asarray(centre) + walk).astype(dtype)


def make_sequence(T: int = 40, *, seed: int = 0, obj_name: str = "mug", intent: str = "lift",
                  sbj_id: str = "s1", n_obj_verts: int = 8, dtype=np.float32,
                  body_model: str = "procedural", with_body_contact: bool = False) -> Sequence:
    """A plausible random sequence: small poses, metre-scale positions, GRAB contact labels."""
    rng = np.random.default_rng(seed)
    body = make_body_params(_poses(rng, T, 3, dtype=dtype), _poses(rng, T, 63, 0.2, dtype),
                            _transl(rng, T, (0.0, 0.9, 0.0), dtype),
                            _poses(rng, T, 45, dtype=dtype), _poses(rng, T, 45, dtype=dtype),
                            expression=_poses(rng, T, 10, 0.5, dtype))
    rhand = make_hand_params(_poses(rng, T, 3, 1.0, dtype), _poses(rng, T, 45, dtype=dtype),
                             _transl(rng, T, (-0.3, 1.0, 0.3), dtype))
    lhand = make_hand_params(_poses(rng, T, 3, 1.0, dtype), _poses(rng, T, 45, dtype=dtype),
                             _transl(rng, T, (0.3, 1.0, 0.3), dtype))
    obj = make_rigid_params(_poses(rng, T, 3, 1.0, dtype), _transl(rng, T, (0.0, 0.8, 0.4), dtype))
    table = make_rigid_params(
        np.zeros((T, 3), dtype), np.tile(np.array([0, 0.75, 0.4], dtype), (T, 1))
    )
    labels = np.zeros((T, n_obj_verts), dtype=np.int32)
    grasp = slice(T // 4, 3 * T // 4)
    labels[grasp, 0] = contact_label("right_index3")
    labels[grasp, 1] = contact_label("right_thumb3")
    labels[T // 2:, 2] = contact_label("left_middle2")
    contact = {"object": labels}
    if with_body_contact:
        contact["body"] = (rng.random((T, 30)) < 0.1).astype(np.int32)
    return Sequence(
        name=f"{sbj_id}/{obj_name}_{intent}_1", sbj_id=sbj_id, gender="female", obj_name=obj_name,
        motion_intent=intent, body=body, rhand=rhand, lhand=lhand, object=obj, table=table,
        contact=contact, body_model=body_model, height=1.68, hand_scale=0.97,
        object_mesh=object_mesh_relpath(obj_name),
    ).validate()


def write_dataset(root: Path, specs, *, T: int = 20, splits: dict | None = None) -> list[Path]:
    """Write ``DATA/`` with one sequence per (sbj_id, obj_name, intent) spec; returns the files."""
    root = Path(root)
    files = []
    for i, (sbj, obj, intent) in enumerate(specs):
        seq = make_sequence(T, seed=i, obj_name=obj, intent=intent, sbj_id=sbj)
        files.append(write_grab(seq, root / "grab" / sbj / f"{obj}_{intent}_1.npz"))
        mesh_path = object_mesh_path(root, obj)
        if not mesh_path.exists():
            mesh_path.parent.mkdir(parents=True, exist_ok=True)
            box_mesh().export(mesh_path)
    if splits is not None:
        write_splits(root, splits)
    return files


class FakeMano:
    """MANO stand-in: orthonormal 45x45 'components', a fixed mean pose, and a MANO-layout
    model per side (``model[side]``, :func:`mano_model_arrays`) for the rest wrist J0."""

    def __init__(self, seed: int = 7):
        rng = np.random.default_rng(seed)
        self.components = {s: np.linalg.qr(rng.normal(size=(45, 45)))[0] for s in ("right", "left")}
        self.mean = {s: rng.normal(0, 0.1, size=45) for s in ("right", "left")}
        self.model = {s: mano_model_arrays(s, seed) for s in ("right", "left")}
        for s in ("right", "left"):
            self.model[s].update(hands_components=self.components[s], hands_mean=self.mean[s])

    def expand_pca(self, side, coeffs):
        return coeffs @ self.components[side][: coeffs.shape[1]]

    def hands_mean(self, side):
        return self.mean[side]

    def rest_wrist(self, side, v_template=None):
        m = self.model[side]
        return m["J_regressor"][0] @ (m["v_template"] if v_template is None else v_template)


# MANO's rest wrist J0 in the fixture models (right hand; the left is its x-mirror): 13 cm
# from the origin, so reading GRAB's transl as the wrist would be off by that much.
FIXTURE_WRIST = (0.11, 0.06, -0.03)
# A subject's template: the model's, moved by this (right; left mirrored), so J0 moves too.
SUBJECT_SHIFT = (0.012, -0.008, 0.005)


def tube(radius_y: float, radius_z: float, n_rings: int = 37,
         n_around: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """An outward-oriented elliptic tube along -x: open ring at x = 0, closed far end.

    37 x 21 ring vertices + 1 pole = 778, MANO's vertex count, so MANO's default fingertip
    ids are valid.
    """
    t = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    rings = [np.stack([np.full(n_around, -0.005 * k), radius_y * np.cos(t),
                       radius_z * np.sin(t)], 1) for k in range(n_rings)]
    verts = np.concatenate([*rings, [[-0.005 * n_rings, 0.0, 0.0]]])
    faces = []
    for k in range(n_rings - 1):
        for i in range(n_around):
            a, b = k * n_around + i, k * n_around + (i + 1) % n_around
            faces += [(a, b + n_around, b), (a, a + n_around, b + n_around)]
    last, pole = (n_rings - 1) * n_around, len(verts) - 1
    faces += [(last + i, pole, last + (i + 1) % n_around) for i in range(n_around)]
    faces = np.array(faces)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    if mesh.face_normals[0][1:] @ verts[faces[0]].mean(0)[1:] < 0:  # side walls face outward
        faces = faces[:, ::-1]
    return verts, np.ascontiguousarray(faces)


def hand_tube(side: str = "right", n_rings: int = 37, n_around: int = 21):
    """A MANO-sized hand stand-in (778 vertices): an outward-oriented tube from the wrist
    ring (at :data:`FIXTURE_WRIST`, open) along -x (right; +x left) to a closed tip."""
    verts, faces = tube(0.03, 0.02, n_rings, n_around)
    verts = verts + np.asarray(FIXTURE_WRIST)
    if side == "left":
        verts, faces = verts * np.array([-1.0, 1.0, 1.0]), faces[:, ::-1]
    return verts.astype(np.float32), np.ascontiguousarray(faces)


def mano_model_arrays(side: str = "right", seed: int = 7) -> dict:
    """A MANO_{RIGHT,LEFT} model's keys and shapes (random skinning, 10 shape directions)
    on :func:`hand_tube`; the wrist joint regresses the wrist ring's centre."""
    from grip_bench.bodies.layouts import MANO_PARENTS

    rng = np.random.default_rng([seed, side == "right"])
    verts, faces = hand_tube(side)
    n = len(verts)
    weights = rng.random((n, 16)) ** 4
    weights /= weights.sum(1, keepdims=True)
    reg = np.zeros((16, n))
    reg[0, :21] = 1.0 / 21  # the wrist ring
    for j in range(1, 16):
        reg[j, rng.choice(n, 4, replace=False)] = 0.25
    comps = np.linalg.qr(rng.normal(size=(45, 45)))[0]
    return {
        "v_template": verts.astype(np.float64), "f": faces.astype(np.uint32), "weights": weights,
        "J_regressor": reg,
        "kintree_table": np.array([[2**32 - 1, *MANO_PARENTS[1:]], list(range(16))], np.int64),
        "posedirs": rng.normal(scale=1e-4, size=(n, 3, 135)),
        "shapedirs": rng.normal(scale=1e-3, size=(n, 3, 10)),
        "hands_components": comps, "hands_mean": rng.normal(scale=0.1, size=45),
    }


def write_mano_models(model_dir: Path, mano: FakeMano) -> Path:
    """``model_dir/mano/MANO_{RIGHT,LEFT}.npz`` holding ``mano``'s models; returns model_dir."""
    model_dir = Path(model_dir)
    (model_dir / "mano").mkdir(parents=True, exist_ok=True)
    for side in ("right", "left"):
        np.savez(model_dir / "mano" / f"MANO_{side.upper()}.npz", **mano.model[side])
    return model_dir


def subject_template(mano: FakeMano, side: str) -> np.ndarray:
    """The fixture subject's hand template ``(778, 3)`` float32: the model's, shifted."""
    shift = np.asarray(SUBJECT_SHIFT) * (np.array([-1.0, 1.0, 1.0]) if side == "left" else 1.0)
    return (mano.model[side]["v_template"] + shift).astype(np.float32)


def write_subject_templates(root: Path, arrays: dict, mano: FakeMano) -> dict[str, np.ndarray]:
    """Write the hand templates the GRAB file members ``arrays`` name (``rhand``/``lhand``
    ``vtemp``, relative to the data root ``root``) as .ply; returns J0 (3,) per side."""
    j0 = {}
    for part, side in (("rhand", "right"), ("lhand", "left")):
        verts = subject_template(mano, side)
        path = Path(root) / arrays[part].item()["vtemp"]
        path.parent.mkdir(parents=True, exist_ok=True)
        trimesh.Trimesh(verts, mano.model[side]["f"], process=False).export(path)
        j0[side] = mano.rest_wrist(side, verts)
    return j0


def _obj(value):
    a = np.empty((), dtype=object)
    a[()] = value
    return a


def real_grab_arrays(T: int = 41, n_comps: int = 24, framerate: float = 120.0, seed: int = 3,
                     n_obj_verts: int = 8) -> dict:
    """Members of a file shaped like a released GRAB ``.npz`` (hands as PCA, hand fullpose 45)."""
    rng = np.random.default_rng(seed)
    f = np.float32
    p = lambda k, s=0.3: rng.normal(0, s, size=(T, k)).astype(f)  # noqa: E731
    tr = lambda c: (np.asarray(c) + np.cumsum(rng.normal(0, 0.001, (T, 3)), 0)).astype(f)  # noqa: E731
    body = {"global_orient": p(3), "body_pose": p(63, 0.2), "transl": tr((0, 0, 0.9)),
            "right_hand_pose": p(n_comps), "left_hand_pose": p(n_comps), "jaw_pose": p(3, 0.05),
            "leye_pose": p(3, 0.05), "reye_pose": p(3, 0.05), "expression": p(10),
            "fullpose": p(165, 0.2)}
    hands = {s: {"global_orient": p(3, 1.0), "hand_pose": p(n_comps), "transl": tr(c),
                 "fullpose": p(45)} for s, c in (("r", (0.2, -0.3, 1.0)), ("l", (0.2, 0.3, 1.0)))}
    labels = np.zeros((T, n_obj_verts), dtype=np.int32)
    labels[T // 3:, 0] = contact_label("right_index1")
    return {
        "gender": np.array("male"), "sbj_id": np.array("s1"), "obj_name": np.array("mug"),
        "motion_intent": np.array("lift"), "framerate": np.array(framerate),
        "n_frames": np.array(T), "n_comps": np.array(n_comps),
        "body": _obj({"params": body, "vtemp": "tools/subject_meshes/male/s1.ply"}),
        "rhand": _obj({"params": hands["r"], "vtemp": "tools/subject_meshes/male/s1_rhand.ply"}),
        "lhand": _obj({"params": hands["l"], "vtemp": "tools/subject_meshes/male/s1_lhand.ply"}),
        "object": _obj({"params": {"global_orient": p(3, 1.0), "transl": tr((0, 0, 0.8))},
                        "object_mesh": object_mesh_relpath("mug")}),
        "table": _obj({"params": {"global_orient": np.zeros((T, 3), f), "transl": tr((0, 0, 0.7))},
                       "table_mesh": "tools/object_meshes/contact_meshes/table.ply"}),
        "contact": _obj({"object": labels, "body": np.zeros((T, 20), dtype=np.int32)}),
    }


def write_npz(path: Path, arrays: dict) -> Path:
    """Write members with plain ``np.savez`` (what GRAB's own tooling produced)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    return path


def full_size_grab_arrays(T: int = 2310, n_obj_verts: int = 48370, n_body_verts: int = 10475,
                          contact_dtype=np.int8, seed: int = 0, n_comps: int = 24) -> dict:
    """Members of a full-size GRAB sequence: 120 fps, PCA hands, sparse contact labels on a
    ``(T, n_obj_verts)`` object and a ``(T, n_body_verts)`` body (GRAB's largest arrays)."""
    raw = real_grab_arrays(T=T, n_comps=n_comps, seed=seed + 1)
    rng = np.random.default_rng(seed)
    contact = {}
    for key, n, label in (("object", n_obj_verts, contact_label("right_index3")),
                          ("body", n_body_verts, 1)):
        a = np.zeros((T, n), contact_dtype)
        a[rng.random((T, n)) < 0.002] = label
        contact[key] = a
    raw["contact"] = _obj(contact)
    return raw
