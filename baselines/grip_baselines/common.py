"""Shared plumbing of the baseline methods: data loading, frames, hands, configs, checkpoints.

Conventions (``docs/architecture.md``): metres and radians; object poses follow GRAB's
row-vector rule ``world = local @ R_row + t``, i.e. the column rotation is ``R_row^T``;
hand frames are ``world = R_wrist @ local + transl``. The left procedural hand is the
x-mirror of the right one, so a left hand is brought into the right hand's frame by
``S = diag(-1, 1, 1)`` on points and ``(ax, -ay, -az)`` on axis-angles.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from grip_bench import constants as C
from grip_bench.checkpoint import load_checkpoint, save_checkpoint
from grip_bench.errors import InputError
from grip_bench.threads import single_thread  # noqa: F401  (U.single_thread in the methods)

SIDES = ("right", "left")
MIRROR = np.diag([-1.0, 1.0, 1.0])  # right-hand frame <-> left-hand frame


# ----------------------------------------------------------------------------- configs


def section_config(cls, profile: dict | None, section: str):
    """Build the train-config dataclass ``cls`` from ``profile[section]`` (defaults elsewhere).

    Unknown keys are an :class:`InputError`: a typo must not silently train the default.
    """
    values = dict((profile or {}).get(section, {}) or {})
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise InputError(f"unknown key(s) {unknown} for {cls.__name__}", f"profile [{section}]")
    return cls(**values)


def train_meta(name: str, data_dir: Path, seed: int, cfg, started: float, **extra) -> dict:
    """Checkpoint ``meta``: method name, train config, data hash, seed and wall time (s)."""
    from grip_bench.data.grab_io import dataset_hash

    return {
        "method": name,
        "trained": True,
        "seed": int(seed),
        "data_hash": dataset_hash(data_dir),
        "train_config": dataclasses.asdict(cfg),
        "train_seconds": float(time.perf_counter() - started),
        **extra,
    }


def save_models(out: Path, models: dict, meta: dict) -> Path:
    """``save_checkpoint`` of ``{name: network}`` (each network carries its ``cfg``)."""
    return save_checkpoint(
        out,
        model_state={k: m.state_dict() for k, m in models.items()},
        configs={k: m.cfg for k, m in models.items()},
        meta=meta,
    )


def load_own(checkpoint: Path, expected: dict, name: str):
    """``load_checkpoint`` that also refuses a checkpoint written by another method."""
    ck = load_checkpoint(checkpoint, expected)
    if ck.meta.get("method") != name:
        raise InputError(f"checkpoint of {ck.meta.get('method')!r}, not {name!r}", checkpoint)
    return ck


class TrainedMethod:
    """Base of the learned baselines: ``train`` is "section config -> fit -> meta -> save".

    A subclass sets ``section`` (its profile section), ``config_cls`` (the train-config
    dataclass built from it) and ``networks`` (``{checkpoint key: network config class}``)
    and implements :meth:`fit`, which returns ``({key: network}, extra meta)``; the
    checkpoint is :func:`save_models` of those networks with :func:`train_meta`. ``fit``
    runs on one torch thread (:func:`single_thread`).
    :meth:`load_checkpoint` reads one back (refusing another method's) and returns the
    networks and the checkpoint.
    """

    section: str = ""
    config_cls: type = None
    networks: dict = {}

    def __init__(self, name: str):
        self.name = name

    def fit(self, data_dir: Path, cfg, seed: int, progress: bool) -> tuple[dict, dict]:
        raise NotImplementedError

    def train(
        self,
        data_dir: Path,
        out: Path,
        *,
        profile: dict,
        seed: int = 0,
        device: str = "cpu",
        progress: bool = True,
    ) -> Path:
        started = time.perf_counter()
        cfg = section_config(self.config_cls, profile, self.section)
        with single_thread():
            models, extra = self.fit(Path(data_dir), cfg, seed, progress)
        meta = train_meta(self.name, Path(data_dir), seed, cfg, started, **extra)
        return save_models(Path(out), models, meta)

    def load_checkpoint(self, checkpoint: Path | None):
        """``({key: network}, checkpoint)`` of a checkpoint written by this method."""
        ck = load_own(checkpoint, self.networks, self.name)
        return ck.models(), ck


def log(progress: bool, name: str, msg: str) -> None:
    if progress:
        print(f"[{name}] {msg}", flush=True)


# ----------------------------------------------------------------------------- data


def load_split(data_dir, split: str, limit: int = 0, seed: int = 0) -> list:
    """Sequences of ``split`` (``limit`` > 0: a seeded random subset of that many files)."""
    from grip_bench.data.grab_io import read_grab
    from grip_bench.data.splits import sequences_in_split

    files = sequences_in_split(data_dir, split)
    if limit and len(files) > limit:
        keep = np.sort(np.random.default_rng(seed).choice(len(files), limit, replace=False))
        files = [files[i] for i in keep]
    return [read_grab(p) for p in files]


def train_sequences(data_dir, limit: int = 0, seed: int = 0) -> list:
    """The train split, or an :class:`InputError` when it is empty."""
    seqs = load_split(data_dir, "train", limit, seed)
    if not seqs:
        raise InputError("the train split has no sequences", data_dir)
    return seqs


# ----------------------------------------------------------------------------- hands


@functools.lru_cache(maxsize=16)
def hand_model(side: str, scale: float = 1.0):
    """A cached :class:`ProceduralHand` (building one costs seconds the first time)."""
    from grip_bench.bodies.hand import ProceduralHand

    return ProceduralHand(side, float(scale))


class SubsetHand(torch.nn.Module):
    """The posed vertices ``ids`` of a :class:`ProceduralHand` only, by the same linear
    blend skinning restricted to those rows of its skinning matrix.

    ``forward(global_orient, hand_pose, transl)`` as the hand's (``None`` = identity /
    zero) -> ``(vertices (B, K, 3), None)``. Losses and features read a few hundred of
    the hand's ~2500 vertices; skinning only those divides the cost of a training step's
    hand pass (and its backward) by about the same factor.
    """

    def __init__(self, hand, ids):
        super().__init__()
        self.hand = hand
        ids = torch.as_tensor(np.array(ids, np.int64))
        w, v = hand.weights[ids], hand.template_vertices[ids]
        # Rows of [w_vj v_c | w_vj] (K, 64): the pose-free LBS factors of the subset.
        self.register_buffer("skin", torch.cat([(w[:, :, None] * v[:, None]).flatten(1), w], 1))

    def forward(self, global_orient=None, hand_pose=None, transl=None):
        from grip_bench.geometry.rotations import axis_angle_to_matrix

        pose = torch.as_tensor(hand_pose).reshape(-1, 15, 3)
        b = pose.shape[0]
        rot, pos = self.hand.kinematics(pose)  # (B, 16, 3, 3), (B, 16, 3)
        rest = self.hand.rest_joints.to(pose)
        shift = pos - (rot @ rest[:, :, None])[..., 0]
        x = torch.cat([rot.transpose(2, 3).reshape(b, 48, 3), shift], 1)  # (B, 64, 3)
        verts = torch.einsum("kj,bjc->bkc", self.skin.to(pose), x)
        if global_orient is not None:
            verts = verts @ axis_angle_to_matrix(torch.as_tensor(global_orient).to(pose)).transpose(
                1, 2
            )
        if transl is not None:
            verts = verts + torch.as_tensor(transl).to(pose)[:, None]
        return verts, None


def seq_hand(seq, side: str):
    """The procedural hand of ``seq``'s subject; MANO sequences are not supported here."""
    if seq.body_model != "procedural":
        raise InputError(
            "the baselines pose procedural hands only (SynthGRAB); this sequence uses "
            f"{seq.body_model!r}",
            f"{seq.source or seq.name}: body_model",
        )
    return hand_model(side, float(seq.hand_scale or 1.0))


