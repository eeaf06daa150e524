"""``toch``: TOCH-style refiner of perturbed hands (GRIP Table 3) as a benchmark method.

Per hand, in the object's frame: the correspondence field of the hand over ``n_points``
object surface samples (fixed, seeded per object), a :class:`TemporalAE` that maps the
field of a noisy window to the clean one, and :func:`fit_hand_to_field` that solves the
hand pose, wrist orientation and wrist translation per frame from the denoised field.

Training: windows of ``window`` frames from the train split that contain an interaction
frame; each window is perturbed with one of GRAB-T (0.01, 0.02 m) and GRAB-R (0.3, 0.5
rad) in turn, and the network learns noisy field -> ground-truth field. Both hands
share one network: a left hand's canonical correspondences are mirrored (x -> -x) into
the right hand's canonical space. Only ~10 % of the object points are touched by the
hand (a hit), so the hit BCE weighs hits up by the class ratio (``hit_balance``):
unweighted, the denoiser learns "nothing is touched" and the fit has nothing to fit.

Prediction: only *interaction frames* are refined, the frames where the input hand comes
within ``interaction_distance`` of the object. Each run of them is cut into windows of at
most ``window`` frames for the denoiser, and the hand is then fitted to the denoised
fields of the whole run at once. Other frames, and runs whose denoised fields have no
hit, keep the input hand.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
import trimesh

from grip_bench.core.constants import (
    TOCH_HIT_THRESHOLD,
    TOCH_INTERACTION_DISTANCE,
    TOCH_R_SIGMAS,
    TOCH_T_SIGMAS,
    TOCH_WINDOW,
)
from grip_bench.core.errors import InputError
from grip_bench.core.frames import mirror_points
from grip_bench.methods.api import MethodSpec, PredictContext, register_method
from grip_bench.nn import ddp

from . import common as U
from .toch import (
    FitConfig,
    TemporalAE,
    TemporalAEConfig,
    correspondence_fields,
    field_losses,
    fit_hand_to_field,
    hit_pos_weight,
)

if TYPE_CHECKING:
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.data.sequence import Sequence

PERTURBATIONS = tuple(("T", s) for s in TOCH_T_SIGMAS) + tuple(("R", s) for s in TOCH_R_SIGMAS)
Window = tuple["Sequence", str, int]  # (sequence, side, first frame) of a training window


@dataclass
class TochTrainConfig:
    """Profile section ``[toch]``."""

    n_points: int = 256  # object surface samples per frame (TOCH: 2000)
    local_dim: int = 32
    frame_dim: int = 64
    gru_hidden: int = 64
    skip_dim: int = 32  # per-point temporal skip path (TemporalAEConfig.skip_dim)
    decoder_hidden: int = 128  # per-point decoder width
    window: int = TOCH_WINDOW
    epochs: int = 8
    batch_size: int = 4  # windows per step
    lr: float = 2e-3
    max_windows: int = 48  # training windows (each with one perturbation)
    windows_per_hand: int = 1  # at most this many windows per train sequence and hand
    frame_stride: int = 3  # interaction frames of train hands are tested on every k-th frame
    max_sequences: int = 0  # train files read (0 = all)
    # Weight of the hit class in the BCE: (misses / hits) ** hit_balance (1 = balanced
    # classes, 0 = plain BCE, under which no probability reaches hit_threshold).
    hit_balance: float = 0.5
    fit_iters: int = 40
    # Weight of the fit's smoothness term (squared accelerations; FitConfig.w_smooth). The
    # perturbations are i.i.d. per frame, so the temporal prior does much of the denoising.
    fit_smooth: float = 100.0
    interaction_distance: float = TOCH_INTERACTION_DISTANCE
    hit_threshold: float = TOCH_HIT_THRESHOLD  # denoised hit probability that counts as a hit


@functools.lru_cache(maxsize=64)
def _samples(library: ObjectLibrary, name: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded surface samples (n, 3) and outward unit normals (n, 3) of one object (m)."""
    mesh = library.mesh(name)
    pts, face = trimesh.sample.sample_surface(mesh, n, seed=0)
    return np.asarray(pts, float), np.asarray(mesh.face_normals[face], float)


