"""Shared plumbing of the baseline methods: data loading, hands, configs, devices, checkpoints.

Conventions (``docs/architecture.md``): metres and radians; object poses follow GRAB's
row-vector rule ``world = local @ R_row + t``, i.e. the column rotation is ``R_row^T``;
hand frames are ``world = R_wrist @ local + transl``. The left procedural hand is the
x-mirror of the right one, so a left hand is brought into the right hand's frame by
``S = diag(-1, 1, 1)`` on points and ``(ax, -ay, -az)`` on axis-angles. The frame
conventions live in :mod:`grip_bench.core.frames` (re-exported here as ``SIDES``,
``MIRROR``, ``mirror_pose``, ``object_pose`` for the methods' ``U.`` spelling).

Devices: :func:`resolve_device` (from :mod:`grip_bench.nn.ddp`, shared with GRIP's training)
turns ``--device`` into a ``torch.device`` (an :class:`InputError` for an unknown or
unavailable one, never a silent CPU fallback);
training builds its networks there and :meth:`TrainedMethod.load_checkpoint` moves the
loaded networks there. Geometry (distance fields, ray casts, BPS) stays numpy on the CPU.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from grip_bench.core import constants as C
from grip_bench.core.checkpoint import Checkpoint, load_checkpoint, save_checkpoint
from grip_bench.core.errors import InputError
from grip_bench.core.frames import (  # noqa: F401  (U.SIDES, U.MIRROR, ... in the methods)
    MIRROR,
    SIDES,
    mirror_pose,
    object_pose,
    world_to_object,
)
from grip_bench.core.threads import single_thread  # noqa: F401  (U.single_thread in the methods)
from grip_bench.methods.api import TrainContext
from grip_bench.nn import ddp
from grip_bench.nn.ddp import resolve_device

if TYPE_CHECKING:
    from grip_bench.bodies.hand import ProceduralHand
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.data.sequence import Sequence

Config = TypeVar("Config")
Device = str | torch.device

# ----------------------------------------------------------------------------- devices


def device_of(module: torch.nn.Module) -> torch.device:
    """The device of a network's first parameter or buffer (CPU for an empty one)."""
    for t in (*module.parameters(), *module.buffers()):
        return t.device
    return torch.device("cpu")


def randn(shape: tuple[int, ...] | torch.Size, generator: torch.Generator,
          device: torch.device) -> torch.Tensor:
    """Standard normal float32 noise drawn from a (CPU) ``generator`` and put on ``device``:
    the same numbers on every device for a seed."""
    return torch.randn(shape, generator=generator).to(device)


# ----------------------------------------------------------------------------- configs


def section_config(cls: type[Config], profile: dict | None, section: str) -> Config:
    """Build the train-config dataclass ``cls`` from ``profile[section]`` (defaults elsewhere).

    Unknown keys are an :class:`InputError`: a typo must not silently train the default.
    """
    values = dict((profile or {}).get(section, {}) or {})
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise InputError(f"unknown key(s) {unknown} for {cls.__name__}", f"profile [{section}]")
    return cls(**values)


def train_meta(name: str, data_dir: Path, seed: int, cfg: Any, **extra: Any) -> dict:
    """Checkpoint ``meta``: method name, train config, data hash and seed. No wall time: the
    same inputs give the same bytes (``grip-bench train`` and ``run`` agree; the run records
    each unit's time in its ``unit.json``)."""
    from grip_bench.data.grab_io import dataset_hash

    return {
        "method": name,
        "trained": True,
        "seed": int(seed),
        "data_hash": dataset_hash(data_dir),
        "train_config": dataclasses.asdict(cfg),
        **extra,
    }


def save_models(out: Path, models: dict[str, torch.nn.Module], meta: dict) -> Path:
    """``save_checkpoint`` of ``{name: network}`` (each network carries its ``cfg``); the
    weights are stored on the CPU whatever device they were trained on."""
    return save_checkpoint(
        out,
        model_state={k: m.state_dict() for k, m in models.items()},
        configs={k: m.cfg for k, m in models.items()},
        meta=meta,
    )


