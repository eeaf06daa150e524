"""Tiny ``grip-bench run`` profiles for tests: SynthGRAB's ``tiny`` data (3 sequences) and
only the ``[run]`` keys a test changes; every other key takes the value below."""

from __future__ import annotations

import json
from pathlib import Path

TINY_RUN = {
    "data": "synth", "synth_profile": "tiny", "data_seed": 0, "dataset": "",
    "tables": ["table4_grasp"], "methods": ["gt"], "extra_methods": [], "perturbations": [],
    "perturb_seed": 0, "seed": 0, "metrics": ["mpjpe", "mpvpe", "cc", "contact_ratio"],
    "per_frame": False, "device": "cpu", "bootstrap_seed": 0, "bootstrap_n": 200,
    "runtime_sequences": 1, "runtime_repeats": 1, "physics_frames": 4, "iv_frames": 0,
    "figure_methods": [], "validity_sequences": 0, "viewer_sequences": 0,
    "seeds": [], "capture_noise": "none", "counterfactual_sources": 0,
    "counterfactual_methods": [],
}


def tiny_run_profile(path: Path, **overrides: object) -> Path:
    """Write a profile with ``[run]`` = :data:`TINY_RUN` updated by ``overrides`` to
    ``path``; returns ``path``."""
    run = {**TINY_RUN, **overrides}
    lines = ["[run]", *(f"{k} = {json.dumps(v)}" for k, v in run.items())]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