def pose_hand(hand, global_orient, hand_pose, transl) -> tuple[np.ndarray, np.ndarray]:
    """World vertices (T, V, 3) and joints (T, 21, 3), float64, from numpy axis-angles."""
    dt = hand.template_vertices.dtype
    t = lambda a: torch.as_tensor(np.asarray(a, np.float64), dtype=dt)  # noqa: E731
    with torch.no_grad():
        v, j = hand(t(global_orient), t(hand_pose).reshape(-1, 15, 3), t(transl))
    return v.double().numpy(), j.double().numpy()


def seq_vertices(seq, side: str, params: dict | None = None) -> np.ndarray:
    """Posed world vertices (T, V, 3) of one hand of ``seq`` (or of ``params``)."""
    p = params or seq.hand_params(side)
    return pose_hand(seq_hand(seq, side), p["global_orient"], p["hand_pose"], p["transl"])[0]


def object_pose(seq) -> tuple[np.ndarray, np.ndarray]:
    """Object pose as column rotations ``R (T, 3, 3)`` and translations ``t (T, 3)``:
    ``world = R @ local + t`` (the transpose of GRAB's row-vector matrices)."""
    return np.transpose(seq.object_rotations(), (0, 2, 1)), np.asarray(seq.object["transl"], float)


def wrist_pose(params: dict) -> tuple[np.ndarray, np.ndarray]:
    """Wrist rotations (T, 3, 3) and positions (T, 3) of hand params."""
    rot = Rotation.from_rotvec(np.asarray(params["global_orient"], float)).as_matrix()
    return rot, np.asarray(params["transl"], float)