def load_own(checkpoint: Path, expected: dict[str, type], name: str) -> Checkpoint:
    """``load_checkpoint`` that also refuses a checkpoint written by another method."""
    ck = load_checkpoint(checkpoint, expected)
    if ck.meta.get("method") != name:
        raise InputError(f"checkpoint of {ck.meta.get('method')!r}, not {name!r}", checkpoint)
    return ck


class TrainedMethod:
    """Base of the learned baselines: ``train`` is "section config -> fit -> meta -> save".

    A subclass sets ``section`` (its profile section), ``config_cls`` (the train-config
    dataclass built from it) and ``networks`` (``{checkpoint key: network config class}``)
    and implements :meth:`fit`, which builds and trains its networks on ``device`` and
    returns ``({key: network}, extra meta)``; the checkpoint is :func:`save_models` of
    those networks with :func:`train_meta`. ``fit`` runs on one torch thread
    (:func:`single_thread`). :meth:`load_checkpoint` reads one back (refusing another
    method's), moves its networks to the requested device and returns them with the
    checkpoint; ``self.device`` is where :meth:`predict` then runs them.
    """

    section: str = ""
    config_cls: type = type(None)
    networks: dict[str, type] = {}

    def __init__(self, name: str) -> None:
        self.name = name
        self.device = torch.device("cpu")

    @property
    def profile_sections(self) -> tuple[str, ...]:
        """The profile sections training reads, its own: a checkpoint keys only these."""
        return (self.section,)

    def fit(self, data_dir: Path, cfg: Any, seed: int, progress: bool,
            device: torch.device) -> tuple[dict[str, torch.nn.Module], dict]:
        raise NotImplementedError

    def train(self, data_dir: Path, out: Path, ctx: TrainContext) -> Path:
        """Fit and save. In a DDP job (:mod:`grip_bench.nn.ddp`) every rank fits, on its
        own GPU for ``cuda`` (``cuda:LOCAL_RANK``), only rank 0 prints and writes."""
        d = ddp.current()
        device = ddp.train_device(ctx.device, d)
        cfg = section_config(self.config_cls, ctx.profile, self.section)
        if hasattr(cfg, "batch_size"):  # a method without batches (nearest) fits on each rank
            ddp.check_batch(cfg.batch_size, d, f"{self.section}.batch_size")
        with single_thread():
            models, extra = self.fit(Path(data_dir), cfg, ctx.seed, ctx.progress and d.main,
                                     device)
        meta = train_meta(self.name, Path(data_dir), ctx.seed, cfg, **extra)
        if d.active:  # N processes train other weights than one (docs/distributed_training.md)
            meta["nproc"] = d.world
        if d.main:
            save_models(Path(out), models, meta)
        ddp.barrier(d)  # the file exists before any rank returns
        return Path(out)

    def load_checkpoint(
        self, checkpoint: Path | None, device: Device = "cpu"
    ) -> tuple[dict[str, torch.nn.Module], Checkpoint]:
        """``({key: network on device}, checkpoint)`` of a checkpoint written by this
        method (read onto the CPU, then moved); sets ``self.device``."""
        dev = resolve_device(device)
        if checkpoint is None:
            raise InputError("this method needs a checkpoint (grip-bench train)", self.name)
        ck = load_own(checkpoint, self.networks, self.name)
        self.device = dev
        return {k: m.to(dev) for k, m in ck.models().items()}, ck

    def _loaded(self, *nets: torch.nn.Module | None) -> None:
        """An :class:`InputError` unless every network is loaded."""
        if any(n is None for n in nets):
            raise InputError("load a checkpoint before predicting", self.name)


def log(progress: bool, name: str, msg: str) -> None:
    if progress:
        print(f"[{name}] {msg}", flush=True)


