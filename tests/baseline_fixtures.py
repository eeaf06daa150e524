"""A tiny grasping dataset with train and test objects, for the baseline method tests.

Sequences come from :mod:`tests.eval_fixtures` (a procedural hand really grasping a
SynthGRAB object, grasps found by ``GraspSynthesizer`` and cached per object).
"""

from __future__ import annotations

import json
from pathlib import Path

from grip_bench.data.grab_io import object_mesh_path, write_grab
from grip_bench.data.splits import write_splits
from tests.eval_fixtures import grasp_sequence, object_and_grasps

# (subject, family, intent, bimanual, split)
SPECS = (
    ("s1", "cylindermedium", "lift", False, "train"),
    ("s2", "cylindermedium", "pass", True, "train"),
    ("s1", "cubesmall", "lift", False, "train"),
    ("s2", "mug", "lift", False, "test"),
)


def baseline_dataset(
    root: Path, T: int = 24, specs: tuple[tuple[str, str, str, bool, str], ...] = SPECS
) -> Path:
    """Write ``DATA/`` (grab/, meshes, splits.json, manifest.json); returns ``root``."""
    root = Path(root)
    splits = {"train": [], "val": [], "test": []}
    for sbj, family, intent, bimanual, split in specs:
        seq = grasp_sequence(family, sbj, intent, bimanual, T)
        write_grab(seq, root / "grab" / sbj / f"{family}_{intent}_1.npz")
        mesh_path = object_mesh_path(root, family)
        if not mesh_path.exists():
            mesh_path.parent.mkdir(parents=True, exist_ok=True)
            object_and_grasps(family)[0].mesh.export(mesh_path)
        if family not in splits[split]:
            splits[split].append(family)
    write_splits(root, splits)
    (root / "manifest.json").write_text(json.dumps({"generator": "test-fixture"}))
    return root