def hand_fields(
    library: ObjectLibrary,
    seq: Sequence,
    side: str,
    params: dict,
    frames: np.ndarray,
    n_points: int,
) -> np.ndarray:
    """Correspondence fields (F, N, 5) of one hand over ``frames``, canonical points in
    the right hand's canonical space (left mirrored)."""
    pts, nrm = _samples(library, seq.obj_name, n_points)
    hand = U.seq_hand(seq, side)
    sub = {k: np.asarray(v)[frames] for k, v in params.items()}
    world = U.pose_hand(hand, sub["global_orient"], sub["hand_pose"], sub["transl"])[0]
    local = U.to_object(seq, world, frames)
    faces, canon = np.asarray(hand.faces), hand.template_vertices.double().numpy()
    out = correspondence_fields(pts, nrm, local, faces, canon).as_array()  # one broad phase
    if side == "left":
        out[..., 2:] = mirror_points(out[..., 2:])
    return out


_FAR_MARGIN = 1e-6  # m; pads the far-frame bound against the rounding of the frame change
_PROBE_STRIDE = 8  # interaction_frames measures every 8th hand vertex first


def far_frames(library: ObjectLibrary, seq: Sequence, world: np.ndarray, dist: float) -> np.ndarray:
    """(T,) bool: frames whose hand vertices ``world (T, V, 3)`` (m) are all surely farther
    than ``dist`` from the object by :func:`common.signed_distance`'s measure, so that
    measuring them can be skipped.

    Beyond the object's fine distance grid that measure is the point's distance to the
    object's bounding box (``far="bound"``), and the grid's nodes reach at most
    ``padding + spacing`` beyond the box on each axis: a point farther than
    ``sqrt(3) (padding + spacing)`` from the box is beyond the grid, and its value is that
    distance. The bound per frame: the distance between the hand's bounding sphere (centre
    and half-diagonal of its box) and the object box's sphere, in the world frame."""
    field = library.field(seq.obj_name)
    v = np.asarray(field.mesh.vertices, np.float64)  # every vertex: the grid's box too
    lo, hi = v.min(0), v.max(0)
    R, t = seq.object_rotations(), np.asarray(seq.object["transl"], float)
    centre = (lo + hi) / 2 @ R + t  # (T, 3) world = local @ R_t + t_t
    # per coordinate plane: ~8x faster than reducing (T, V, 3) over its middle axis
    a = np.stack([world[..., k].min(1) for k in range(3)], 1)  # (T, 3)
    b = np.stack([world[..., k].max(1) for k in range(3)], 1)
    gap = (
        np.linalg.norm((a + b) / 2 - centre, axis=1)
        - np.linalg.norm(b - a, axis=1) / 2
        - np.linalg.norm(hi - lo) / 2
    )  # (T,) lower bound of every hand point's distance to the object's box
    beyond = 3**0.5 * (field.padding + field.spacing)
    return gap > max(dist, beyond) + _FAR_MARGIN


def interaction_frames(
    library: ObjectLibrary, seq: Sequence, side: str, params: dict, dist: float
) -> np.ndarray:
    """(T,) bool: the hand comes within ``dist`` (m) of the object.

    The same mask as measuring every vertex of every frame (the measure is per point),
    for less: frames that :func:`far_frames` proves far (about half of a sequence) are not
    measured, and the others first measure every ``_PROBE_STRIDE``-th vertex; only the
    frames none of those decide measure the rest."""
    world = U.seq_vertices(seq, side, params)  # (T, V, 3)
    out = np.zeros(len(world), bool)
    frames = np.flatnonzero(~far_frames(library, seq, world, dist))
    probe = np.zeros(world.shape[1], bool)
    probe[::_PROBE_STRIDE] = True
    for ids in np.flatnonzero(probe), np.flatnonzero(~probe):
        if len(frames) == 0 or len(ids) == 0:
            break
        d = U.signed_distance(library, seq, world[np.ix_(frames, ids)], frames)
        near = (d <= dist).any(1)
        out[frames[near]] = True
        frames = frames[~near]
    return out


