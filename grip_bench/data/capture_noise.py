"""An optional capture-noise model for ground truth: what motion capture adds to hands.

SynthGRAB's ground-truth hands are exact: fingers rest about a millimetre off the surface
and nothing jitters. Optical motion capture fitted with a body model is not: GRAB reports
that its hands *penetrate* the objects they hold (the soft-tissue deformation no
articulated hand model has) and models its own capture noise as noise on the marker
positions. :func:`apply_capture_noise` is a pure, seeded ``Sequence -> Sequence`` transform
that adds both to a sequence's hands, so that users can see how the metrics behave on
mocap-like ground truth (``[run] capture_noise = "grab"``, docs/seeds_and_noise.md).

The ``grab`` model (:data:`MODELS`), with its sources in the GRAB paper (Taheri et al.,
ECCV 2020, supplementary material):

===================== ============================================================== ========
term                  what it does                                                   value
===================== ============================================================== ========
penetration bias      each finger in contact is curled (equal flexion at its three   3.25 mm
                      joints) until its contact vertices lie on average ``d`` inside  +- 0.68
                      the object; ``d`` is drawn per sequence and hand from
                      ``N(3.25 mm, 0.68 mm)``, clipped to [0, 5.8] mm. Sup. Mat. S.5
                      (and S.4): "use" grasps have 3.25 +- 0.68 mm average surface
                      penetration, 99.9 % of them <= 5.8 mm.
translation jitter    i.i.d. Gaussian noise on each hand's wrist translation, per    1 mm
                      frame and axis. Sup. Mat. S.8: GRAB models its marker noise
                      as 3D Gaussian noise of 1 mm variance on each marker.
finger-pose jitter    i.i.d. Gaussian noise on every finger axis-angle component,    0.0199
                      per frame, sized so that the finger vertices move as much as   rad
                      the wrist does: rms 3-D displacement sqrt(3) mm relative to
                      the wrist (measured on the procedural hand in GRIP's relaxed
                      pose: 0.0869 mm of rms displacement per 0.001 rad).
===================== ============================================================== ========

Definitions. The penetration is reached by adding flexion to the finger's three joints (damped
minimum-norm Newton steps on the patch's mean signed distance, :func:`_solve`). Where the
object is thinner than twice the depth (a cup's wall, a handle) no flexion puts the patch
that deep (it comes out on the far side): those finger-frames keep the closest depth found
and are counted (``unreached`` in the statistics).

*Contact vertices* of a finger (thumb, index, middle, ring, pinky: the hand's
``part_labels``) at a frame are its vertices within ``contact_distance`` (2 mm) of the
surface in the clean ground truth; the finger is *in contact* when it has some. The bias
fades in as a finger approaches: with ``w`` the smoothstep of its closest vertex's distance
from ``fade_distance`` (10 mm, w = 0) to ``contact_distance`` (w = 1), the finger is curled
until the mean signed distance of its closest vertices (those within ``contact_distance``,
or within 1 mm of its closest one while it is farther) is ``(1 - w) s0 - w d``, ``s0`` their
clean mean; so in contact the contact vertices' mean depth is exactly ``d`` (before the
jitter) and the motion has no step where contact starts. The palm is not moved (its
penetration would need a wrist motion that also moves the fingers), nor are the body, the
object or the contact labels of the file (they stay those of the clean capture).

Randomness: one generator per (sequence name, seed) (``numpy.random.default_rng``), drawn in
a fixed order (per hand, right then left: depth, translation noise, pose noise), so a
dataset's noise does not depend on the order or the process its sequences are handled in.
"""

from __future__ import annotations

import json
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import InputError
from ..core.frames import SIDES

if TYPE_CHECKING:
    from .library import ObjectLibrary
    from .sequence import Sequence


@dataclass(frozen=True)
class CaptureNoise:
    """Parameters of a capture-noise model (metres, radians; module docstring)."""

    penetration_mean: float  # m, mean depth of the contact vertices of a finger in contact
    penetration_std: float  # m, spread of that depth over sequences and hands
    penetration_max: float  # m, depths are clipped to [0, penetration_max]
    transl_jitter: float  # m, std per frame and axis of each wrist translation
    pose_jitter: float  # rad, std per frame of each finger axis-angle component
    contact_distance: float = 0.002  # m, contact vertices: this close in the clean GT
    fade_distance: float = 0.01  # m, the bias fades out as the finger gets this far
    max_curl: float = 0.6  # rad, the largest flexion added to a finger's joints

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(value) or value < 0:
                raise InputError(f"must be a finite number >= 0, got {value!r}",
                                 f"capture noise {name}")
        if self.fade_distance <= self.contact_distance:
            raise InputError("fade_distance must exceed contact_distance", "capture noise")


