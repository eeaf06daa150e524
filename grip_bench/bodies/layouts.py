"""Joint layouts shared by the procedural and the real (smplx) backends.

MANO order (16 joints + 5 tips = 21 keypoints) and the SMPL-X 55-joint order
with its kinematic parent table, as in the official model files.
"""

from __future__ import annotations

FINGERS = ("index", "middle", "pinky", "ring", "thumb")  # MANO's (non-anatomical) order

# MANO: wrist, then index1-3, middle1-3, pinky1-3, ring1-3, thumb1-3.
MANO_JOINTS: tuple[str, ...] = ("wrist",) + tuple(f"{f}{i}" for f in FINGERS for i in (1, 2, 3))
MANO_PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)
# Fingertips appended after the 16 joints, in the common OpenPose-compatible
# keypoint convention of MANO code bases: thumb, index, middle, ring, pinky.
TIP_NAMES: tuple[str, ...] = ("thumb_tip", "index_tip", "middle_tip", "ring_tip", "pinky_tip")
HAND_KEYPOINTS: tuple[str, ...] = MANO_JOINTS + TIP_NAMES
# The joint each tip hangs from (distal joint of that finger).
TIP_PARENTS: tuple[int, ...] = (15, 3, 6, 12, 9)
FINGER_JOINTS = tuple(range(1, 16))  # the 15 joints MPJPE counts

# Vertex part labels (heatmaps, contact statistics).
HAND_PARTS: tuple[str, ...] = ("palm", "thumb", "index", "middle", "ring", "pinky")

SMPLX_JOINTS: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "jaw", "left_eye_smplhf",
    "right_eye_smplhf",
    *(f"left_{f}{i}" for f in FINGERS for i in (1, 2, 3)),
    *(f"right_{f}{i}" for f in FINGERS for i in (1, 2, 3)),
)
SMPLX_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53,
)
SMPLX_INDEX = {name: i for i, name in enumerate(SMPLX_JOINTS)}
N_BODY_POSE_JOINTS = 21  # body_pose covers joints 1..21

assert len(SMPLX_JOINTS) == 55 and len(SMPLX_PARENTS) == 55
assert len(MANO_JOINTS) == 16 and len(HAND_KEYPOINTS) == 21
