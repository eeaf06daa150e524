"""Per-object caches shared by evaluation, sensors and methods: canonical mesh and distance field.

Distance fields cost ~0.1-2 s to build, so every consumer of a dataset goes through one
:class:`ObjectLibrary` and each object's field is built once per process.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import InputError
from ..core.frames import world_to_object
from .grab_io import object_mesh_path

if TYPE_CHECKING:
    import trimesh

    from ..geometry.distance import DistanceField
    from ..geometry.repair import MeshOptions
    from .sequence import Sequence


class ObjectLibrary:
    """Canonical object meshes and distance fields of one dataset directory.

    mesh_options: how meshes are taken in (``--mesh-scale``, ``--accept-repair``; default:
    no scale, the default repair tolerance; docs/meshes.md).
    """

    def __init__(self, data_dir: str | Path, mesh_options: MeshOptions | None = None):
        self.data_dir = Path(data_dir)
        self.mesh_options = mesh_options
        self.mesh = lru_cache(maxsize=None)(self._load_mesh)
        self.field = lru_cache(maxsize=64)(self._build_field)

    def _load_mesh(self, name: str) -> trimesh.Trimesh:
        """Watertight canonical mesh of ``name`` (trimesh, metres, object frame)."""
        from ..geometry.meshes import load_object_mesh

        path = object_mesh_path(self.data_dir, name)
        if not path.is_file():
            raise InputError(f"object mesh not found: {path}", f"object '{name}'")
        return load_object_mesh(path, options=self.mesh_options)

    def repair_report(self, name: str) -> dict:
        """The repair report of ``name``'s mesh (loads it): method, counts, distances (mm)."""
        return dict(self.mesh(name).metadata["repair"])

    def _build_field(self, name: str) -> DistanceField:
        from ..geometry.distance import DistanceField

        return DistanceField(self.mesh(name))

    def world_to_object(self, seq: Sequence, points: np.ndarray) -> np.ndarray:
        """World points (T, N, 3) -> the object's frame at each frame (T, N, 3)
        (:func:`grip_bench.core.frames.world_to_object`)."""
        return world_to_object(points, seq.object_rotations(), seq.object["transl"])
