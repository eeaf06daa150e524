"""``grip-bench predict``: run a trained method over sequences and write GRAB-layout files."""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..data.sequence import Sequence

DESCRIPTION = """\
Run METHOD (loaded from --checkpoint) on one SEQ.npz or on every sequence of a data
folder (optionally one --split) and write OUT/grab/s<k>/<name>.npz under the same
relative names, with the method's hands. The object meshes and splits.json are copied
so that `grip-bench evaluate` and `export` accept OUT; OUT/manifest.json records the
method, checkpoint hash, options and wall time per sequence.

--online streams frame by frame (each output frame uses only frames up to it; no
future-cue latency, lower accuracy). --no-anet keeps the input wrists. --refine refines
the input (perturbed) hands instead of generating them (GRIP Tab. 3). --precision sets
the arithmetic of GRIP's networks: auto (the default) runs bfloat16 where the hardware
does it natively (AVX512-BF16, AMX or Arm BF16 CPUs, bf16 GPUs: ~2-4x faster GEMMs, ~3
significant digits) and fp32 elsewhere; bf16 on a CPU that only emulates it is ~4x
slower than fp32 and warns. `grip-bench run` always uses fp32, as the tables do."""


def register(sub: argparse._SubParsersAction) -> None:
    from .meshopts import add_mesh_flags

    p = sub.add_parser(
        "predict",
        help="run a trained method and write its sequences",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example:\n  grip-bench predict --method grip --checkpoint ckpt/grip.pt "
        "--input synth/ --split test --out preds/grip",
    )
    p.add_argument("--method", required=True, help="method name (see `grip-bench ls methods`)")
    p.add_argument("--checkpoint", type=Path, default=None, metavar="CKPT",
                   help="checkpoint written by `grip-bench train`")
    p.add_argument("--input", type=Path, required=True, metavar="SEQ.npz|DIR")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output data folder")
    p.add_argument("--split", default="all", help="with a folder input: train, val, test or all")
    p.add_argument("--future-frames", type=int, default=None, metavar="N",
                   help="future-cue frames (must match the checkpoint; see grip-futureN)")
    p.add_argument("--no-anet", action="store_true", help="use the input wrists (no arm denoising)")
    p.add_argument("--online", action="store_true", help="frame-by-frame streaming mode")
    p.add_argument("--refine", action="store_true", help="refine the input hands (perturbed sets)")
    p.add_argument("--precision", default="auto", choices=("auto", "fp32", "bf16"),
                   help="arithmetic of GRIP's networks (default auto: bf16 where native)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    add_mesh_flags(p)
    p.set_defaults(func=run)


def _inputs(path: Path, split: str) -> tuple[Path, list[Path]]:
    """(data root, sequence files) of a file or folder input."""
    from ..core.errors import InputError
    from ..data.grab_io import data_root_of, list_sequences
    from ..data.splits import sequences_in_split

    if path.is_file():
        root = data_root_of(path)
        if root is None:
            raise InputError(
                "a single sequence must sit in a data folder (DATA/grab/s<k>/NAME.npz)", path
            )
        return root, [path]
    if not path.is_dir():
        raise InputError("no such file or folder", path)
    files = list_sequences(path) if split == "all" else sequences_in_split(path, split)
    if not files:
        raise InputError(f"no sequences (split {split!r})", path)
    return path, files


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def run(args: argparse.Namespace) -> int:
    from ..bench.stages.predict import predict_files
    from ..core.errors import InputError
    from ..data.library import ObjectLibrary
    from ..grip.frozen import resolve_precision
    from ..methods.api import PredictContext, load_all
    from .meshopts import check_meshes, mesh_options

    spec = load_all().get(args.method)
    if args.checkpoint is not None and not args.checkpoint.is_file():
        raise InputError("checkpoint file not found", args.checkpoint)
    root, files = _inputs(args.input, args.split)
    if args.out.resolve() == root.resolve():
        raise InputError("output folder must differ from the input folder", args.out)
    library = ObjectLibrary(root, mesh_options(args))
    meshes = check_meshes(library, files)  # bad meshes fail before any work
    args.precision_run, warning = resolve_precision(args.precision, args.device)
    if warning:
        print(f"warning: --precision: {warning}", file=sys.stderr)
    method = spec.build()
    method.load(args.checkpoint, args.device)
    ctx = PredictContext(library=library, device=args.device, seed=args.seed,
                         future_frames=args.future_frames, online=args.online,
                         refine=args.refine, use_anet=not args.no_anet,
                         precision=args.precision_run, data_dir=root, split=args.split)
    seconds = {}

    def done(seq: Sequence, secs: float) -> None:
        seconds[seq.name] = {"seconds": secs, "frames": seq.n_frames}

    # the runner's prediction stage does the same (one torch thread, meshes and splits)
    predict_files(method, files, root, args.out, ctx, progress=False, on_done=done)
    _write_manifest(args, root, seconds, meshes)
    total = sum(s["seconds"] for s in seconds.values())
    frames = sum(s["frames"] for s in seconds.values())
    print(f"wrote {len(files)} sequences to {args.out} ({total:.1f} s, "
          f"{1000 * total / max(frames, 1):.1f} ms/frame)")
    return 0


def _write_manifest(args: argparse.Namespace, root: Path, seconds: dict, meshes: dict) -> None:
    from ..core.io import atomic_write_text
    from ..core.version import __version__

    manifest = {
        "generator": "grip-bench predict", "suite_version": __version__, "method": args.method,
        "checkpoint": str(args.checkpoint) if args.checkpoint else None,
        "checkpoint_sha256": sha256(args.checkpoint) if args.checkpoint else None,
        "input": str(root.resolve()),
        "options": {"future_frames": args.future_frames, "no_anet": args.no_anet,
                    "online": args.online, "refine": args.refine, "precision": args.precision,
                    "precision_run": args.precision_run,
                    "split": args.split, "seed": args.seed, "device": args.device,
                    "mesh_scale": args.mesh_scale, "accept_repair_mm": args.accept_repair},
        "meshes": meshes,
        "sequences": seconds,
    }
    atomic_write_text(args.out / "manifest.json", json.dumps(manifest, indent=2) + "\n")
