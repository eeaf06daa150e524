"""Stage unit ``dataset``: SynthGRAB generation, or an imported GRAB-layout folder
normalised to our own files (30 fps, full axis-angle hands, meshes, splits.json).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from ...core.progress import bar

if TYPE_CHECKING:
    from ...data.sequence import Sequence
    from ..execute import RunState
    from ..plan import Unit

# --- stage: data ----------------------------------------------------------------------------
def _copy_sequence_meshes(seq: Sequence, src: Path, dest: Path) -> None:
    """Copy the object mesh (and any subject / table mesh the file names) into ``dest``."""
    from ...data.grab_io import object_mesh_relpath, resolve_object_mesh

    rel = seq.object_mesh if seq.object_mesh and not Path(seq.object_mesh).is_absolute() \
        else object_mesh_relpath(seq.obj_name)
    pairs = [(resolve_object_mesh(seq, src), dest / rel)]
    for r in (seq.table_mesh, seq.body_vtemp, seq.rhand_vtemp, seq.lhand_vtemp):
        if r and not Path(r).is_absolute() and (src / r).is_file():
            pairs.append((src / r, dest / r))
    for a, b in pairs:
        if not b.exists():
            b.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(a, b)


def import_data(src: Path, dest: Path, model_path: str | None, progress: bool) -> None:
    """Normalise a GRAB-layout folder: 30 fps, full axis-angle hands, meshes, splits.json.

    Every later stage then reads our own files, whatever the source (real GRAB at 120 fps
    with PCA hands, or SynthGRAB).
    """
    from ...data.grab_io import list_sequences, load_mano_backend, read_grab, write_grab
    from ...data.splits import read_splits, write_splits

    backend = load_mano_backend(model_path) if model_path else None
    splits = read_splits(src, default="grip")
    for path in bar(list_sequences(src), "import", progress, unit="seq"):
        seq = read_grab(path, mano_backend=backend)
        write_grab(seq, dest / path.relative_to(src))
        _copy_sequence_meshes(seq, src, dest)
    write_splits(dest, splits)


def make_dataset(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Generate SynthGRAB or import ``--data`` into ``tmp/data``."""
    from ...data.grab_io import dataset_hash

    cfg, dest = st.cfg, tmp / "data"
    if cfg.data is not None:
        import_data(cfg.data, dest, cfg.model_path, cfg.progress)
    else:
        from ...data.synth.generate import generate

        generate(dest, profile=cfg.settings["synth_profile"], seed=cfg.settings["data_seed"],
                 workers=cfg.workers, progress=cfg.progress)
    return {"data_hash": dataset_hash(dest), "source_hash": unit.params.get("source_hash")}