# ----------------------------------------------------------------------------- data


def load_split(data_dir: Path | str, split: str, limit: int = 0, seed: int = 0) -> list[Sequence]:
    """Sequences of ``split`` (``limit`` > 0: a seeded random subset of that many files)."""
    from grip_bench.data.grab_io import read_grab
    from grip_bench.data.splits import sequences_in_split

    files = sequences_in_split(data_dir, split)
    if limit and len(files) > limit:
        keep = np.sort(np.random.default_rng(seed).choice(len(files), limit, replace=False))
        files = [files[i] for i in keep]
    return [read_grab(p) for p in files]


def train_sequences(data_dir: Path | str, limit: int = 0, seed: int = 0) -> list[Sequence]:
    """The train split, or an :class:`InputError` when it is empty."""
    seqs = load_split(data_dir, "train", limit, seed)
    if not seqs:
        raise InputError("the train split has no sequences", data_dir)
    return seqs


class KeptFields:
    """An :class:`ObjectLibrary` view that keeps every distance field it hands out.

    The library keeps its 64 most recently used fields (``lru_cache(maxsize=64)``). A
    training loop that cycles through more objects than that (the 72 train objects of the
    default SynthGRAB: GrabNet's grasp-frame search and every GrabNet batch, ManipNet's
    per-sequence features) evicts each field before it comes round again, so every visit
    rebuilt it from the geometry cache (~45 ms each, thousands of times per training), and
    objects held elsewhere (ManipNet's per-sequence features) were held twice. Fields are
    a few MB each; keeping all of a split's costs less than the LRU's 64. The fields are
    the library's own (the same arrays), so results do not change. Everything else
    (``mesh``, ``data_dir``, ...) is the wrapped library's.
    """

    def __init__(self, library: ObjectLibrary) -> None:
        self._library = library
        self._fields: dict[str, Any] = {}

    def field(self, name: str) -> Any:
        """The library's distance field of object ``name``, built once per view."""
        if name not in self._fields:
            self._fields[name] = self._library.field(name)
        return self._fields[name]

    def __getattr__(self, attr: str) -> Any:
        return getattr(self._library, attr)


def train_library(data_dir: Path | str) -> ObjectLibrary:
    """The :class:`ObjectLibrary` of a training run over ``data_dir``, keeping every field
    (:class:`KeptFields`)."""
    from grip_bench.data.library import ObjectLibrary

    return KeptFields(ObjectLibrary(data_dir))  # type: ignore[return-value]


# ----------------------------------------------------------------------------- hands


@functools.lru_cache(maxsize=16)
def _cpu_hand(side: str, scale: float) -> ProceduralHand:
    from grip_bench.bodies.hand import ProceduralHand

    return ProceduralHand(side, float(scale))


@functools.lru_cache(maxsize=16)
def _device_hand(side: str, scale: float, device: torch.device) -> ProceduralHand:
    import copy

    return copy.deepcopy(_cpu_hand(side, scale)).to(device)


def hand_model(side: str, scale: float = 1.0, device: Device = "cpu") -> ProceduralHand:
    """A cached :class:`ProceduralHand` on ``device`` (building one costs seconds the first
    time). Each device has its own copy: moving a shared cached hand would move it for
    every other user too."""
    dev = torch.device(device)
    if dev.type == "cpu":
        return _cpu_hand(side, float(scale))
    return _device_hand(side, float(scale), dev)