def windows_of_run(run: np.ndarray, length: int) -> list[np.ndarray]:
    """Consecutive frames ``run`` cut into windows of at most ``length`` frames."""
    return [run[i : i + length] for i in range(0, len(run), length)]


def windows_of(mask: np.ndarray, length: int) -> list[np.ndarray]:
    """Runs of True frames cut into consecutive windows of at most ``length`` frames."""
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return []
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    return [r[i : i + length] for r in runs for i in range(0, len(r), length)]


# ----------------------------------------------------------------------------- training


def _training_windows(
    seqs: list[Sequence], library: ObjectLibrary, cfg: TochTrainConfig, rng: np.random.Generator
) -> list[Window]:
    """(seq, side, start) of up to ``max_windows`` windows holding at least one
    ground-truth interaction frame, at most ``windows_per_hand`` per sequence and hand.

    Hands are visited in random order and only until enough windows are found, and their
    interaction frames are tested on every ``frame_stride``-th frame: finding the windows
    of every train sequence costs more than the whole training budget.
    """
    pairs = [(seq, side) for seq in seqs if seq.n_frames >= cfg.window for side in U.SIDES]
    out = []
    for k in rng.permutation(len(pairs)):
        seq, side = pairs[k]
        cand = np.arange(0, seq.n_frames, max(cfg.frame_stride, 1))
        p = seq.hand_params(side)
        sub = {key: np.asarray(p[key])[cand] for key in ("global_orient", "hand_pose", "transl")}
        d = U.signed_distance(library, seq, U.seq_vertices(seq, side, sub), cand)
        near = np.zeros(seq.n_frames, bool)
        near[cand] = (d <= cfg.interaction_distance).any(1)
        starts = [
            a
            for a in range(0, seq.n_frames - cfg.window + 1, max(cfg.window // 2, 1))
            if near[a : a + cfg.window].any()
        ]
        for j in rng.permutation(len(starts))[: cfg.windows_per_hand or len(starts)]:
            out.append((seq, side, starts[j]))
        if cfg.max_windows and len(out) >= cfg.max_windows:
            break
    if not out:
        raise InputError(
            f"no train window of {cfg.window} frames near an object", "toch training data"
        )
    return out[: cfg.max_windows or len(out)]


def _window_tensors(
    windows: list[Window],
    library: ObjectLibrary,
    cfg: TochTrainConfig,
    seed: int,
    device: U.Device = "cpu",
) -> list[torch.Tensor]:
    """Stacked (points, normals, noisy field, clean field) over the windows, float32, on
    ``device``."""
    from grip_bench.data.perturb import perturb_sequence

    P, Nn, X, Y = [], [], [], []
    for k, (seq, side, start) in enumerate(windows):
        frames = np.arange(start, start + cfg.window)
        kind, sigma = PERTURBATIONS[k % len(PERTURBATIONS)]
        noisy = perturb_sequence(seq, kind, sigma, np.random.default_rng([seed, k]))
        X.append(hand_fields(library, seq, side, noisy.hand_params(side), frames, cfg.n_points))
        Y.append(hand_fields(library, seq, side, seq.hand_params(side), frames, cfg.n_points))
        pts, nrm = _samples(library, seq.obj_name, cfg.n_points)
        centre = library.mesh(seq.obj_name).centroid
        P.append(np.broadcast_to(pts - centre, (cfg.window, *pts.shape)))
        Nn.append(np.broadcast_to(nrm, (cfg.window, *nrm.shape)))
    return [
        torch.as_tensor(np.stack(a), dtype=torch.float32, device=device) for a in (P, Nn, X, Y)
    ]


def train_toch(
    name: str,
    data_dir: Path,
    cfg: TochTrainConfig,
    seed: int,
    progress: bool,
    device: U.Device = "cpu",
) -> tuple[TemporalAE, int]:
    """The field denoiser, trained on ``device``; hits weighted by the class ratio of the
    training targets."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    library = U.train_library(data_dir)
    seqs = U.train_sequences(data_dir, cfg.max_sequences, seed)
    windows = _training_windows(seqs, library, cfg, rng)
    pts, nrm, noisy, clean = _window_tensors(windows, library, cfg, seed, device)
    pos_weight = hit_pos_weight(clean[..., 0]) ** cfg.hit_balance
    U.log(
        progress,
        name,
        f"{len(windows)} windows of {cfg.window} frames; "
        f"{float(clean[..., 0].mean()):.1%} of the object points are hits, "
        f"weighted x{pos_weight:.2f}",
    )
    net = TemporalAEConfig(
        local_dim=cfg.local_dim,
        frame_dim=cfg.frame_dim,
        gru_hidden=cfg.gru_hidden,
        window=cfg.window,
        skip_dim=cfg.skip_dim,
        decoder_hidden=cfg.decoder_hidden,
    ).build().to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    d = ddp.current()  # DDP under torchrun / --nproc: each rank its share of a batch
    model = ddp.wrap(net, d, torch.device(device))
    for epoch in range(cfg.epochs):
        net.train()
        total = 0.0
        for idx, w in U.rank_batches(U.batches(len(windows), cfg.batch_size, rng), d):
            out = model(pts[idx], nrm[idx], noisy[idx])
            loss = field_losses(out, clean[idx], pos_weight=pos_weight)[0]
            opt.zero_grad()
            U.backward(loss, w)
            opt.step()
            total += loss.item() * len(idx)
        total = ddp.global_sum([total], d)[0]
        U.log(progress, name, f"epoch {epoch + 1}/{cfg.epochs} loss {total / len(windows):.4f}")
    return net.eval(), len(windows)


# ----------------------------------------------------------------------------- method


class TochMethod(U.TrainedMethod):
    """Denoise correspondence fields over interaction windows, then fit the hands to them."""

    section, config_cls, networks = "toch", TochTrainConfig, {"toch": TemporalAEConfig}

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.net: TemporalAE | None = None
        self.cfg = TochTrainConfig()

    def fit(
        self, data_dir: Path, cfg: TochTrainConfig, seed: int, progress: bool,
        device: torch.device,
    ) -> tuple[dict[str, torch.nn.Module], dict]:
        net, n = train_toch(self.name, data_dir, cfg, seed, progress, device)
        return {"toch": net}, {"n_samples": n}

    def load(self, checkpoint: Path | None, device: str = "cpu") -> None:
        nets, ck = self.load_checkpoint(checkpoint, device)
        self.net = nets["toch"]
        self.cfg = TochTrainConfig(**ck.meta["train_config"])

    def predict(self, seq: Sequence, ctx: PredictContext) -> Sequence:
        """Both hands refined on their interaction frames; everything else as in the input
        (the denoiser and the fit run on the device :meth:`load` put the network on)."""
        self._loaded(self.net)
        with U.single_thread():
            new = {side: self._refine_side(seq, ctx.library, side) for side in U.SIDES}
        return seq.with_hands(**new)

    def _refine_side(self, seq: Sequence, library: ObjectLibrary, side: str) -> dict:
        """Per run of interaction frames: denoise its windows, then fit the run at once
        (one smoothness term across the window borders, and one optimisation per run
        instead of one per window). The fitted runs come back to numpy at the end."""
        cfg = self.cfg
        p = {
            k: np.array(seq.hand_params(side)[k], float)
            for k in ("global_orient", "hand_pose", "transl")
        }
        near = interaction_frames(library, seq, side, p, cfg.interaction_distance)
        fitted = []
        for run in windows_of(near, seq.n_frames):
            fields = [
                self._denoise(seq, library, side, p, w) for w in windows_of_run(run, cfg.window)
            ]
            hit, dist, canon = (torch.cat(x).cpu().numpy() for x in zip(*fields, strict=True))
            fit = self._fit_run(seq, side, p, run, hit, dist, canon, library)
            if fit is not None:
                fitted.append((run, fit))
        # Runs are disjoint, so writing them after all the fits reads the same input.
        for run, fit in fitted:
            go, pose, transl = (x.double().cpu().numpy() for x in fit)
            p["global_orient"][run], p["hand_pose"][run], p["transl"][run] = (
                go, pose.reshape(len(run), 45), transl
            )
        return p

    def _denoise(
        self, seq: Sequence, library: ObjectLibrary, side: str, p: dict, frames: np.ndarray
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Denoised field of one window, on the network's device: hit (F, N) bool,
        distance (F, N), canonical (F, N, 3) (float64)."""
        cfg, dev = self.cfg, self.device
        pts, nrm = _samples(library, seq.obj_name, cfg.n_points)
        field = hand_fields(library, seq, side, p, frames, cfg.n_points)

        def per_frame(a: np.ndarray) -> torch.Tensor:  # (N, 3) in the object frame -> (1, F, N, 3)
            return torch.as_tensor(
                np.broadcast_to(a, (len(frames), *a.shape)).copy(), dtype=torch.float32,
                device=dev,
            )[None]

        centre = library.mesh(seq.obj_name).centroid
        with torch.no_grad():
            noisy = torch.as_tensor(field, dtype=torch.float32, device=dev)[None]
            out = self.net(per_frame(pts - centre), per_frame(nrm), noisy)[0].double()
        canon = mirror_points(out[..., 2:]) if side == "left" else out[..., 2:]
        hit = torch.sigmoid(out[..., 0]) > cfg.hit_threshold
        return hit, out[..., 1], canon

    def _fit_run(
        self,
        seq: Sequence,
        side: str,
        p: dict,
        frames: np.ndarray,
        hit: np.ndarray,
        dist: np.ndarray,
        canon: np.ndarray,
        library: ObjectLibrary,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
        """Hand params (go (F,3), pose (F,15,3), transl (F,3), tensors on the network's
        device) of ``frames`` fitted to their denoised fields, or None when the fields have
        no hit."""
        if not hit.any():
            return None
        dev = self.device
        pts, nrm = _samples(library, seq.obj_name, self.cfg.n_points)
        F = len(frames)
        hand = U.seq_hand(seq, side, dev)
        R, t = (
            torch.as_tensor(x[frames], dtype=torch.float32, device=dev)
            for x in U.object_pose(seq)
        )

        def subset_forward(
            ids: np.ndarray,
        ) -> Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]:
            posed = U.SubsetHand(hand, ids)  # world hand vertices ids -> object frame (F, K, 3)

            def forward(go: torch.Tensor, pose: torch.Tensor, transl: torch.Tensor) -> torch.Tensor:
                v = posed(go, pose, transl)[0]
                # world -> object frame, R^T (v - t) with column rotations (torch, so the fit
                # can differentiate through it; core.frames.world_to_object is numpy)
                return torch.einsum("fji,fvj->fvi", R, v - t[:, None])

            return forward

        f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=dev)  # noqa: E731
        res = fit_hand_to_field(
            np.broadcast_to(pts, (F, *pts.shape)),
            np.broadcast_to(nrm, (F, *nrm.shape)),
            hit,
            dist,
            canon,
            subset_forward(np.arange(hand.num_vertices)),
            hand.template_vertices.double().cpu().numpy(),
            np.asarray(hand.faces),
            f32(p["global_orient"][frames]),
            f32(p["hand_pose"][frames]).reshape(F, 15, 3),
            f32(p["transl"][frames]),
            FitConfig(n_iters=self.cfg.fit_iters, w_smooth=self.cfg.fit_smooth),
            subset_forward=subset_forward,
        )
        return res.global_orient, res.hand_pose, res.transl


register_method(
    MethodSpec(
        name="toch",
        description="TOCH-style refiner: denoised correspondence fields + hand fitting on "
        "interaction frames",
        factory=TochMethod,
        needs=("object", "noisy_hands"),
        predict_cost=6.0,  # ray casting and a hand fit per run of interaction frames
    )
)
