"""Key-frame tracks of an episode: what the choreography writes and the solver reads.

:class:`Track` (rigid-pose keys, min-jerk between them), :class:`PoseTrack` (finger-pose
keys) and :class:`Script`: a track of each kind per hand, the object's track, a frame
cursor and the spans saying which hand carries or holds the object. Kept apart from
:mod:`.choreography` because :mod:`.solve` reads scripts but needs none of the
choreography.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...core.frames import SIDES
from .motion import blend, min_jerk_path, slerp_path


# --- key-frame tracks ----------------------------------------------------------------
@dataclass
class Track:
    """Key frames of a rigid pose (and optionally a finger pose); min-jerk between keys.

    keys: ``(frame, position (3,), rotation (3, 3), via (3,) | None)``; a key's ``via``
    bends the path that ends at it. Before the first key and after the last the pose holds.
    """

    keys: list = field(default_factory=list)

    def add(
        self,
        frame: int,
        p: np.ndarray,
        R: np.ndarray,
        via: tuple[np.ndarray, float] | None = None,
        ease: str = "both",
    ) -> None:
        """Key at ``frame``; ``via`` = (point (3,), progress in (0, 1)) bends the path ending
        here; ``ease`` as :func:`.motion.min_jerk_path` takes it."""
        if self.keys and frame <= self.keys[-1][0]:
            raise ValueError(f"key frame {frame} not after {self.keys[-1][0]}")
        self.keys.append((int(frame), np.asarray(p, float), np.asarray(R, float), via, ease))

    @property
    def last(self) -> tuple[np.ndarray, np.ndarray]:
        return self.keys[-1][1], self.keys[-1][2]

    def sample(self, T: int) -> tuple[np.ndarray, np.ndarray]:
        """Positions (T, 3) and rotations (T, 3, 3) at every frame."""
        pos, rot = np.empty((T, 3)), np.empty((T, 3, 3))
        f0, p0, R0 = self.keys[0][:3]
        pos[: f0 + 1], rot[: f0 + 1] = p0, R0
        for (fa, pa, Ra, *_), (fb, pb, Rb, via, ease) in zip(
            self.keys[:-1], self.keys[1:], strict=True
        ):
            n = fb - fa + 1
            point, at = via if via is not None else (None, 0.5)
            pos[fa: fb + 1] = min_jerk_path(pa, pb, n, point, at, ease)
            rot[fa: fb + 1] = slerp_path(Ra, Rb, n) if not np.allclose(Ra, Rb) else Ra
        fl, pl, Rl = self.keys[-1][:3]
        pos[fl:], rot[fl:] = pl, Rl
        return pos, rot


@dataclass
class PoseTrack:
    """Key frames of a finger pose (15, 3); min-jerk blends between keys."""

    keys: list = field(default_factory=list)

    def add(self, frame: int, pose: np.ndarray) -> None:
        if self.keys and frame <= self.keys[-1][0]:
            raise ValueError(f"pose key frame {frame} not after {self.keys[-1][0]}")
        self.keys.append((int(frame), np.asarray(pose, float)))

    def sample(self, T: int) -> np.ndarray:
        """Finger poses (T, 15, 3)."""
        out = np.empty((T, 15, 3))
        f0, q0 = self.keys[0]
        out[: f0 + 1] = q0
        for (fa, qa), (fb, qb) in zip(self.keys[:-1], self.keys[1:], strict=True):
            out[fa: fb + 1] = blend(qa, qb, fb - fa + 1)
        out[self.keys[-1][0]:] = self.keys[-1][1]
        return out


@dataclass
class Script:
    """The choreography being written: a frame cursor, hand and object tracks, spans.

    ``carrier`` spans say which hand's wrist the object follows; ``attached`` spans say
    when a hand's wrist follows the object (its own keys are ignored there).
    """

    fps: float
    rest: dict  # side -> (p (3,), R (3, 3)) rest wrist frames
    relaxed: dict  # side -> (15, 3) relaxed finger pose, or (2, 15, 3): before / after
    obj_rest: tuple  # (R (3, 3), p (3,))
    t: int = 0
    wrist: dict = field(default_factory=dict)
    fingers: dict = field(default_factory=dict)
    obj: Track = field(default_factory=Track)
    carrier: list = field(default_factory=list)  # (a, b, side): frames [a, b)
    attached: list = field(default_factory=list)  # (a, b, side)
    phases: list = field(default_factory=list)  # (name, a, b)
    relaxed_end: dict = field(init=False, default_factory=dict)  # side -> (15, 3)

    def __post_init__(self) -> None:
        # an idle hand's pose before the grasp (``relaxed``) and after it (``relaxed_end``)
        poses = {s: np.asarray(self.relaxed[s], float) for s in SIDES}
        self.relaxed = {s: p[0] if p.ndim == 3 else p for s, p in poses.items()}
        self.relaxed_end = {s: p[-1] if p.ndim == 3 else p for s, p in poses.items()}
        for s in SIDES:
            self.wrist[s] = Track()
            self.wrist[s].add(0, *self.rest[s])
            self.fingers[s] = PoseTrack()
            self.fingers[s].add(0, self.relaxed[s])
        self.obj.add(0, self.obj_rest[1], self.obj_rest[0])

    def frames(self, seconds: float) -> int:
        return max(2, int(round(seconds * self.fps)))

    def phase(self, name: str, seconds: float) -> tuple[int, int]:
        """Advance the cursor by ``seconds``; return the span ``(a, b)`` (b = new cursor)."""
        a = self.t
        self.t += self.frames(seconds)
        self.phases.append((name, a, self.t))
        return a, self.t

    def move(
        self,
        side: str,
        a: int,
        b: int,
        p: np.ndarray,
        R: np.ndarray,
        via: tuple[np.ndarray, float] | None = None,
        ease: str = "both",
    ) -> None:
        """Wrist of ``side`` holds its last key until ``a`` and moves to ``(p, R)`` by ``b``."""
        tr = self.wrist[side]
        if tr.keys[-1][0] < a:
            tr.add(a, *tr.last)
        tr.add(b, p, R, via, ease)

    def shape(self, side: str, a: int, b: int, pose: np.ndarray) -> None:
        """Fingers of ``side`` hold until ``a`` and blend to ``pose`` by ``b``."""
        tr = self.fingers[side]
        if tr.keys[-1][0] < a:
            tr.add(a, tr.keys[-1][1])
        tr.add(b, pose)

    def carry(self, a: int, b: int, p: np.ndarray, R: np.ndarray) -> None:
        """Object holds until ``a`` and moves to ``(p, R)`` by ``b`` (a hand must carry it)."""
        if self.obj.keys[-1][0] < a:
            self.obj.add(a, *self.obj.last)
        self.obj.add(b, p, R)

    @property
    def obj_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The object's (R, p) at the last key."""
        p, R = self.obj.last
        return R, p