class SubsetHand(torch.nn.Module):
    """The posed vertices ``ids`` of a :class:`ProceduralHand` only, by the same linear
    blend skinning restricted to those rows of its skinning matrix.

    ``forward(global_orient, hand_pose, transl)`` as the hand's (``None`` = identity /
    zero) -> ``(vertices (B, K, 3), None)``. Losses and features read a few hundred of
    the hand's ~2500 vertices; skinning only those divides the cost of a training step's
    hand pass (and its backward) by about the same factor. It lives on the hand's device
    (take the hand from :func:`hand_model` with a device rather than moving this module,
    which would move the cached hand in place).
    """

    def __init__(self, hand: ProceduralHand, ids: np.ndarray | list[int]) -> None:
        super().__init__()
        self.hand = hand
        ids = torch.as_tensor(np.array(ids, np.int64), device=hand.weights.device)
        w, v = hand.weights[ids], hand.template_vertices[ids]
        # Rows of [w_vj v_c | w_vj] (K, 64): the pose-free LBS factors of the subset.
        self.register_buffer("skin", torch.cat([(w[:, :, None] * v[:, None]).flatten(1), w], 1))

    def forward(
        self,
        global_orient: torch.Tensor | None = None,
        hand_pose: torch.Tensor | None = None,
        transl: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, None]:
        from grip_bench.geometry.rotations import axis_angle_to_matrix

        pose = torch.as_tensor(hand_pose).reshape(-1, 15, 3)
        b = pose.shape[0]
        rot, pos = self.hand.kinematics(pose)  # (B, 16, 3, 3), (B, 16, 3)
        rest = self.hand.rest_joints.to(pose)
        shift = pos - (rot @ rest[:, :, None])[..., 0]
        x = torch.cat([rot.transpose(2, 3).reshape(b, 48, 3), shift], 1)  # (B, 64, 3)
        verts = torch.einsum("kj,bjc->bkc", self.skin.to(pose), x)
        if global_orient is not None:
            go = torch.as_tensor(global_orient).to(pose)
            verts = verts @ axis_angle_to_matrix(go).transpose(1, 2)
        if transl is not None:
            verts = verts + torch.as_tensor(transl).to(pose)[:, None]
        return verts, None


def seq_hand(seq: Sequence, side: str, device: Device = "cpu") -> ProceduralHand:
    """The procedural hand of ``seq``'s subject (on ``device``); MANO sequences are not
    supported here."""
    if seq.body_model != "procedural":
        raise InputError(
            "the baselines pose procedural hands only (SynthGRAB); this sequence uses "
            f"{seq.body_model!r}",
            f"{seq.source or seq.name}: body_model",
        )
    return hand_model(side, float(seq.hand_scale or 1.0), device)


