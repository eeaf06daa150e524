"""The object-mesh flags shared by ``predict`` and ``evaluate`` (docs/meshes.md).

``--mesh-scale S`` multiplies mesh coordinates (0.001 for millimetres) and skips the units
check; ``--accept-repair MM`` raises the largest repair distance accepted. Each command
loads the objects of its sequences up front, prints one repair line per mesh to stderr and
records the reports in its output's manifest.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..data.library import ObjectLibrary
    from ..geometry.repair import MeshOptions


def add_mesh_flags(p: argparse.ArgumentParser) -> None:
    from ..core.constants import MESH_REPAIR_TOLERANCE_MM

    p.add_argument("--mesh-scale", type=float, default=None, metavar="S",
                   help="multiply object mesh coordinates by S (0.001: file in millimetres, "
                        "0.01: centimetres); skips the units check")
    p.add_argument("--accept-repair", type=float, default=MESH_REPAIR_TOLERANCE_MM,
                   metavar="MM", help="accept mesh repairs that move the surface by up to MM "
                   f"mm (default {MESH_REPAIR_TOLERANCE_MM:g})")


def mesh_options(args: argparse.Namespace) -> MeshOptions:
    from ..geometry.repair import MeshOptions

    return MeshOptions(scale=args.mesh_scale, accept_repair_mm=args.accept_repair)


def check_meshes(library: ObjectLibrary, files: Iterable[Path]) -> dict[str, dict]:
    """Load (repair) the object of every sequence file once; one stderr line per mesh that
    was changed (a clean mesh says nothing: stderr stays for what needs reading).

    Returns ``{object name: repair report}`` for the manifest, clean meshes included.
    """
    from ..data.grab_io import read_grab_header

    names = sorted({read_grab_header(p)["obj_name"] for p in files})
    reports = {}
    for name in names:
        reports[name] = library.repair_report(name)
        if reports[name].get("method", "none") != "none":
            print(_line(reports[name]), file=sys.stderr)
    return reports


def _line(report: dict) -> str:
    from ..geometry.repair import RepairReport

    return RepairReport(**report).line()