def signed_distance(library, seq, world: np.ndarray, frames=None) -> np.ndarray:
    """Signed distance (T, N) (m, negative inside) of world points (T, N, 3) to the object
    (``frames``: the points are of those frames only, ``(F, N, 3)`` -> ``(F, N)``).

    Beyond the library grid the bounding-box bound answers: exact enough for the 4.5 mm
    contact test and for features that are clipped at a few centimetres.
    """
    if frames is None:
        local = library.world_to_object(seq, world)
    else:
        R, t = (x[frames] for x in object_pose(seq))
        local = np.einsum("fji,fvj->fvi", R, np.asarray(world) - t[:, None])
    return library.field(seq.obj_name).signed_distance(local, far="bound")


def contact_frames(
    library,
    seq,
    side: str,
    params: dict | None = None,
    threshold: float = C.CONTACT_THRESHOLD,
    frames=None,
) -> np.ndarray:
    """Frames (T,) where the hand (``params`` or the sequence's) is within ``threshold``
    of the object or inside it: the grasp frames of DESIGN 5 for ground-truth hands.
    With ``frames`` (indices) only those are tested: a ``(len(frames),)`` mask."""
    p = params or seq.hand_params(side)
    if frames is not None:
        p = {k: np.asarray(p[k])[frames] for k in ("global_orient", "hand_pose", "transl")}
    d = signed_distance(library, seq, seq_vertices(seq, side, p), frames)
    return (d <= threshold).any(axis=1)


def mirror_pose(aa: np.ndarray) -> np.ndarray:
    """Mirror axis-angles ``(..., 3k)`` between the hands: ``(ax, ay, az) -> (ax, -ay, -az)``."""
    a = np.asarray(aa, float)
    out = a.reshape(*a.shape[:-1], -1, 3) * np.array([1.0, -1.0, -1.0])
    return out.reshape(a.shape)


def matrix_to_rotvec(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angles (..., 3)."""
    m = np.asarray(m, float)
    return Rotation.from_matrix(m.reshape(-1, 3, 3)).as_rotvec().reshape(*m.shape[:-2], 3)


def vertex_subset(hand, n: int) -> np.ndarray:
    """``n`` hand vertex ids at a fixed stride (``n = 0``: all vertices), int64."""
    v = hand.num_vertices
    return np.arange(v) if n <= 0 or n >= v else np.linspace(0, v - 1, n).astype(np.int64)


def seeded(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(int(seed))


def batches(n: int, size: int, rng: np.random.Generator, shuffle: bool = True):
    """Index arrays covering ``range(n)`` in chunks of ``size`` (shuffled per call)."""
    order = rng.permutation(n) if shuffle else np.arange(n)
    # A final batch of one would break BatchNorm's training statistics: fold it in.
    cuts = list(range(0, n, size))
    if len(cuts) > 1 and n - cuts[-1] < 2:
        cuts.pop()
    return [order[a:b] for a, b in zip(cuts, cuts[1:] + [n], strict=True)]
