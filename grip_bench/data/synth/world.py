"""SynthGRAB's cast and stage: subjects, generation profiles, intents, table placement.

Everything here is data plus small seeded draws; the motion itself is made by
:mod:`grip_bench.data.synth.episode` and the modules it drives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GENERATOR_NAME = "SynthGRAB"
GENERATOR_VERSION = "2.5"  # 2.1: hook grasps, regrasps in a third of one-handed use sequences;
# 2.2: among grasps touching with the same parts, one that can hold the lifted object wins;
# 2.3: the hand's thumb opposes (its CMC framed for opposition): pinch pads meet head-on and
# straddle the object, a wrapping thumb opposes before it curls; 2.4: exact pinches (the pads on
# opposing surface points), handle grasps wrap the bar (never from along it), the large box
# is an open storage box (its walls' mass, ~1 kg, not a 10.5 kg block); 2.5: compact objects
# are pinched at their centre's height from 2 cm above their base (PINCH_CENTRE_MIN; 2.5 cm),
# and a grasp the object's surface cuts more than MAX_PENETRATION into is refused (cut_depth)

# GRAB's intents; "use" becomes an object-specific verb as in GRAB's file names.
INTENTS = ("lift", "pass", "use", "offhand")
USE_VERBS = {
    "drink": "drink", "look": "see", "cut": "chop", "eat": "eat", "brush": "brush",
    "pour": "pour", "none": "inspect",
}

# Stature range of adults (m); hand length scales with stature (hand length is
# ~10.8% of stature: Drillis & Contini 1966) with individual variation of ~4%.
HEIGHT_RANGE = (1.55, 1.92)
TABLE_HEIGHT_RANGE = (0.75, 1.2)  # GRAB used tables of several heights (issue spec)


@dataclass(frozen=True)
class Subject:
    """One synthetic participant."""

    sid: str  # "s1" ...
    gender: str  # "male" | "female"
    height: float  # m
    hand_scale: float  # multiplies the 0.19 m default hand
    handedness: str  # "right" | "left"

    @property
    def dominant(self) -> str:
        return self.handedness

    @property
    def off_hand(self) -> str:
        return "left" if self.handedness == "right" else "right"


def make_subjects(n: int, seed: int) -> list[Subject]:
    """``n`` subjects spread over the stature range; about 1 in 8 left-handed (at least one if
    n >= 8)."""
    rng = np.random.default_rng([seed, 7001])
    heights = np.linspace(*HEIGHT_RANGE, n)
    rng.shuffle(heights)
    lefties = set(rng.choice(n, size=max(1 if n >= 8 else 0, n // 8), replace=False).tolist())
    subjects = []
    for k in range(n):
        h = float(heights[k])
        hand = h / 1.76 * float(np.clip(rng.normal(1.0, 0.04), 0.9, 1.1))
        gender = "male" if (h > 1.73) ^ (rng.random() < 0.2) else "female"
        subjects.append(Subject(f"s{k + 1}", gender, round(h, 3), round(hand, 3),
                                "left" if k in lefties else "right"))
    return subjects


@dataclass(frozen=True)
class Profile:
    """Size of a generated dataset."""

    name: str
    n_subjects: int
    instances_per_family: int
    sequences: int  # total sequence budget
    intent_weights: tuple[float, float, float, float]  # lift, pass, use, offhand


PROFILES = {
    "smoke": Profile("smoke", 10, 1, 20, (0.35, 0.2, 0.3, 0.15)),
    "default": Profile("default", 10, 3, 300, (0.3, 0.25, 0.3, 0.15)),
    "large": Profile("large", 10, 4, 1300, (0.3, 0.25, 0.3, 0.15)),
}


@dataclass(frozen=True)
class Stage:
    """Where things stand in the world (y up, body faces +z, pelvis starts above x = z = 0)."""

    table_height: float  # m, top surface
    table_front: float  # m, z of the table edge facing the subject
    object_xz: tuple[float, float]  # object centre on the table
    object_yaw: float  # rad, about +y


def draw_stage(rng: np.random.Generator, subject: Subject, obj_radius: float, large: bool) -> Stage:
    """A table in front of the subject with the object placed within comfortable reach."""
    h = float(rng.uniform(*TABLE_HEIGHT_RANGE))
    front = 0.22 + 0.05 * subject.height / 1.76
    reach_z = front + max(0.08, obj_radius) + float(rng.uniform(0.02, 0.1))
    # Offset the object slightly toward the dominant side (people place things there).
    side = -1.0 if subject.handedness == "right" else 1.0
    x = 0.0 if large else side * float(rng.uniform(0.0, 0.15))
    return Stage(h, front, (x, reach_z), float(rng.uniform(-np.pi, np.pi)))