# The rms 3-D displacement of the procedural hand's finger vertices (relative to the wrist)
# per radian of i.i.d. finger-pose noise, measured in GRIP's relaxed pose (2000 draws of
# 0.01 rad: 0.869 mm), so that pose_jitter moves the fingers as much as transl_jitter
# moves the wrist (sqrt(3) transl_jitter in 3-D).
FINGER_RMS_PER_RAD = 0.0869
_GRAB_TRANSL_JITTER = 0.001  # GRAB Sup. Mat. S.8: markers' 3D noise of 1 mm variance

NONE = "none"
MODELS: dict[str, CaptureNoise | None] = {
    NONE: None,
    # GRAB Sup. Mat. S.5 (penetration of "use" grasps) and S.8 (marker noise)
    "grab": CaptureNoise(
        penetration_mean=0.00325, penetration_std=0.00068, penetration_max=0.0058,
        transl_jitter=_GRAB_TRANSL_JITTER,
        pose_jitter=round(float(np.sqrt(3.0) * _GRAB_TRANSL_JITTER / FINGER_RMS_PER_RAD), 4)),
}
PATCH_BAND = 0.001  # m; a finger not yet in contact: its vertices this close to its closest
FINGERS = ("thumb", "index", "middle", "ring", "pinky")
_SOLVE_ITERATIONS = 25  # at most this many Newton steps (typically 3-8)
_SOLVE_TOLERANCE = 1e-7  # m; 0.1 um, far below any metric's resolution
_SOLVE_MAX_STEP = 0.05  # rad per joint and step


def resolve_model(model: str | CaptureNoise | None) -> CaptureNoise | None:
    """A model by name (:data:`MODELS`), a :class:`CaptureNoise`, or None ("none")."""
    if model is None or isinstance(model, CaptureNoise):
        return model
    if model not in MODELS:
        raise InputError(f"unknown capture-noise model {model!r} (known: "
                         f"{', '.join(MODELS)})", "capture_noise")
    return MODELS[model]


def sequence_rng(seq: Sequence, seed: int) -> np.random.Generator:
    """The generator of one sequence: independent of the order sequences are handled in."""
    return np.random.default_rng([int(seed), zlib.crc32(f"{seq.name}|capture".encode())])


