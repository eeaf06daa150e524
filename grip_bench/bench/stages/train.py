"""Stage unit ``checkpoint``: one method trained on the dataset's train split.

``grip-bench train`` calls :func:`train_checkpoint` too, so both entry points run the same
code on the same floating-point path (one torch thread) and write the same bytes.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from ...core.threads import single_thread
from ...methods.api import METHODS, TrainContext

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit


def train_checkpoint(name: str, data_dir: Path, out: Path, ctx: TrainContext) -> Path:
    """Train registered method ``name`` on ``data_dir`` and write its checkpoint ``out``.

    One torch thread: the same floating-point path in a worker process, in-process and in
    ``grip-bench train``, so the same seed gives the same bytes.
    """
    method = METHODS.get(name).build()
    with single_thread():
        return Path(method.train(Path(data_dir), Path(out), ctx))


def train_method(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Train one method on the dataset's train split; the checkpoint is the unit.

    Training writes into ``cache/work/<key>/`` (outside the atomic temp folder) so that a
    method that checkpoints its progress (GRIP's ``<out>.partial``) resumes after a kill;
    the finished file is then moved into the unit. GRIP's variants share the sensor
    features of the data through ``cache/features/<code>/`` (keyed inside by data hash):
    one folder per version of the code that trains them, so edited code never reads
    features an older version wrote.
    """
    work = st.cache.root / "work" / unit.key
    work.mkdir(parents=True, exist_ok=True)
    features = st.cache.root / "features" / unit.params["inputs"]["code"][:16]
    ctx = TrainContext(profile=st.cfg.profile, seed=st.cfg.seed, device=st.cfg.device,
                       progress=st.cfg.progress, feature_cache=features)
    path = train_checkpoint(unit.params["method"], st.data_dir(unit.deps[0]),
                            work / "model.ckpt", ctx)
    shutil.move(path, tmp / path.name)
    shutil.rmtree(work, ignore_errors=True)
    return {"file": path.name}