def pose_hand(hand: ProceduralHand, global_orient: np.ndarray, hand_pose: np.ndarray,
              transl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World vertices (T, V, 3) and joints (T, 21, 3), float64, from numpy axis-angles."""
    dt = hand.template_vertices.dtype
    t = lambda a: torch.as_tensor(np.asarray(a, np.float64), dtype=dt)  # noqa: E731
    with torch.no_grad():
        v, j = hand(t(global_orient), t(hand_pose).reshape(-1, 15, 3), t(transl))
    return v.double().cpu().numpy(), j.double().cpu().numpy()


def seq_vertices(seq: Sequence, side: str, params: dict | None = None) -> np.ndarray:
    """Posed world vertices (T, V, 3) of one hand of ``seq`` (or of ``params``)."""
    p = params or seq.hand_params(side)
    return pose_hand(seq_hand(seq, side), p["global_orient"], p["hand_pose"], p["transl"])[0]


def to_object(seq: Sequence, world: np.ndarray, frames: np.ndarray | None = None) -> np.ndarray:
    """World points ``(T, N, 3)`` (or ``(F, N, 3)`` of ``frames``) in the object's frame
    (:func:`grip_bench.core.frames.world_to_object`)."""
    R, t = seq.object_rotations(), np.asarray(seq.object["transl"], float)
    if frames is not None:
        R, t = R[frames], t[frames]
    return world_to_object(world, R, t)


def wrist_pose(params: dict) -> tuple[np.ndarray, np.ndarray]:
    """Wrist rotations (T, 3, 3) and positions (T, 3) of hand params."""
    rot = Rotation.from_rotvec(np.asarray(params["global_orient"], float)).as_matrix()
    return rot, np.asarray(params["transl"], float)


def signed_distance(library: ObjectLibrary, seq: Sequence, world: np.ndarray,
                    frames: np.ndarray | None = None) -> np.ndarray:
    """Signed distance (T, N) (m, negative inside) of world points (T, N, 3) to the object
    (``frames``: the points are of those frames only, ``(F, N, 3)`` -> ``(F, N)``).

    Beyond the library grid the bounding-box bound answers: exact enough for the 4.5 mm
    contact test and for features that are clipped at a few centimetres.
    """
    local = to_object(seq, np.asarray(world), frames)
    return library.field(seq.obj_name).signed_distance(local, far="bound")


def contact_frames(
    library: ObjectLibrary,
    seq: Sequence,
    side: str,
    params: dict | None = None,
    threshold: float = C.CONTACT_THRESHOLD,
    frames: np.ndarray | None = None,
) -> np.ndarray:
    """Frames (T,) where the hand (``params`` or the sequence's) is within ``threshold``
    of the object or inside it: the grasp frames (docs/contract.md, "Definitions") for
    ground-truth hands.
    With ``frames`` (indices) only those are tested: a ``(len(frames),)`` mask."""
    p = params or seq.hand_params(side)
    if frames is not None:
        p = {k: np.asarray(p[k])[frames] for k in ("global_orient", "hand_pose", "transl")}
    d = signed_distance(library, seq, seq_vertices(seq, side, p), frames)
    return (d <= threshold).any(axis=1)


def matrix_to_rotvec(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angles (..., 3)."""
    m = np.asarray(m, float)
    return Rotation.from_matrix(m.reshape(-1, 3, 3)).as_rotvec().reshape(*m.shape[:-2], 3)


def vertex_subset(hand: ProceduralHand, n: int) -> np.ndarray:
    """``n`` hand vertex ids at a fixed stride (``n = 0``: all vertices), int64."""
    v = hand.num_vertices
    return np.arange(v) if n <= 0 or n >= v else np.linspace(0, v - 1, n).astype(np.int64)


def seeded(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(int(seed))


def rank_batches(
    batches: list[np.ndarray], d: ddp.Dist
) -> list[tuple[np.ndarray, float]]:
    """``(this rank's share, loss weight)`` of each global batch of :func:`batches`.

    One process: every batch whole with weight 1. Under DDP every rank holds the same
    global batches (the same seeded ``rng``) and takes its share; the weight makes DDP's
    gradient average the mean over the global batch (:func:`grip_bench.nn.ddp.share_weight`).
    A batch with fewer samples than ranks is skipped by all ranks.
    """
    if not d.active:
        return [(b, 1.0) for b in batches]
    return [(ddp.rank_share(b, d), ddp.share_weight(len(ddp.rank_share(b, d)), len(b), d))
            for b in batches if len(b) >= d.world]


def backward(loss: torch.Tensor, weight: float) -> None:
    """``loss.backward()`` of a rank's share, weighted (no op added for weight 1)."""
    (loss if weight == 1.0 else loss * weight).backward()


def rank_seed(seed: int, d: ddp.Dist, *parts: int) -> int:
    """A seed of its own for rank ``d.rank`` (dropout, sampling noise) from ``(seed, rank)``."""
    return int(np.random.SeedSequence([int(seed), d.rank, *parts]).generate_state(1)[0])


def batches(n: int, size: int, rng: np.random.Generator, shuffle: bool = True) -> list[np.ndarray]:
    """Index arrays covering ``range(n)`` in chunks of ``size`` (shuffled per call)."""
    order = rng.permutation(n) if shuffle else np.arange(n)
    # A final batch of one would break BatchNorm's training statistics: fold it in.
    cuts = list(range(0, n, size))
    if len(cuts) > 1 and n - cuts[-1] < 2:
        cuts.pop()
    return [order[a:b] for a, b in zip(cuts, cuts[1:] + [n], strict=True)]