def smoothstep_weight(d: np.ndarray, near: float, far: float) -> np.ndarray:
    """1 at distances ``d <= near``, 0 from ``far`` on, a smoothstep between (no kink)."""
    x = np.clip((far - np.asarray(d, dtype=np.float64)) / (far - near), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


# --- the penetration bias -----------------------------------------------------------------
class _FingerCurl:
    """Curling the fingers of one hand of one sequence and measuring their patches.

    ``items`` are (frame, finger) pairs; each has a patch of vertices whose mean signed
    distance (m, object frame) :meth:`patch_means` measures at per-item flexion angles.
    Only the patch vertices are skinned (LBS from the hand's joint transforms), so one
    evaluation costs the forward kinematics of the frames and a few thousand distances.
    """

    def __init__(self, hand, params: dict, frames: np.ndarray, rot_obj: np.ndarray,
                 t_obj: np.ndarray, field, item_frame: np.ndarray, item_finger: np.ndarray,
                 patch_item: np.ndarray, patch_vertex: np.ndarray):
        import torch
        from scipy.spatial.transform import Rotation

        self.hand, self.field, self.torch = hand, field, torch
        self.frames = frames  # (F,) frame indices of the sequence the items use
        local = {int(t): i for i, t in enumerate(frames)}
        self.item_row = np.array([local[int(t)] for t in item_frame], dtype=np.int64)
        self.item_finger = item_finger
        self.patch_item, self.patch_vertex = patch_item, patch_vertex
        self.pose = np.asarray(params["hand_pose"], np.float64)[frames].reshape(-1, 15, 3)
        self.rot_g = Rotation.from_rotvec(np.asarray(params["global_orient"], np.float64)
                                          [frames]).as_matrix()  # (F, 3, 3)
        self.transl = np.asarray(params["transl"], np.float64)[frames]
        self.rot_obj, self.t_obj = rot_obj[frames], t_obj[frames]
        dtype = hand.template_vertices.dtype
        # flexion axis (axis-angle direction) of every joint: from_local is linear
        flex = torch.zeros(15, 3, dtype=dtype)
        flex[:, 0] = 1.0
        self.axes = hand.from_local(flex).double().numpy()  # (15, 3)
        self.finger_joints = [_pose_joints(f) for f in FINGERS]
        self.weights = hand.weights.double().numpy()[patch_vertex]  # (P, 16)
        self.rest = hand.rest_joints.double().numpy()  # (16, 3)
        self.template = hand.template_vertices.double().numpy()[patch_vertex]  # (P, 3)
        self.counts = np.bincount(patch_item, minlength=len(item_frame)).astype(np.float64)

    def curled_pose(self, flexion: np.ndarray) -> np.ndarray:
        """Finger poses (F, 15, 3) with each item's flexion (n_items, 3) rad added at its
        finger's three joints, base to tip (composed after each joint's rotation)."""
        from scipy.spatial.transform import Rotation

        extra = np.zeros_like(self.pose)
        for k, joints in enumerate(self.finger_joints):
            sel = self.item_finger == k
            for i, j in enumerate(joints):
                extra[self.item_row[sel], j] = flexion[sel, i, None] * self.axes[j]
        moved = np.abs(extra).sum(axis=(1, 2)) > 0
        out = self.pose.copy()
        if moved.any():
            r = (Rotation.from_rotvec(self.pose[moved].reshape(-1, 3))
                 * Rotation.from_rotvec(extra[moved].reshape(-1, 3)))
            out[moved] = r.as_rotvec().reshape(-1, 15, 3)
        return out

    def patch_means(self, flexion: np.ndarray) -> np.ndarray:
        """Mean signed distance (n_items,) m of each item's patch at ``flexion`` (n, 3) rad."""
        torch = self.torch
        pose = torch.as_tensor(self.curled_pose(flexion), dtype=torch.float64)
        with torch.no_grad():
            rot_j, pos_j = self.hand.kinematics(pose)  # (F, 16, 3, 3), (F, 16, 3)
        rot_j, pos_j = rot_j.double().numpy(), pos_j.double().numpy()
        row = self.item_row[self.patch_item]  # (P,) frame row of each patch vertex
        # LBS: v' = sum_j w_vj (R_j (v - rest_j) + p_j), in the hand frame
        rel = self.template[:, None, :] - self.rest[None]  # (P, 16, 3)
        per_joint = np.einsum("pjab,pjb->pja", rot_j[row], rel) + pos_j[row]
        posed = np.einsum("pj,pja->pa", self.weights, per_joint)
        world = np.einsum("pab,pb->pa", self.rot_g[row], posed) + self.transl[row]
        # object frame, GRAB's row convention: local = (world - t) @ R^T
        local = np.einsum("pb,pab->pa", world - self.t_obj[row], self.rot_obj[row])
        sd = np.asarray(self.field.signed_distance(local, far="bound"), dtype=np.float64)
        return np.bincount(self.patch_item, weights=sd, minlength=len(self.counts)) / self.counts


def _pose_joints(finger: str) -> tuple[int, int, int]:
    """The ``hand_pose`` rows (0..14) of a finger's three joints (MANO order)."""
    from ..bodies.layouts import MANO_JOINTS

    return tuple(MANO_JOINTS.index(f"{finger}{i}") - 1 for i in (1, 2, 3))


def _solve(curl: _FingerCurl, target: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray]:
    """Flexions (n, 3) rad of each item's finger joints with its patch mean at ``target``
    (n,) m, and whether each was reached (to 1 um) within ``limit`` rad per joint.

    One equation, three unknowns: damped minimum-norm Newton steps (``dx = -g J / |J|^2``,
    ``J`` by forward differences, at most 0.05 rad per joint and step), so the joints that
    move the patch along the surface normal do the work; a finger wrapped round a cylinder
    presses in with its distal joints instead of sliding round it, as an equal curl of all
    three would. All items step at once (four evaluations per step).
    """
    n = len(target)
    x = np.zeros((n, 3))
    g = curl.patch_means(x) - target
    live = np.abs(g) > _SOLVE_TOLERANCE
    h = 1e-4  # rad, forward-difference step (the patch moves ~10 um)
    scale = np.ones(n)
    for _ in range(_SOLVE_ITERATIONS):
        if not live.any():
            break
        jac = np.zeros((n, 3))
        for i in range(3):
            xi = x.copy()
            xi[live, i] += h
            jac[:, i] = (curl.patch_means(xi) - target - g) / h
        norm2 = (jac ** 2).sum(axis=1)
        step = np.where(live[:, None] & (norm2[:, None] > 1e-12),
                        -g[:, None] * jac / np.maximum(norm2, 1e-12)[:, None], 0.0)
        cap = np.minimum(1.0, _SOLVE_MAX_STEP / np.maximum(np.abs(step).max(axis=1), 1e-12))
        x_new = np.clip(x + step * (cap * scale)[:, None], -limit, limit)
        g_new = curl.patch_means(x_new) - target
        # keep a step only where it helps; else halve that item's steps (four times at most)
        better = live & (np.abs(g_new) < np.abs(g))
        x[better], g[better] = x_new[better], g_new[better]
        scale[live & ~better] /= 2.0
        live &= (np.abs(g) > _SOLVE_TOLERANCE) & (scale >= 1.0 / 16.0)
    return x, np.abs(g) <= 1e-6


def _finger_vertices(hand) -> list[np.ndarray]:
    from ..bodies.layouts import HAND_PARTS

    labels = np.asarray(hand.part_labels)
    return [np.flatnonzero(labels == HAND_PARTS.index(f)) for f in FINGERS]


def penetration_bias(seq: Sequence, depths: dict[str, float], model: CaptureNoise,
                     library: ObjectLibrary) -> tuple[Sequence, dict]:
    """``seq`` with each hand's fingers curled into the object (module docstring): per side,
    the fingers in contact have their contact vertices' mean depth ``depths[side]`` (m).

    Returns the new sequence and per side the measured statistics: ``contact_depth`` (m,
    mean over in-contact finger-frames of their contact vertices' mean depth, NaN when
    none), ``inside_share`` (share of those vertices with a negative signed distance),
    ``finger_frames`` (in-contact finger-frames), ``unreached`` (those of them whose depth no
    flexion within ``max_curl`` reaches: a wall thinner than twice the depth).
    """
    from .posing import hand_poser

    poser = hand_poser(seq, None)
    if not hasattr(poser, "hands"):
        raise InputError("capture noise needs procedural hands (SynthGRAB)", seq.name)
    field = library.field(seq.obj_name)
    rot_obj, t_obj = seq.object_rotations(), np.asarray(seq.object["transl"], np.float64)
    new, stats = {}, {}
    for side in SIDES:
        hand = poser.hands[side]
        params = seq.hand_params(side)
        fingers = _finger_vertices(hand)
        verts = poser.vertices(side, params)  # (T, V, 3) world
        T = len(verts)
        ids = np.concatenate(fingers)
        local = library.world_to_object(seq, verts[:, ids])
        sd_all = np.asarray(field.signed_distance(local.reshape(-1, 3), far="bound"),
                            dtype=np.float64).reshape(T, len(ids))
        items_t, items_f, patch_i, patch_v, s0, w_list = [], [], [], [], [], []
        start = 0
        for k, vids in enumerate(fingers):
            sd = sd_all[:, start:start + len(vids)]
            start += len(vids)
            dmin = sd.min(axis=1)
            w = smoothstep_weight(dmin, model.contact_distance, model.fade_distance)
            for t in np.flatnonzero(w > 0):
                # in contact: exactly the contact vertices the statistics measure (a band
                # past the contact distance would solve for other vertices than it reports)
                near = (model.contact_distance if dmin[t] <= model.contact_distance
                        else dmin[t] + PATCH_BAND)
                sel = sd[t] <= near
                patch_i.append(np.full(int(sel.sum()), len(items_t)))
                patch_v.append(vids[sel])
                s0.append(float(sd[t, sel].mean()))
                items_t.append(int(t))
                items_f.append(k)
                w_list.append(float(w[t]))
        d = float(depths[side])
        if not items_t:
            stats[side] = {"contact_depth": float("nan"), "inside_share": float("nan"),
                           "finger_frames": 0, "unreached": 0}
            continue
        item_t, item_f = np.array(items_t), np.array(items_f)
        w, s0 = np.array(w_list), np.array(s0)
        frames = np.unique(item_t)
        curl = _FingerCurl(hand, params, frames, rot_obj, t_obj, field, item_t, item_f,
                           np.concatenate(patch_i), np.concatenate(patch_v))
        target = (1.0 - w) * s0 - w * d
        flexion, reached = _solve(curl, target, model.max_curl)
        pose = curl.curled_pose(flexion)
        hand_pose = np.array(params["hand_pose"], dtype=np.float64).reshape(T, 15, 3)
        hand_pose[frames] = pose
        new[side] = {"hand_pose": hand_pose.reshape(T, 45)}
        # measured: the contact vertices (clean distance <= contact_distance) of fingers in
        # contact (w = 1), posed with the full model, not the patch evaluation above
        stats[side] = _contact_depth_stats(hand, params, hand_pose, frames, rot_obj, t_obj,
                                           field, item_t, item_f, w, fingers, sd_all, model)
        stats[side]["unreached"] = int((~reached & (w >= 1.0)).sum())
    return seq.with_hands(**new), stats


def _contact_depth_stats(hand, params, hand_pose, frames, rot_obj, t_obj, field, item_t, item_f,
                         w, fingers, sd_all, model) -> dict:
    """Mean depth (m) of the contact vertices of in-contact fingers after the curl, their
    share inside the object, and the number of in-contact finger-frames."""
    import torch

    on = w >= 1.0
    if not on.any():
        return {"contact_depth": float("nan"), "inside_share": float("nan"), "finger_frames": 0}
    rows = np.unique(item_t[on])
    dtype = hand.template_vertices.dtype
    t = lambda a: torch.as_tensor(np.asarray(a)[rows], dtype=dtype)  # noqa: E731
    with torch.no_grad():
        verts, _ = hand(t(params["global_orient"]), t(hand_pose), t(params["transl"]))
    verts = verts.double().numpy()
    from ..core.frames import world_to_object

    local = world_to_object(verts, rot_obj[rows], t_obj[rows])
    where = {int(r): i for i, r in enumerate(rows)}
    starts = np.cumsum([0, *(len(f) for f in fingers)])
    depths, inside = [], []
    for tt, k in zip(item_t[on], item_f[on], strict=True):
        vids = fingers[k]
        clean = sd_all[tt, starts[k]:starts[k + 1]]
        sel = vids[clean <= model.contact_distance]
        sd = np.asarray(field.signed_distance(local[where[int(tt)], sel], far="bound"),
                        dtype=np.float64)
        depths.append(-sd.mean())
        inside.append(float((sd < 0).mean()))
    return {"contact_depth": float(np.mean(depths)), "inside_share": float(np.mean(inside)),
            "finger_frames": int(on.sum())}


# --- jitter and the whole model ---------------------------------------------------------------
def draw(seq: Sequence, model: CaptureNoise, seed: int) -> dict[str, dict[str, np.ndarray]]:
    """The random part of the model for one sequence, per side: ``depth`` (m, scalar),
    ``transl`` (T, 3) m and ``hand_pose`` (T, 45) rad of noise, drawn in a fixed order."""
    rng = sequence_rng(seq, seed)
    T, out = seq.n_frames, {}
    for side in SIDES:
        depth = model.penetration_mean + model.penetration_std * rng.normal()
        out[side] = {
            "depth": float(np.clip(depth, 0.0, model.penetration_max)),
            "transl": model.transl_jitter * rng.normal(size=(T, 3)),
            "hand_pose": model.pose_jitter * rng.normal(size=(T, 45)),
        }
    return out


def apply_capture_noise(seq: Sequence, model: str | CaptureNoise | None, library: ObjectLibrary,
                        seed: int) -> tuple[Sequence, dict]:
    """``seq`` as a motion-capture system would have recorded it (module docstring): the
    penetration bias, then the per-frame jitter of each hand's translation and finger pose.

    ``model``: a :class:`CaptureNoise`, a name of :data:`MODELS`, or None / ``"none"`` (the
    identity: an unchanged copy). Pure and seeded: the same sequence, model and seed give
    the same bits. Returns the new sequence and per side what was drawn and measured
    (``depth`` drawn, ``contact_depth`` / ``inside_share`` / ``finger_frames`` /
    ``unreached`` of :func:`penetration_bias`, ``transl_rms`` m and ``pose_rms`` rad of the
    jitter drawn).
    """
    model = resolve_model(model)
    if model is None:
        return seq.copy(), {}
    noise = draw(seq, model, seed)
    depths = {side: noise[side]["depth"] for side in SIDES}
    if model.penetration_mean > 0 or model.penetration_std > 0:
        out, stats = penetration_bias(seq, depths, model, library)
    else:
        out, stats = seq.copy(), {side: {} for side in SIDES}
    jittered = {}
    for side in SIDES:
        p = out.hand_params(side)
        jittered[side] = {"transl": np.asarray(p["transl"], np.float64) + noise[side]["transl"],
                          "hand_pose": np.asarray(p["hand_pose"], np.float64)
                          + noise[side]["hand_pose"]}
        stats[side] = {"depth": depths[side], **stats[side],
                       "transl_rms": _rms(noise[side]["transl"]),
                       "pose_rms": _rms(noise[side]["hand_pose"])}
    return out.with_hands(**jittered), stats


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a)))) if np.size(a) else float("nan")


