"""``grip-bench data``: inspect and perturb GRAB-layout data.

Subcommands are registered by the functions decorated with :func:`data_command`;
adding one (e.g. ``synth``) is one decorated ``add_<name>(sub)`` function that creates
its parser and sets ``func``.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import InputError

if TYPE_CHECKING:
    from ..data.grab_io import ManoBackend

_COMMANDS = []


def data_command(
    fn: Callable[[argparse._SubParsersAction], None],
) -> Callable[[argparse._SubParsersAction], None]:
    """Register ``fn(subparsers)`` as a ``grip-bench data`` subcommand."""
    _COMMANDS.append(fn)
    return fn


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("data", help="inspect, perturb (and generate) GRAB-layout data",
                       description="Work with GRAB-layout datasets (DATA/grab/s<k>/*.npz).")
    inner = p.add_subparsers(dest="data_command", metavar="SUBCOMMAND")
    inner.required = True
    for add in _COMMANDS:
        add(inner)


def _mano(args: argparse.Namespace) -> ManoBackend | None:
    """MANO backend from ``--model-path`` (None without it)."""
    if not getattr(args, "model_path", None):
        return None
    from ..data.grab_io import load_mano_backend

    return load_mano_backend(args.model_path)


# --- info -------------------------------------------------------------------------
@data_command
def add_info(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="summarise a sequence file or a dataset folder",
                       description="A sequence .npz: frames, fps, subject, object, intent, "
                       "duration, contact frames (the file is fully read and validated). "
                       "A dataset folder: counts per split, object, intent and subject, and "
                       "(SynthGRAB, from manifest.json) grasp types per object family.")
    p.add_argument("path", type=Path, metavar="PATH", help="a .npz sequence or a data folder")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--model-path", help="MANO/SMPL-X models, to expand PCA hand poses (real GRAB)")
    p.set_defaults(func=run_info)


def sequence_info(path: Path, mano_backend: ManoBackend | None = None) -> dict:
    """Summary of one sequence file (fully read and validated)."""
    from ..data.grab_io import read_grab, read_grab_header

    hdr = read_grab_header(path)
    seq = read_grab(path, mano_backend=mano_backend)
    info = {
        "path": str(path), "name": seq.name, "subject": seq.sbj_id, "gender": seq.gender,
        "object": seq.obj_name, "intent": seq.motion_intent, "body_model": seq.body_model,
        "frames": seq.n_frames, "fps": seq.fps, "duration_s": round(seq.duration, 4),
        "source_frames": hdr["n_frames"], "source_fps": hdr["framerate"],
        "height_m": seq.height, "hand_scale": seq.hand_scale,
    }
    if "object" in seq.contact:
        info["contact_frames"] = {
            "any": int(seq.contact_frames().sum()),
            "right": int(seq.contact_frames("right").sum()),
            "left": int(seq.contact_frames("left").sum()),
        }
    return info


def dataset_info(data_dir: Path) -> dict:
    """Counts per split / object / intent / subject from file headers."""
    from ..data.grab_io import list_sequences, read_grab_header
    from ..data.splits import read_splits, split_of

    files = list_sequences(data_dir)
    if not files:
        raise InputError("no sequences under grab/s<k>/", data_dir)
    headers = [read_grab_header(p) for p in files]
    try:
        splits = read_splits(data_dir)
    except InputError:
        splits = None  # a real GRAB download has no splits.json
    frames = sum(math.ceil(h["n_frames"] / h["step"]) for h in headers)
    count = lambda key: dict(sorted(Counter(h[key] for h in headers).items()))  # noqa: E731
    info = {"path": str(data_dir), "sequences": len(files), "frames_30fps": frames,
            "duration_s": round(frames / 30.0, 2), "objects": count("obj_name"),
            "intents": count("motion_intent"), "subjects": count("sbj_id"),
            "body_models": count("body_model")}
    if splits is not None:
        split_counts = Counter(_safe_split(h["obj_name"], splits, split_of) for h in headers)
        info["splits"] = {s: split_counts.get(s, 0) for s in (*splits, "unassigned")
                          if s != "unassigned" or split_counts.get(s)}
    grasps = grasp_type_counts(data_dir, [p.relative_to(data_dir).as_posix() for p in files])
    if grasps:
        info["grasp_types"] = grasps
    return info


def grasp_type_counts(data_dir: Path, files: list[str]) -> dict[str, dict[str, int]]:
    """family -> grasp type -> grasps of that type (a regrasping hand's two both count), over
    the sequence ``files`` (paths relative to ``data_dir``) that a SynthGRAB
    ``manifest.json`` describes (its ``sequences`` member); empty without one (real GRAB,
    SynthGRAB v1)."""
    path = data_dir / "manifest.json"
    if not path.is_file():
        return {}
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"not a JSON manifest ({err})", path) from None
    seqs = manifest.get("sequences") if isinstance(manifest, dict) else None
    if not isinstance(seqs, dict):
        return {}
    out: dict[str, Counter] = {}
    for f in files:
        entry = seqs.get(f)
        if not isinstance(entry, dict) or not isinstance(entry.get("grasps"), dict):
            continue
        fam = out.setdefault(str(entry.get("family", "?")), Counter())
        fam.update(str(k) for k in entry["grasps"].values())
        if isinstance(entry.get("regrasp"), dict):  # the first grasp of a regrasp counts too
            fam.update(str(k) for k in entry["regrasp"].values())
    return {f: dict(sorted(c.items())) for f, c in sorted(out.items())}


def _safe_split(
    obj: str, splits: dict[str, list[str]], split_of: Callable[[str, dict], str]
) -> str:
    try:
        return split_of(obj, splits)
    except InputError:
        return "unassigned"


def _print_text(info: dict) -> None:
    width = max(len(k) for k in info)
    for key, value in info.items():
        if isinstance(value, dict) and value and all(isinstance(v, dict) for v in value.values()):
            print(key)  # a table: one row per entry (grasp types per family)
            inner = max(len(k) for k in value)
            for k, v in value.items():
                print(f"  {k:<{inner}}  " + ", ".join(f"{a} {b}" for a, b in v.items()))
            continue
        if isinstance(value, dict):
            value = ", ".join(f"{k} {v}" for k, v in value.items())
        print(f"{key:<{width}}  {value}")


def run_info(args: argparse.Namespace) -> int:
    path: Path = args.path
    if path.is_dir():
        info = dataset_info(path)
    elif path.is_file():
        info = sequence_info(path, _mano(args))
    else:
        raise InputError("no such file or folder", path)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        _print_text(info)
    return 0


# --- perturb --------------------------------------------------------------------------
@data_command
def add_perturb(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "perturb", help="write a noisy copy of a split (TOCH GRAB-T / GRAB-R, ANet arm noise)",
        description="Per-frame i.i.d. Gaussian noise, seeded. --kind T: hand translation "
        "(TOCH sigma 0.01, 0.02 m); R: every finger joint's axis-angle (0.3, 0.5 rad); "
        "arm: shoulders and elbows (default 0.01,0.03 rad). Writes the GRAB layout, meshes, "
        "splits.json and manifest.json to --out (which must be new or empty).")
    p.add_argument("input", type=Path, metavar="IN", help="data folder (DATA/grab/...)")
    p.add_argument("--out", type=Path, required=True, help="output data folder")
    p.add_argument("--kind", choices=("T", "R", "arm"), required=True)
    p.add_argument("--sigma", help="noise sigma (m for T, rad for R); for arm "
                   "'SHOULDER,ELBOW' or one value (default 0.01,0.03)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--split", default="test", choices=("train", "val", "test", "all"),
                   help="which split to perturb (default test)")
    p.add_argument("--model-path", help="MANO/SMPL-X models, to expand PCA hand poses (real GRAB)")
    p.set_defaults(func=run_perturb)


def _parse_sigma(text: str | None, kind: str) -> float | tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"not a number or NUMBER,NUMBER: {text!r}", "--sigma") from None
    if len(values) == 1:
        return values[0]
    if kind == "arm" and len(values) == 2:
        return tuple(values)
    raise InputError(
        f"expected one number{' or SHOULDER,ELBOW' if kind == 'arm' else ''}: {text!r}", "--sigma"
    )


def run_perturb(args: argparse.Namespace) -> int:
    from ..data.perturb import perturb_dataset

    if not args.input.is_dir():
        raise InputError("no such data folder", args.input)
    sigma = _parse_sigma(args.sigma, args.kind)
    manifest = perturb_dataset(args.input, args.out, args.kind, sigma, args.seed, args.split,
                               mano_backend=_mano(args))
    info = json.loads(manifest.read_text(encoding="utf-8"))
    print(f"wrote {info['n_sequences']} {info['protocol']} sequences (sigma {info['sigma']} "
          f"{info['sigma_unit']}, seed {info['seed']}) to {args.out}")
    return 0


# --- synth ------------------------------------------------------------------------------
@data_command
def add_synth(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "synth", help="generate SynthGRAB, the built-in GRAB-like dataset",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Generate SynthGRAB: whole-body reach-and-grasp sequences (lift, pass, use, "
        "off-hand pass) of a procedural body and hands with procedural household objects on a "
        "table, written in GRAB's layout (grab/s<k>/<object>_<intent>_<n>.npz, object meshes, "
        "splits.json with held-out objects and families, manifest.json). Prints a quality "
        "report (grasp frames, penetration, per-finger contact frequencies beside GRAB's).",
        epilog="profiles (time on 2 cores):\n"
        "  smoke     ~20 sequences, under a minute\n"
        "  default  ~300 sequences, about 3-6 minutes\n"
        "  large   ~1300 sequences, about 15-25 minutes (estimated)\n"
        "The same --seed gives the same arrays whatever the number of workers.")
    p.add_argument("--out", type=Path, required=True, help="output data folder (created)")
    p.add_argument("--profile", default="smoke", choices=("smoke", "default", "large", "tiny"),
                   help="dataset size (default smoke; 'tiny' = 3 sequences, for tests)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: all CPU cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or report")
    p.set_defaults(func=run_synth)


def run_synth(args: argparse.Namespace) -> int:
    from ..data.synth.generate import generate

    if args.workers is not None and args.workers < 1:
        raise InputError(f"must be at least 1, got {args.workers}", "--workers")
    if args.out.exists() and not args.out.is_dir():
        raise InputError("exists and is not a folder", args.out)
    manifest = generate(args.out, args.profile, args.seed, args.workers, progress=not args.quiet)
    c = manifest["counts"]
    print(f"wrote {c['sequences']} sequences ({c['failed']} failed) to {args.out}")
    return 0
