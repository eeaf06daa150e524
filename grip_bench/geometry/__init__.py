"""Geometry: rotations, object meshes, distance fields.

Rotations are imported eagerly (light, torch only); ``meshes`` and ``distance``
load trimesh / manifold3d / libigl on first attribute access.
"""

from __future__ import annotations

from typing import Any

from grip_bench.geometry.rotations import (
    axis_angle_to_matrix,
    axis_angle_to_quaternion,
    axis_angle_to_rotation_6d,
    matrix_to_axis_angle,
    matrix_to_quaternion,
    matrix_to_rotation_6d,
    quaternion_to_axis_angle,
    quaternion_to_matrix,
    rotation_6d_to_axis_angle,
    rotation_6d_to_matrix,
    standardize_quaternion,
)

_LAZY = {
    "load_object_mesh": "meshes",
    "ObjectAsset": "meshes",
    "to_manifold": "meshes",
    "from_manifold": "meshes",
    "DistanceField": "distance",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        module = importlib.import_module(f"grip_bench.geometry.{_LAZY[name]}")
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "axis_angle_to_matrix",
    "axis_angle_to_quaternion",
    "axis_angle_to_rotation_6d",
    "matrix_to_axis_angle",
    "matrix_to_quaternion",
    "matrix_to_rotation_6d",
    "quaternion_to_axis_angle",
    "quaternion_to_matrix",
    "rotation_6d_to_axis_angle",
    "rotation_6d_to_matrix",
    "standardize_quaternion",
    *_LAZY,
]
