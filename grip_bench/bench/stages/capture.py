"""Stage of a ``dataset`` unit with capture noise (``[run] capture_noise`` other than "none").

The dataset is generated as without noise (``stages.data``), then every sequence goes
through the capture-noise model (``data.capture_noise``, docs/seeds_and_noise.md). This
module is separate so that noise-free dataset units keep their keys: their code is the
closure of ``stages.data`` alone, and a noisy dataset unit's code adds this module
(``bench.plan.CAPTURE_MODULE``); the runner picks the function by the unit's inputs.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ...data.capture_noise import MODELS, CaptureNoise, apply_to_dataset
from .data import make_dataset

if TYPE_CHECKING:
    from ..execute import RunState
    from ..plan import Unit


def make_noisy_dataset(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Generate the dataset into ``tmp/data``, then apply the unit's capture-noise model
    (seeded by ``[run] data_seed``) to every sequence; the data hash is of the noisy files,
    and ``data/capture_noise.json`` holds the model and its measured statistics."""
    from ...data.grab_io import dataset_hash
    from ...metrics.aggregate import default_workers

    info = make_dataset(st, unit, tmp)
    spec = dict(unit.params["inputs"]["capture_noise"])
    name = spec.pop("model")
    model = CaptureNoise(**spec)  # as planned: the parameters are part of the key
    record = apply_to_dataset(tmp / "data", name if MODELS.get(name) == model else model,
                              seed=st.cfg.settings["data_seed"], progress=st.cfg.progress,
                              workers=st.cfg.workers or default_workers())
    return {**info, "data_hash": dataset_hash(tmp / "data"), "capture_noise": record["statistics"]}
