"""Procedural imperfect meshes for the repair tests (docs/meshes.md).

:func:`open_mug`: a mug as a modeller might export it: wall (a thick annulus), base and
handle (a torus sunk into the wall) as separate, overlapping shells, the wall's vertices
duplicated along a texture seam, and a hole of ~20 mm perimeter punched in the wall.
"""

from __future__ import annotations

import numpy as np
import trimesh

MUG_RADIUS, MUG_WALL, MUG_HEIGHT = 0.04, 0.004, 0.09  # m


def split_seam(mesh: trimesh.Trimesh, axis: int = 0) -> trimesh.Trimesh:
    """Duplicate the vertices of faces on the positive side of ``axis`` (a texture seam)."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces).copy()
    side = mesh.triangles_center[:, axis] > 0
    used = np.unique(f[side])
    remap = np.arange(len(v))
    remap[used] = len(v) + np.arange(len(used))
    f[side] = remap[f[side]]
    return trimesh.Trimesh(np.vstack([v, v[used]]), f, process=False)


def punch_hole(mesh: trimesh.Trimesh, centre, radius: float) -> trimesh.Trimesh:
    """Remove the faces whose centre lies within ``radius`` of ``centre``."""
    keep = np.linalg.norm(mesh.triangles_center - np.asarray(centre), axis=1) > radius
    return trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)


def open_mug() -> trimesh.Trimesh:
    """The imperfect mug (m, y up)."""
    wall = trimesh.creation.annulus(MUG_RADIUS - MUG_WALL, MUG_RADIUS, MUG_HEIGHT, sections=96)
    v, f = trimesh.remesh.subdivide_to_size(wall.vertices, wall.faces, max_edge=0.006)
    wall = trimesh.Trimesh(v, f)
    base = trimesh.creation.cylinder(MUG_RADIUS - 0.001, 0.006, sections=96)
    base.apply_translation([0, 0, -MUG_HEIGHT / 2 + 0.003])
    handle = trimesh.creation.torus(0.025, 0.006, major_sections=48, minor_sections=16)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([MUG_RADIUS + 0.012, 0, 0])
    wall = punch_hole(split_seam(wall), [-MUG_RADIUS - 0.002, 0.0, 0.0], 0.0045)
    mesh = trimesh.util.concatenate([wall, base, handle])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
