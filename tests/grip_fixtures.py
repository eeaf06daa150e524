"""A tiny GRAB-layout dataset where the right hand holds a box: enough for GRIP's training
and prediction tests (interaction frames for RNet, far frames for the mask)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from grip_bench.data.grab_io import object_mesh_path, write_grab
from grip_bench.data.splits import write_splits
from grip_bench.profiles import load_profile
from tests.grab_fixtures import box_mesh, make_sequence

SPECS = [("s1", "mug", "lift"), ("s1", "apple", "pass"), ("s2", "mug", "pass"),
         ("s2", "cup", "lift"), ("s1", "bowl", "lift")]
SPLITS = {"train": ["mug", "apple"], "val": ["cup"], "test": ["bowl"]}


def holding_sequence(T: int, seed: int, obj: str, intent: str, sbj: str):
    """A fixture sequence whose object sits 5 cm in front of the right palm for the middle
    half of the frames and 40 cm away otherwise."""
    seq = make_sequence(T, seed=seed, obj_name=obj, intent=intent, sbj_id=sbj)
    near = np.zeros(T, bool)
    near[T // 4: 3 * T // 4] = True
    offset = np.where(near[:, None], [0.0, -0.05, 0.0], [0.0, -0.4, 0.0])
    obj_params = dict(seq.object)
    obj_params["transl"] = (seq.rhand["transl"] + offset).astype(np.float32)
    return replace(seq, object=obj_params).validate()


def write_grip_dataset(root: Path, T: int = 24) -> Path:
    root = Path(root)
    for i, (sbj, obj, intent) in enumerate(SPECS):
        write_grab(
            holding_sequence(T, i, obj, intent, sbj), root / "grab" / sbj / f"{obj}_{intent}_1.npz"
        )
        mesh = object_mesh_path(root, obj)
        if not mesh.exists():
            mesh.parent.mkdir(parents=True, exist_ok=True)
            box_mesh().export(mesh)
    write_splits(root, SPLITS)
    return root


def tiny_profile(**overrides) -> dict:
    """The smoke profile with the fewest epochs (tests of behaviour, not of accuracy)."""
    p = load_profile("smoke")
    p["grip"].update(epochs_anet=1, epochs_cnet=2, epochs_rnet=1, batch_size=32, **overrides)
    return p
