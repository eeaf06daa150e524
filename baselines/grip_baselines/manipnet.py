"""ManipNet-style single-hand (right) autoregressive finger model.

Written from the ManipNet paper's description, not from its code. Per frame t the model
sees, all in the current wrist frame (metres, 6D rotations):

* the wrist trajectory: positions and orientations of ``n_past`` frames before and
  ``n_future`` frames after t, relative to the wrist at t;
* object occupancy in a ``res^3`` grid of ``cell``-sized cells fixed to the wrist;
* signed distances from the proximity vertices of the *previous* finger pose, placed on
  the wrist of frame t and of each future frame, to the object (clipped);
* the previous finger pose (15 x 6D),

and predicts the finger pose at t (15 x 6D) as a residual on the previous one. The wrist
is given (it comes from the body motion); only the fingers are generated.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from grip_bench.core.constants import (
    MANIPNET_DIST_CLIP,
    MANIPNET_FUTURE,
    MANIPNET_PAST,
    MANIPNET_VOXEL_CELL,
    MANIPNET_VOXEL_CENTER,
    MANIPNET_VOXEL_RES,
    N_HAND_POSE_JOINTS,
    PROXIMITY_N_VERTS,
    ROT6D_DIM,
)
from grip_bench.core.frames import world_to_object
from grip_bench.geometry.rotations import matrix_to_rotation_6d
from grip_bench.nn.blocks import ResMLP, check_config, check_shape

__all__ = [
    "ManipNet",
    "ManipNetConfig",
    "ManipNetInputs",
    "hand_proximity_fn",
    "manipnet_features",
    "motion_features",
    "pose_features",
    "voxel_centres",
]

SdfFn = Callable[[np.ndarray], np.ndarray]  # object-frame points (..., 3) -> signed distance (...)
# (wrist_rot (M, 3, 3), wrist_pos (M, 3), hand_pose (M, 15, 3)) -> proximity vertices (M, P, 3)
ProximityFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass
class ManipNetConfig:
    n_past: int = MANIPNET_PAST
    n_future: int = MANIPNET_FUTURE
    voxel_res: int = MANIPNET_VOXEL_RES
    n_prox: int = PROXIMITY_N_VERTS
    n_joints: int = N_HAND_POSE_JOINTS
    rot_dim: int = ROT6D_DIM
    width: int = 1024
    hidden: int = 1024
    n_blocks: int = 3
    dropout: float = 0.3  # as GRIP's residual MLPs; ManipNet's inputs are as redundant
    zero_init_head: bool = True

    def __post_init__(self) -> None:
        check_config(self, may_be_zero=("n_past", "n_future"))

    @property
    def traj_frames(self) -> int:
        return self.n_past + self.n_future

    @property
    def in_dim(self) -> int:
        traj = self.traj_frames * (3 + self.rot_dim)
        dist = (1 + self.n_future) * self.n_prox
        return traj + self.voxel_res**3 + dist + self.n_joints * self.rot_dim

    def build(self) -> ManipNet:
        return ManipNet(self)


class ManipNet(nn.Module):
    """Residual MLP: features of frame t -> finger pose at t (residual on the previous)."""

    def __init__(self, cfg: ManipNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.net = ResMLP(
            cfg.in_dim,
            cfg.n_joints * cfg.rot_dim,
            width=cfg.width,
            hidden=cfg.hidden,
            n_blocks=cfg.n_blocks,
            dropout=cfg.dropout,
        )
        if cfg.zero_init_head:
            # Untrained = "keep the previous pose", a sane autoregressive start.
            nn.init.zeros_(self.net.head.weight)
            nn.init.zeros_(self.net.head.bias)

    def forward(
        self,
        traj: torch.Tensor,
        voxels: torch.Tensor,
        distances: torch.Tensor,
        prev_pose: torch.Tensor,
    ) -> torch.Tensor:
        """traj (B, past+future, 9) = position (m) + 6D; voxels (B, r, r, r) in {0, 1};
        distances (B, 1+future, P) clipped signed distances (m); prev_pose (B, J, 6).
        Returns the finger pose (B, J, 6)."""
        c = self.cfg
        b = prev_pose.shape[0]
        check_shape(traj, (b, c.traj_frames, 3 + c.rot_dim), "ManipNet traj")
        check_shape(voxels, (b, c.voxel_res, c.voxel_res, c.voxel_res), "ManipNet voxels")
        check_shape(distances, (b, 1 + c.n_future, c.n_prox), "ManipNet distances")
        check_shape(prev_pose, (b, c.n_joints, c.rot_dim), "ManipNet prev_pose")
        x = torch.cat(
            [
                traj.flatten(1),
                voxels.flatten(1).to(traj.dtype),
                distances.flatten(1),
                prev_pose.flatten(1),
            ],
            -1,
        )  # (B, in_dim)
        return prev_pose + self.net(x).unflatten(-1, (c.n_joints, c.rot_dim))


# ----------------------------------------------------------------------------- features


@dataclass
class ManipNetInputs:
    """Features of F frames (numpy, float64): traj (F, past+future, 9), voxels
    (F, r, r, r) float {0, 1}, distances (F, 1+future, P) (m, clipped), prev_pose (F, J, 6)."""

    traj: np.ndarray
    voxels: np.ndarray
    distances: np.ndarray
    prev_pose: np.ndarray

    def torch(
        self, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu"
    ) -> tuple[torch.Tensor, ...]:
        """The four arrays as tensors on ``device``, in :meth:`ManipNet.forward` order."""
        return tuple(
            torch.as_tensor(x, dtype=dtype, device=device)
            for x in (self.traj, self.voxels, self.distances, self.prev_pose)
        )


def voxel_centres(
    res: int = MANIPNET_VOXEL_RES,
    cell: float = MANIPNET_VOXEL_CELL,
    centre: tuple[float, float, float] | np.ndarray = MANIPNET_VOXEL_CENTER,
) -> np.ndarray:
    """Cell centres of the wrist-frame grid, ``(res, res, res, 3)`` (m), index order x, y, z."""
    ax = (np.arange(res) - (res - 1) / 2) * cell
    grid = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)
    return grid + np.asarray(centre, dtype=np.float64)


def _to_object(points: np.ndarray, obj_rot: np.ndarray, obj_pos: np.ndarray) -> np.ndarray:
    """World points (F, ..., 3) -> object frame, with the object pose as column rotations
    (F, 3, 3) (world = R x + t) and translations (F, 3): ``R^T (x - t)``."""
    return world_to_object(points, np.swapaxes(obj_rot, 1, 2), obj_pos)


def _axis_angle_6d(aa: np.ndarray) -> np.ndarray:
    from grip_bench.geometry.rotations import axis_angle_to_rotation_6d

    return np.asarray(axis_angle_to_rotation_6d(np.ascontiguousarray(aa, np.float64)))


def manipnet_features(
    wrist_rot: np.ndarray,
    wrist_pos: np.ndarray,
    obj_rot: np.ndarray,
    obj_pos: np.ndarray,
    prev_hand_pose: np.ndarray,
    sdf: SdfFn,
    proximity_fn: ProximityFn,
    frames: np.ndarray | list[int] | None = None,
    cfg: ManipNetConfig | None = None,
    cell: float = MANIPNET_VOXEL_CELL,
    voxel_centre: tuple[float, float, float] | np.ndarray = MANIPNET_VOXEL_CENTER,
    dist_clip: float = MANIPNET_DIST_CLIP,
) -> ManipNetInputs:
    """ManipNet inputs for the frames ``frames`` (default all) of one sequence.

    wrist_rot (T, 3, 3), wrist_pos (T, 3): right wrist in the world; obj_rot (T, 3, 3),
    obj_pos (T, 3): object pose (world = R x + t); prev_hand_pose (T, 15, 3) axis-angle:
    the finger pose of frame t-1 for each t (ground truth when training, the model's own
    output when rolling out). ``sdf`` works in the object frame (e.g.
    ``DistanceField.signed_distance``); ``proximity_fn`` poses the proximity vertices.
    Trajectory frames past either end repeat the end frame.

    = :func:`motion_features` (what the wrist and object motion give) + :func:`pose_features`
    (what the previous pose gives), each computed per frame.
    """
    cfg = cfg or ManipNetConfig()
    t = np.arange(len(wrist_pos)) if frames is None else np.asarray(frames)
    traj, voxels = motion_features(wrist_rot, wrist_pos, obj_rot, obj_pos, sdf, t, cfg, cell,
                                   voxel_centre)
    distances, prev6 = pose_features(wrist_rot, wrist_pos, obj_rot, obj_pos, prev_hand_pose,
                                     sdf, proximity_fn, t, cfg, dist_clip)
    return ManipNetInputs(traj, voxels, distances, prev6)


def motion_features(
    wrist_rot: np.ndarray,
    wrist_pos: np.ndarray,
    obj_rot: np.ndarray,
    obj_pos: np.ndarray,
    sdf: SdfFn,
    t: np.ndarray,
    cfg: ManipNetConfig,
    cell: float = MANIPNET_VOXEL_CELL,
    voxel_centre: tuple[float, float, float] | np.ndarray = MANIPNET_VOXEL_CENTER,
) -> tuple[np.ndarray, np.ndarray]:
    """The inputs of frames ``t (F,)`` that the previous pose does not change: trajectory
    ``(F, past+future, 9)`` and occupancy ``(F, r, r, r)`` (arguments as
    :func:`manipnet_features`). Every value is a function of its own frame alone, so a
    rollout computes them for all frames at once (the same numbers)."""
    wr, wp = np.asarray(wrist_rot, np.float64), np.asarray(wrist_pos, np.float64)
    orot, opos = np.asarray(obj_rot, np.float64), np.asarray(obj_pos, np.float64)
    n = len(wp)
    offsets = np.r_[np.arange(-cfg.n_past, 0), np.arange(1, cfg.n_future + 1)]
    idx = np.clip(t[:, None] + offsets, 0, n - 1)  # (F, past+future)
    rt = wr[t]  # (F, 3, 3) current wrist
    rel_pos = np.einsum("fji,fkj->fki", rt, wp[idx] - wp[t][:, None])  # R_t^T (p_k - p_t)
    rel_rot = np.einsum("fji,fkjl->fkil", rt, wr[idx])  # R_t^T R_k
    traj = np.concatenate([rel_pos, np.asarray(matrix_to_rotation_6d(rel_rot))], -1)

    # Occupancy: cell centres in the wrist frame -> world -> object frame -> inside?
    cells = voxel_centres(cfg.voxel_res, cell, voxel_centre)  # (r, r, r, 3)
    world = np.einsum("fij,abcj->fabci", rt, cells) + wp[t][:, None, None, None]
    voxels = (np.asarray(sdf(_to_object(world, orot[t], opos[t]))) < 0).astype(np.float64)
    return traj, voxels


def pose_features(
    wrist_rot: np.ndarray,
    wrist_pos: np.ndarray,
    obj_rot: np.ndarray,
    obj_pos: np.ndarray,
    prev_hand_pose: np.ndarray,
    sdf: SdfFn,
    proximity_fn: ProximityFn,
    t: np.ndarray,
    cfg: ManipNetConfig,
    dist_clip: float = MANIPNET_DIST_CLIP,
) -> tuple[np.ndarray, np.ndarray]:
    """The inputs of frames ``t (F,)`` that come from the previous pose: clipped distances
    ``(F, 1+future, P)`` (m) and the previous pose in 6D ``(F, J, 6)`` (arguments as
    :func:`manipnet_features`)."""
    wr, wp = np.asarray(wrist_rot, np.float64), np.asarray(wrist_pos, np.float64)
    orot, opos = np.asarray(obj_rot, np.float64), np.asarray(obj_pos, np.float64)
    prev = np.asarray(prev_hand_pose, np.float64)
    n = len(wp)
    # Distances of the previous pose's proximity vertices, on the wrist at t and ahead.
    future = np.clip(t[:, None] + np.arange(cfg.n_future + 1), 0, n - 1)  # (F, 1+future)
    m = future.reshape(-1)
    pose_rep = np.repeat(prev[t], cfg.n_future + 1, axis=0)  # (F*(1+future), 15, 3)
    prox = np.asarray(proximity_fn(wr[m], wp[m], pose_rep))  # (F*(1+future), P, 3)
    d = np.asarray(sdf(_to_object(prox, orot[m], opos[m])))
    distances = np.clip(d, -dist_clip, dist_clip).reshape(len(t), cfg.n_future + 1, -1)
    return distances, _axis_angle_6d(prev[t])


def hand_proximity_fn(hand: torch.nn.Module) -> ProximityFn:
    """A :data:`ProximityFn` from a hand model (ProceduralHand): wrist rotation matrices are
    turned into axis-angle for ``hand.forward``; returns ``proximity_ids`` vertices."""
    from grip_bench.geometry.rotations import matrix_to_axis_angle

    ids = torch.tensor(np.asarray(hand.proximity_ids, dtype=np.int64))

    def fn(rot: np.ndarray, pos: np.ndarray, pose: np.ndarray) -> np.ndarray:
        dtype = hand.template_vertices.dtype
        t = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
        with torch.no_grad():
            verts = hand(matrix_to_axis_angle(t(rot)), t(pose), t(pos))[0]
        return verts[:, ids.to(verts.device)].double().cpu().numpy()

    return fn
