"""Stage unit ``runtime``: prediction time per frame, offline and (if supported) online.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ...methods.api import METHODS
from ...results.layout import CLEAN, MAIN_SPLIT
from .predict import _predict_context, loaded_method

if TYPE_CHECKING:
    from ...data.sequence import Sequence
    from ...methods.api import Method, PredictContext
    from ..execute import RunState
    from ..plan import Unit

# --- stage: runtime -------------------------------------------------------------------------
def _time_once(
    method: Method, seqs: list[Sequence], ctx: PredictContext, device: str
) -> float:
    t0 = time.perf_counter()
    for seq in seqs:
        method.predict(seq, ctx)
    if device.startswith("cuda"):
        import torch

        torch.cuda.synchronize()  # kernels run asynchronously; time their completion
    return time.perf_counter() - t0


def time_method(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Prediction seconds per frame: offline (whole sequences) and, if supported, online.

    One untimed warm-up call first (lazy imports, distance fields, CUDA context); then
    ``runtime_repeats`` timed passes over the first ``runtime_sequences`` test sequences,
    one row each. ``batch`` is the number of sequences per ``predict`` call (1).
    """
    from ...data.grab_io import read_grab
    from ...data.splits import sequences_in_split

    p, s, device = unit.params, st.cfg.settings, st.cfg.device
    method = loaded_method(st, p["method"], p["checkpoint"])
    in_dir = st.data_dir(p["data"])
    seqs = [read_grab(f) for f in sequences_in_split(in_dir, MAIN_SPLIT)[:s["runtime_sequences"]]]
    frames = sum(seq.n_frames for seq in seqs)
    online_too = METHODS.get(p["method"]).supports_online
    modes = [("offline", False)] + ([("online", True)] if online_too else [])
    rows = []
    for mode, online in modes if seqs else []:
        ctx = _predict_context(st, in_dir, CLEAN, online=online)
        _time_once(method, seqs[:1], ctx, device)
        for _ in range(s["runtime_repeats"]):
            dt = max(_time_once(method, seqs, ctx, device), 1e-9)
            rows.append({"method": p["method"], "mode": mode, "device": device, "batch": 1,
                         "seconds_per_frame": dt / frames, "frames_per_second": frames / dt})
    (tmp / "runtime.json").write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    return {"frames": frames}