NOISE_FILE = "capture_noise.json"  # beside grab/ in a noisy dataset: model, seed, statistics


def _apply_file(path: Path, root: Path, model: CaptureNoise, seed: int) -> list[dict]:
    """Apply the model to one sequence file in place; its per-side statistics."""
    from .grab_io import read_grab, write_grab
    from .library import ObjectLibrary

    library = _LIBRARIES.setdefault(str(root), ObjectLibrary(root))
    noisy, stats = apply_capture_noise(read_grab(path), model, library, seed)
    write_grab(noisy, path)
    return [stats[side] for side in SIDES]


_LIBRARIES: dict[str, ObjectLibrary] = {}  # per process: distance fields are built once


def _init_worker() -> None:
    """Pool initializer: one torch thread, and the worker ends with a killed parent rather
    than idle forever (docs/hostile_inputs.md). Only ever run in a pool's worker."""
    import torch

    from ..core.procs import exit_with_parent

    torch.set_num_threads(1)
    exit_with_parent()


def apply_to_dataset(data_dir: str | Path, model: str | CaptureNoise, seed: int,
                     progress: bool = True, workers: int = 1) -> dict:
    """Apply the model to every sequence file of ``data_dir`` (every split) in place and write
    :data:`NOISE_FILE`; returns its content: the model, the seed and the statistics pooled
    over sequences and hands (``depth_mean`` / ``depth_std`` drawn, ``contact_depth_mean``
    measured, ``inside_share``, ``finger_frames``, ``unreached``, ``transl_rms``,
    ``pose_rms``; metres and radians)."""
    from ..core.io import atomic_write_text
    from ..core.progress import bar
    from .grab_io import list_sequences

    resolved = resolve_model(model)
    if resolved is None:
        raise InputError("the 'none' model changes nothing; nothing to apply", "capture_noise")
    root = Path(data_dir)
    files = list_sequences(root)
    rows: list[dict] = []
    if workers <= 1 or len(files) <= 1:
        for path in bar(files, "capture noise", progress, unit="seq"):
            rows += _apply_file(path, root, resolved, seed)
    else:  # each sequence's noise depends on its name and the seed only: any order is fine
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=min(workers, len(files)),
                                 mp_context=mp.get_context("spawn"),
                                 initializer=_init_worker) as pool:
            done = pool.map(_apply_file, files, [root] * len(files), [resolved] * len(files),
                            [seed] * len(files))
            for part in bar(done, "capture noise", progress, unit="seq"):
                rows += part
    summary = summarize(rows)
    record = {"model": model if isinstance(model, str) else "custom",
              "parameters": asdict(resolved), "seed": int(seed), "statistics": summary}
    atomic_write_text(root / NOISE_FILE, json.dumps(record, sort_keys=True, indent=1) + "\n")
    return record


def summarize(rows: list[dict]) -> dict:
    """Statistics pooled over (sequence, hand) rows of :func:`apply_capture_noise`: the mean
    contact depth is weighted by each row's in-contact finger-frames."""
    def col(key: str) -> np.ndarray:
        return np.array([r.get(key, np.nan) for r in rows], dtype=np.float64)

    depth, n = col("depth"), np.nan_to_num(col("finger_frames"))
    cd, share = col("contact_depth"), col("inside_share")
    ok = np.isfinite(cd) & (n > 0)
    wmean = lambda v: float((v[ok] * n[ok]).sum() / n[ok].sum()) if ok.any() else None  # noqa: E731
    return {"hands": len(rows), "depth_mean": float(np.mean(depth)) if len(rows) else None,
            "depth_std": float(np.std(depth)) if len(rows) else None,
            "contact_depth_mean": wmean(cd), "inside_share": wmean(share),
            "finger_frames": int(n.sum()), "unreached": int(np.nan_to_num(col("unreached")).sum()),
            "transl_rms": float(np.sqrt(np.nanmean(col("transl_rms") ** 2))) if len(rows) else None,
            "pose_rms": float(np.sqrt(np.nanmean(col("pose_rms") ** 2))) if len(rows) else None}
