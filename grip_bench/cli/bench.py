"""``grip-bench bench``: hardware floors, then each stage against them (docs/performance.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

DESCRIPTION = """\
Measure this machine's floors first (sgemm fp32/bf16 GFLOP/s at GRIP's GEMM shapes and a
square size, fp32 GEMV bandwidth, one exact signed-distance query, one manifold3d boolean),
then each stage (GRIP offline and online, the sensors, exact IV, physics tests), and print
stage | time | floor | ratio | goal | met?, then where GRIP's time goes (ANet's recursion,
the stage-one inputs, CNet, RNet, the rest; each network part against its own FLOP floor).
The machine's absolute speed moves from run to run, so goals are ratios to floors measured
in the same run. Writes OUT/bench.json (with a manifest: versions, CPU model and flags, git
revision) and OUT/bench.md; progress on stderr."""


def _parts(text: str) -> tuple[str, ...]:
    from ..bench.perf import PARTS

    parts = tuple(p.strip() for p in text.split(",") if p.strip())
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise argparse.ArgumentTypeError(
            f"unknown part(s) {', '.join(bad) or '(none)'} (choose from {', '.join(PARTS)})")
    return parts


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="measure hardware floors, then each stage against them",
                       description=DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true",
                   help="a fast pass: 2 repeats, smaller workloads, shorter samples")
    p.add_argument("--out", type=Path, default=Path("bench"), metavar="DIR",
                   help="output folder for bench.json and bench.md (default ./bench)")
    p.add_argument("--threads", type=int, default=None, metavar="N",
                   help="torch intra-op threads (default: the cores this process may use)")
    p.add_argument("--repeats", type=int, default=None, metavar="N",
                   help="samples per measurement, median reported (default 5, --quick 2)")
    p.add_argument("--only", type=_parts, default=None, metavar="PARTS",
                   help="comma-separated subset of floors,grip,sensors,iv,physics (default all)")
    p.add_argument("--data", type=Path, default=None, metavar="DIR",
                   help="a GRAB-layout folder (e.g. the default run's data): the physics part "
                        "also times the articulated hold test on tested frames of its split, "
                        "the measure of issue #15's goal of 20 tests/s a core")
    p.add_argument("--split", default="test", choices=("train", "val", "test"),
                   help="the split of --data to time (default test)")
    p.add_argument("--model-path", default=None, metavar="DIR",
                   help="MANO / SMPL-X model folder, for real GRAB data with --data")
    p.set_defaults(func=run)


def header(result: dict) -> str:
    """CPU model, flags, threads and load average of a result, as markdown lines."""
    cpu = result["cpu"]
    s = result["settings"]
    la0 = ", ".join(f"{x:.2f}" for x in result["loadavg_before"])
    la1 = ", ".join(f"{x:.2f}" for x in result["loadavg_after"])
    return "\n".join([
        f"- CPU: {cpu['model']} ({result['cpu_count']} logical cores); flags: "
        f"{' '.join(cpu['flags']) or '-'}; native bf16: {'yes' if cpu['native_bf16'] else 'no'}",
        f"- torch threads: {s['threads']}; repeats: {s['repeats']} (median, ±half the "
        f"max-min spread){'; quick' if s['quick'] else ''}",
        f"- load average (1, 5, 15 min): before {la0}; after {la1} (other processes share the "
        "cores: a load above the core count slows every figure)",
        f"- numerics: {numerics_line(result['manifest'].get('numerics'))}",
        f"- wall time: {result['wall_s']:.0f} s; git {result['manifest']['git']['revision']}",
    ])


def numerics_line(state: dict | None) -> str:
    """The kernels the figures ran on (``core/numerics.py``): pinned kernels are slower on
    processors with wider ones, so a figure means little without them."""
    if not state:
        return "not recorded"
    kernels = (f"numpy AVX-512 targets {', '.join(state['numpy_avx512']) or 'off'}; "
               f"OpenBLAS {state.get('openblas_core') or '?'}; "
               f"torch {state.get('torch_capability') or '?'}; "
               f"MKL_CBWR {state['pins'].get('MKL_CBWR') or 'unset'}")
    return f"{state['mode']} ({kernels})"


def markdown(result: dict) -> str:
    """bench.md: the header, the floors table, the stages table and, when measured, where
    GRIP's time goes (each part against its own network's FLOP floor)."""
    md = (f"# grip-bench bench\n\n{header(result)}\n\n## Floors\n\n"
          f"{result['tables']['floors']}\n\n## Stages\n\n{result['tables']['stages']}\n")
    if result["tables"].get("parts"):
        md += (f"\n## Where GRIP's time goes\n\nOne timed call per row, split over the "
               f"pipeline's parts; a part's floor is its network's FLOPs at the row's sgemm "
               f"rate.\n\n{result['tables']['parts']}\n")
    return md


def run(args: argparse.Namespace) -> int:
    import json
    import os

    from ..bench.perf import PARTS, Settings, run_bench
    from ..core.cpu import cpu_info
    from ..core.errors import InputError
    from ..core.io import atomic_write_text, jsonable
    from ..results.manifest import build_manifest

    if args.threads is not None and args.threads < 1:
        raise InputError("must be at least 1", "--threads")
    if args.repeats is not None and args.repeats < 1:
        raise InputError("must be at least 1", "--repeats")
    if args.data is not None and not (args.data / "splits.json").is_file():
        raise InputError("not a GRAB-layout folder (no splits.json)", str(args.data))
    settings = Settings.make(args.quick, args.repeats, args.threads,
                             None if args.data is None else str(args.data), args.split,
                             args.model_path)
    result = run_bench(settings, args.only or PARTS)
    result["cpu"] = cpu_info().as_dict()
    result["cpu_count"] = os.cpu_count()
    result["manifest"] = build_manifest({"name": "bench"}, result["settings"],
                                        {"scene": 0, "weights": 0}, "",
                                        {"bench": result["wall_s"]})
    args.out.mkdir(parents=True, exist_ok=True)
    text = json.dumps(jsonable(result), indent=2, sort_keys=True, allow_nan=False) + "\n"
    atomic_write_text(args.out / "bench.json", text)
    md = markdown(result)
    atomic_write_text(args.out / "bench.md", md)
    print(md)
    print(f"wrote {args.out / 'bench.json'} and {args.out / 'bench.md'}")
    return 0
