"""Perturbed test sets: TOCH's GRAB-T / GRAB-R protocol and GRIP's ANet arm noise.

All noise is per frame, i.i.d. Gaussian, drawn from a seeded ``np.random.Generator``
(same seed -> same bits). Fields changed by each kind (nothing else is touched):

====== =================================================================== ==============
kind   fields                                                              sigma
====== =================================================================== ==============
``T``  ``rhand.params.transl``, ``lhand.params.transl`` (GRAB-T)             0.01, 0.02 m
``R``  ``rhand/lhand.params.hand_pose`` and the finger part of their         0.3, 0.5 rad
       ``fullpose``; the same noise on ``body.params.right/left_hand_pose``
       and their slice of ``body.params.fullpose`` (GRAB-R)
``arm`` ``body.params.body_pose`` entries of both shoulders (0.01 rad) and   ANet defaults
       elbows (0.03 rad), and the same joints in ``body.params.fullpose``
====== =================================================================== ==============

GRAB-R here perturbs the **full axis-angle** rotation of each of the 15 finger joints of
both hands (each component gets ``N(0, sigma^2)``). TOCH's public code instead adds the
noise to the MANO PCA coefficients. We perturb axis-angle because (1) the procedural
hand has no PCA space, so a PCA protocol would not exist for SynthGRAB; (2) a per-joint
sigma in radians has a direct, model-independent meaning; (3) PCA noise concentrates in
the few leading components (the low-variance tail of MANO's 45-D space gets almost
none), so the same sigma would mean different perturbations on different hand models.
Numbers are therefore comparable in shape, not value, with TOCH's Table.

The body's hand poses receive the same noise as the MANO hands so that no clean copy of
the perturbed hand remains in the file for a method to read.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zlib
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..bodies.layouts import SMPLX_INDEX
from ..core import constants as C
from ..core.errors import InputError
from ..core.version import __version__
from .grab_io import (
    ManoBackend,
    dataset_hash,
    list_sequences,
    object_mesh_relpath,
    read_grab,
    resolve_object_mesh,
    write_grab,
)
from .sequence import Sequence
from .splits import read_splits, sequences_in_split, write_splits

KINDS = ("T", "R", "arm")
PROTOCOL = {"T": "GRAB-T", "R": "GRAB-R", "arm": "ANet-arm"}
DEFAULT_SIGMA = {"T": C.TOCH_T_SIGMAS[0], "R": C.TOCH_R_SIGMAS[0],
                 "arm": (C.ANET_SHOULDER_SIGMA, C.ANET_ELBOW_SIGMA)}
ARM_JOINTS = {
    "shoulder": ("left_shoulder", "right_shoulder"),
    "elbow": ("left_elbow", "right_elbow"),
}
# SMPL-X fullpose column of the left / right hand's 45 finger values.
_BODY_FULLPOSE_HAND = {"left": 25 * 3, "right": 40 * 3}


def _arm_sigmas(sigma: float | Iterable[float] | None) -> tuple[float, float]:
    """(shoulder, elbow) sigmas from None (ANet's), a number (both) or a pair."""
    if sigma is None:
        return DEFAULT_SIGMA["arm"]
    if isinstance(sigma, int | float):
        return float(sigma), float(sigma)
    s = tuple(float(x) for x in sigma)
    if len(s) != 2:
        raise InputError("arm sigma should be one number or (shoulder, elbow)", "sigma")
    return s


def _check_sigma(values: float | tuple[float, ...]) -> None:
    for s in np.atleast_1d(values):
        if not np.isfinite(s) or s < 0:
            raise InputError(f"noise sigma must be a finite number >= 0, got {s}", "sigma")


def resolve_sigma(
    kind: str, sigma: float | Iterable[float] | None = None
) -> float | tuple[float, float]:
    """Checked sigma for ``kind``: a float for T (m) and R (rad), (shoulder, elbow) for arm."""
    if kind not in KINDS:
        raise InputError(f"unknown perturbation kind {kind!r} (allowed: {list(KINDS)})", "kind")
    if kind == "arm":
        sig = _arm_sigmas(sigma)
    elif sigma is None:
        raise InputError(f"kind {kind!r} needs a sigma ({PROTOCOL[kind]} uses "
                         f"{C.TOCH_T_SIGMAS if kind == 'T' else C.TOCH_R_SIGMAS})", "sigma")
    else:
        sig = float(sigma)
    _check_sigma(sig)
    return sig


def _noisy(a: np.ndarray, rng: np.random.Generator, sigma: float) -> np.ndarray:
    """``a + N(0, sigma^2)`` per entry, drawn in float64, returned in ``a``'s dtype."""
    return _add(a, rng.normal(0.0, 1.0, size=a.shape) * sigma)


def _add(a: np.ndarray, noise: np.ndarray) -> np.ndarray:
    return (a + noise).astype(a.dtype)


def _perturb_translation(seq: Sequence, sigma: float, rng: np.random.Generator) -> dict:
    return {part: {**getattr(seq, part), "transl": _noisy(getattr(seq, part)["transl"], rng, sigma)}
            for part in ("rhand", "lhand")}


def _perturb_hand_pose(seq: Sequence, sigma: float, rng: np.random.Generator) -> dict:
    out = {"body": dict(seq.body)}
    body_full = seq.body["fullpose"].copy()
    for side, part in (("right", "rhand"), ("left", "lhand")):
        hand = getattr(seq, part)
        noise = rng.normal(0.0, 1.0, size=hand["hand_pose"].shape) * sigma
        full = hand["fullpose"].copy()
        full[:, 3:] = _add(full[:, 3:], noise)
        out[part] = {**hand, "hand_pose": _add(hand["hand_pose"], noise), "fullpose": full}
        key = f"{side}_hand_pose"
        out["body"][key] = _add(seq.body[key], noise)
        c = _BODY_FULLPOSE_HAND[side]
        body_full[:, c:c + 45] = _add(body_full[:, c:c + 45], noise)
    out["body"]["fullpose"] = body_full
    return out


def _perturb_arm(
    seq: Sequence, sigmas: tuple[float, float], rng: np.random.Generator
) -> dict:
    body_pose = seq.body["body_pose"].copy()
    full = seq.body["fullpose"].copy()
    joints = [*ARM_JOINTS["shoulder"], *ARM_JOINTS["elbow"]]
    scale = np.repeat(np.array([sigmas[0]] * 2 + [sigmas[1]] * 2), 3)  # (12,) per column
    noise = rng.normal(0.0, 1.0, size=(seq.n_frames, 12)) * scale
    for i, name in enumerate(joints):
        j = SMPLX_INDEX[name]  # body_pose covers joints 1..21
        n = noise[:, 3 * i:3 * i + 3]
        body_pose[:, 3 * (j - 1) : 3 * j] = (body_pose[:, 3 * (j - 1) : 3 * j] + n).astype(
            body_pose.dtype
        )
        full[:, 3 * j:3 * j + 3] = (full[:, 3 * j:3 * j + 3] + n).astype(full.dtype)
    return {"body": {**seq.body, "body_pose": body_pose, "fullpose": full}}


def perturb_sequence(seq: Sequence, kind: str, sigma: float | Iterable[float] | None = None,
                     rng: np.random.Generator | int | None = None) -> Sequence:
    """A perturbed copy of ``seq`` (see the module table). The input is not modified.

    ``kind``: ``"T"`` (sigma in m), ``"R"`` (sigma in rad), ``"arm"`` (sigma None for
    ANet's (0.01, 0.03) rad, a number for both, or (shoulder, elbow)). ``rng``: a
    ``np.random.Generator`` or an int seed (required: noise is never unseeded).
    """
    if rng is None:
        raise InputError(
            "a seed or np.random.Generator is required (noise is always seeded)", "rng"
        )
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    sig = resolve_sigma(kind, sigma)
    change = {"T": _perturb_translation, "R": _perturb_hand_pose, "arm": _perturb_arm}[kind]
    return replace(seq, **change(seq, sig, rng))


def sequence_rng(seed: int, name: str) -> np.random.Generator:
    """Generator for one sequence: seeded by ``seed`` and the sequence name, so each file's
    noise does not depend on which other files are perturbed or in what order."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(name.encode())]))


def _copy_meshes(seq: Sequence, in_dir: Path, tmp: Path) -> None:
    """Copy the object mesh (required) and any subject/table meshes the file names."""
    src = resolve_object_mesh(seq, in_dir)
    rel = seq.object_mesh if seq.object_mesh and not Path(seq.object_mesh).is_absolute() \
        else object_mesh_relpath(seq.obj_name)
    _copy(src, tmp / rel)
    for rel in (seq.table_mesh, seq.body_vtemp, seq.rhand_vtemp, seq.lhand_vtemp):
        if rel and not Path(rel).is_absolute() and (in_dir / rel).is_file():
            _copy(in_dir / rel, tmp / rel)


def _copy(src: Path, dst: Path) -> None:
    if not dst.exists():
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)


def _select(in_dir: Path, split: str | None) -> tuple[list[Path], dict]:
    splits = read_splits(in_dir, default="grip")
    files = (
        list_sequences(in_dir)
        if split in (None, "all")
        else sequences_in_split(in_dir, split, splits)
    )
    if not files:
        raise InputError(f"no sequences in split {split!r}", in_dir)
    return files, splits


def _prepare_out(in_dir: Path, out_dir: Path) -> Path:
    """A fresh temp folder beside ``out_dir`` (renamed onto it at the end, so a failure
    leaves ``out_dir`` untouched)."""
    if out_dir.resolve() == in_dir.resolve():
        raise InputError("output folder must differ from the input folder", out_dir)
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise InputError("exists and is not an empty folder; refusing to overwrite", out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(dir=out_dir.parent, prefix=f".{out_dir.name}.tmp-"))


def perturb_dataset(in_dir: str | os.PathLike, out_dir: str | os.PathLike, kind: str,
                    sigma: float | Iterable[float] | None = None, seed: int = 0,
                    split: str | None = "test", *,
                    mano_backend: ManoBackend | None = None,
                    source: str | None = None) -> Path:
    """Write a perturbed copy of one split of ``in_dir`` to ``out_dir`` (GRAB layout).

    Writes ``grab/s<k>/*.npz`` (30 fps, full axis-angle), the object (and any subject /
    table) meshes, ``splits.json`` and ``manifest.json`` (kind, sigma, seed, split, source
    hash, sequences). ``split=None`` or ``"all"`` perturbs every sequence. Returns the
    manifest path. Without ``DATA/splits.json`` the GRIP split of real GRAB is used.
    ``source``: how the manifest names the input (default: its absolute path; a run names
    its dataset unit, so that a unit's bytes do not depend on where its cache lies).
    """
    in_dir, out_dir = Path(in_dir), Path(out_dir)
    resolve_sigma(kind, sigma)
    files, splits = _select(in_dir, split)
    tmp = _prepare_out(in_dir, out_dir)
    try:
        names = []
        for path in files:
            seq = read_grab(path, mano_backend=mano_backend)
            noisy = perturb_sequence(seq, kind, sigma, sequence_rng(seed, seq.name))
            write_grab(noisy, tmp / path.relative_to(in_dir))
            _copy_meshes(seq, in_dir, tmp)
            names.append(seq.name)
        write_splits(tmp, splits)
        manifest = _manifest(in_dir, kind, sigma, seed, split, names, source)
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
        if out_dir.exists():
            out_dir.rmdir()  # empty (checked above); rename cannot replace it portably
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out_dir / "manifest.json"


def _manifest(
    in_dir: Path,
    kind: str,
    sigma: float | Iterable[float] | None,
    seed: int,
    split: str | None,
    names: list[str],
    source: str | None = None,
) -> dict:
    sig = resolve_sigma(kind, sigma)
    return {
        "generator": "grip_bench.data.perturb", "suite_version": __version__,
        "protocol": PROTOCOL[kind], "kind": kind,
        "sigma": list(sig) if isinstance(sig, tuple) else sig,
        "sigma_unit": "m" if kind == "T" else "rad", "seed": int(seed), "split": split,
        "noise": "per-frame i.i.d. Gaussian; per-sequence generator from (seed, crc32(name))",
        "source": source or str(in_dir.resolve()), "source_hash": dataset_hash(in_dir),
        "n_sequences": len(names), "sequences": names,
    }
