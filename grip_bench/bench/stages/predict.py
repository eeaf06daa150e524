"""Stage unit ``prediction``: one method on one test set, written as a GRAB-layout folder.

``grip-bench predict`` calls :func:`predict_files` too, so both entry points write the same
files the same way.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ...core.progress import bar
from ...core.threads import single_thread
from ...methods.api import METHODS, PredictContext
from ...results.layout import CLEAN, MAIN_SPLIT

if TYPE_CHECKING:
    from ...data.sequence import Sequence
    from ...methods.api import Method
    from ..execute import RunState
    from ..plan import Unit

def loaded_method(st: RunState, name: str, ckpt_key: str | None) -> Method:
    """The method ``name`` built and loaded once per run (weights from its checkpoint unit)."""
    if (name, ckpt_key) not in st.methods:
        method = METHODS.get(name).build()
        ckpt = None
        if ckpt_key is not None:
            ckpt = st.unit_dir(ckpt_key) / st.info(ckpt_key)["info"]["file"]
        method.load(ckpt, device=st.cfg.device)
        st.methods[(name, ckpt_key)] = method
    return st.methods[(name, ckpt_key)]


def _predict_context(st: RunState, in_dir: Path, perturbation: str,
                     online: bool = False) -> PredictContext:
    """The context of every prediction of a run on the test set ``in_dir``."""
    from ...data.library import ObjectLibrary

    # refine: on a perturbed set the task is Table 3's, refining the given noisy hands
    return PredictContext(library=ObjectLibrary(in_dir), device=st.cfg.device, seed=st.cfg.seed,
                          online=online, refine=perturbation != CLEAN,
                          data_dir=st.data_dir(st.plan.data_key), split=MAIN_SPLIT,
                          perturbation=perturbation)


def _copy_dataset_files(in_dir: Path, dest: Path) -> None:
    """Meshes and splits beside the predictions, so the folder is a complete dataset."""
    from ...data.splits import SPLITS_FILE, read_splits, write_splits

    if (in_dir / "tools").is_dir():
        shutil.copytree(in_dir / "tools", dest / "tools", dirs_exist_ok=True)
    if (in_dir / SPLITS_FILE).is_file():
        write_splits(dest, read_splits(in_dir))


def predict_files(method: Method, files: list[Path], in_dir: Path, out_dir: Path,
                  ctx: PredictContext, progress: bool = True, label: str = "predict",
                  on_done: Callable[[Sequence, float], None] | None = None) -> None:
    """Predict each sequence file of data folder ``in_dir`` into the same relative path
    under ``out_dir`` (GRAB layout), one torch thread, then copy meshes and splits so that
    ``out_dir`` is a complete dataset. ``on_done(seq, seconds)`` is called per input
    sequence with its prediction time."""
    import time

    from ...data.grab_io import read_grab, write_grab

    with single_thread():  # the same floating-point path in a worker and in-process
        for path in bar(files, label, progress, unit="seq"):
            seq = read_grab(path)
            t0 = time.perf_counter()
            pred = method.predict(seq, ctx)
            if on_done is not None:
                on_done(seq, time.perf_counter() - t0)
            write_grab(pred, out_dir / path.relative_to(in_dir))
    _copy_dataset_files(in_dir, out_dir)


def predict_set(st: RunState, unit: Unit, tmp: Path) -> dict:
    """One method on one test set: GRAB-layout files with the method's hands."""
    from ...data.splits import sequences_in_split

    p = unit.params
    method = loaded_method(st, p["method"], p["checkpoint"])
    in_dir = st.data_dir(p["input"])
    files = sequences_in_split(in_dir, MAIN_SPLIT)
    predict_files(method, files, in_dir, tmp, _predict_context(st, in_dir, p["perturbation"]),
                  st.cfg.progress, p["method"])
    return {"sequences": len(files)}
