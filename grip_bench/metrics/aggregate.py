"""Evaluate a folder of predictions against a ground-truth dataset (``grip-bench evaluate``).

Sequences are matched by their path relative to the data folder (``grab/s1/mug_lift_1.npz``).
Every GT sequence of the evaluated split needs a prediction, every prediction a GT sequence,
with equal frame counts and the same object: all of this is checked from file headers before
anything is computed or written. Sequences then run over a process pool (spawn-safe, one
:class:`ObjectLibrary` and one torch thread per worker); rows are sorted canonically, so the
files are byte-identical for any number of workers.

Writes (atomically) ``results.csv``, ``frames.csv`` with ``per_frame`` and ``evaluation.json``;
with ``contact_stats`` also ``contact_stats.npz`` (figure data, :func:`pool_contact_stats`).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core import constants as C
from ..core.errors import InputError
from .evaluate import EvalOptions, RowLabels

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    from ..data.library import ObjectLibrary

ALL_SPLITS = "all"


@dataclass(frozen=True)
class Task:
    """One (prediction, ground truth) file pair to evaluate."""

    pred: str
    gt: str
    labels: RowLabels
    options: EvalOptions
    per_frame: bool
    contact_stats: bool = False


# ------------------------------------------------------------------ labels
def _manifest(data_dir: Path) -> dict:
    path = data_dir / "manifest.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"not readable JSON ({e})", path) from e
    return data if isinstance(data, dict) else {}


def dataset_name(gt_dir: Path, manifest: dict) -> str:
    """``dataset`` (or the generator's name, e.g. "synthgrab") from the GT manifest, else the
    folder's name."""
    name = manifest.get("dataset") or manifest.get("generator")
    if isinstance(name, dict):
        name = name.get("name")
    if isinstance(name, str) and name.strip():
        return name.strip().split()[0].lower()
    return gt_dir.resolve().name


def perturbation_name(manifest: dict) -> str:
    """``perturbation`` of the prediction folder's manifest ("T0.01"), or one derived from a
    ``grip-bench data perturb`` manifest (kind + sigma), else "none"."""
    name = manifest.get("perturbation")
    if isinstance(name, str) and name:
        return name
    kind, sigma = manifest.get("kind"), manifest.get("sigma")
    if isinstance(kind, str) and sigma is not None:
        sig = ",".join(f"{s:g}" for s in sigma) if isinstance(sigma, list) else f"{sigma:g}"
        return f"{kind}{sig}"
    return "none"


# ------------------------------------------------------------------ matching
def _listing(paths: list[str], n: int = C.EVAL_MAX_LISTED) -> str:
    more = f" (and {len(paths) - n} more)" if len(paths) > n else ""
    return ", ".join(paths[:n]) + more


def gt_sequences(gt_dir: Path, split: str) -> tuple[dict[str, dict], str]:
    """GT headers by relative path for ``split`` ("all": every sequence) and the split name."""
    from ..data.grab_io import list_sequences, read_grab_header
    from ..data.splits import SPLIT_NAMES, read_splits

    if split != ALL_SPLITS and split not in SPLIT_NAMES:
        raise InputError(
            f"unknown split {split!r} (allowed: {', '.join(SPLIT_NAMES)}, all)", "--split"
        )
    headers = {
        p.relative_to(gt_dir).as_posix(): read_grab_header(p) for p in list_sequences(gt_dir)
    }
    if split == ALL_SPLITS:
        return headers, split
    wanted = set(read_splits(gt_dir, default="grip")[split])
    return {k: h for k, h in headers.items() if h["obj_name"] in wanted}, split


def match_sequences(
    pred_dir: Path, gt_dir: Path, split: str
) -> tuple[list[tuple[str, dict, dict]], int]:
    """Matched (relative path, pred header, GT header) triples, sorted, and the number of
    predictions ignored because their GT sequence belongs to another split.

    Raises :class:`InputError` (nothing computed yet) on missing or extra sequences, different
    frame counts or different objects.
    """
    from ..data.grab_io import list_sequences, read_grab_header

    gt, split = gt_sequences(gt_dir, split)
    if not gt:
        raise InputError(f"no ground-truth sequences in split '{split}'", gt_dir)
    all_gt = {p.relative_to(gt_dir).as_posix() for p in list_sequences(gt_dir)}
    pred_paths = {p.relative_to(pred_dir).as_posix(): p for p in list_sequences(pred_dir)}
    missing = sorted(set(gt) - set(pred_paths))
    if missing:
        raise InputError(f"{len(missing)} ground-truth sequence(s) of split '{split}' have no "
                         f"prediction: {_listing(missing)}", pred_dir)
    extra = sorted(set(pred_paths) - all_gt)
    if extra:
        raise InputError(f"{len(extra)} prediction(s) have no ground-truth sequence in {gt_dir}: "
                         f"{_listing(extra)}", pred_dir)
    pairs = []
    for rel in sorted(gt):
        ph = read_grab_header(pred_paths[rel])
        _check_headers(pred_paths[rel], ph, gt_dir / rel, gt[rel])
        pairs.append((rel, ph, gt[rel]))
    return pairs, len(pred_paths) - len(pairs)


def _frames_30fps(h: dict) -> int:
    return math.ceil(h["n_frames"] / h["step"]) if "step" in h else h["n_frames"]


def _check_headers(pred_path: Path, ph: dict, gt_path: Path, gh: dict) -> None:
    """A prediction must be of the ground truth's take: same object, subject, intent and
    length (a prediction of another subject's take would be scored against wrong hands), and
    of the same body model (a prediction is posed with the ground truth's hand model, so
    hand parameters of another model would be read in the wrong convention)."""
    for key, what in (("obj_name", "object"), ("sbj_id", "subject"),
                      ("motion_intent", "intent"), ("body_model", "body model")):
        if ph[key] != gh[key]:
            raise InputError(f"{what} '{ph[key]}', but the ground truth {gt_path} has "
                             f"'{gh[key]}'", pred_path)
    np_, ng = _frames_30fps(ph), _frames_30fps(gh)
    if np_ != ng:
        raise InputError(f"{np_} frames, but the ground truth {gt_path} has {ng}", pred_path)


# ------------------------------------------------------------------ workers
_LIBRARY = None


def _init_worker(gt_dir: str, mesh_options=None) -> None:
    """One torch thread and one object library for this process's tasks."""
    import torch

    from ..data.library import ObjectLibrary

    global _LIBRARY
    torch.set_num_threads(1)
    _LIBRARY = ObjectLibrary(gt_dir, mesh_options)


def _init_pool_worker(gt_dir: str, mesh_options=None) -> None:
    """Process-pool initializer: :func:`_init_worker`, and the worker exits when the process
    that started it dies (``core.procs``: a kept pool's idle workers would otherwise outlive
    a run killed outright). Never in the calling process: that one may outlive its shell."""
    from ..core.procs import exit_with_parent

    exit_with_parent()
    _init_worker(gt_dir, mesh_options)


def run_task(task: Task) -> tuple:
    """Evaluate one pair in this process: (rows, frame rows, failure counts by reason), plus
    ``{side: contact_stats}`` as a fourth item when ``task.contact_stats``."""
    from ..data.grab_io import read_grab
    from .evaluate import evaluate_sequence
    from .intersection import FailureCounter

    failures = FailureCounter()
    pred, gt = read_grab(task.pred), read_grab(task.gt)
    stats: dict | None = {} if task.contact_stats else None
    rows, frames = evaluate_sequence(pred, gt, _LIBRARY, per_frame=task.per_frame,
                                     options=task.options, labels=task.labels, failures=failures,
                                     stats=stats, gt_cache=True)
    if stats is not None:
        return rows, frames, dict(failures.reasons), stats
    return rows, frames, dict(failures.reasons)


def _progress(total: int, enabled: bool, desc: str = "evaluate", unit: str = "seq") -> tqdm:
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, leave=False)


def worker_library() -> ObjectLibrary:
    """The object library of this process's evaluation worker (set by the pool initializer,
    or in-process by :func:`map_tasks` with one worker)."""
    if _LIBRARY is None:
        raise RuntimeError("not inside an evaluation worker (metrics.aggregate.map_tasks)")
    return _LIBRARY


def run_tasks(tasks: list[Task], gt_dir: Path, workers: int, progress: bool,
              mesh_options=None) -> list[tuple]:
    """Results of ``tasks`` in task order; ``workers`` > 1 uses a spawn process pool."""
    return map_tasks(run_task, tasks, gt_dir, workers, progress, mesh_options)


def map_tasks(fn: Callable[[Any], Any], tasks: list, gt_dir: Path, workers: int,
              progress: bool, mesh_options=None, desc: str = "evaluate",
              unit: str = "seq") -> list:
    """``[fn(t) for t in tasks]`` in task order, ``fn`` a module-level function that reads
    the objects through :func:`worker_library`; ``workers`` > 1 runs them in the kept spawn
    pool of ``gt_dir`` (:func:`worker_pool`). Both paths run torch on one thread, so the
    values do not depend on ``workers``."""
    import torch

    results: list = [None] * len(tasks)
    bar = _progress(len(tasks), progress, desc, unit)
    if workers <= 1 or len(tasks) <= 1:
        threads = torch.get_num_threads()
        try:  # one thread, as in the workers: the same floating-point path for any --workers
            _init_worker(str(gt_dir), mesh_options)
            for i, task in enumerate(tasks):
                results[i] = fn(task)
                bar.update()
        finally:
            torch.set_num_threads(threads)
            bar.close()
        return results
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    pool = worker_pool(workers, gt_dir, mesh_options)
    futures = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
    try:
        for fut in as_completed(futures):
            results[futures[fut]] = fut.result()
            bar.update()
    except BaseException as e:
        for fut in futures:
            fut.cancel()
        if isinstance(e, BrokenProcessPool) or not isinstance(e, Exception):
            close_pools()  # a dead worker or an interrupt: never reuse this pool
        raise
    finally:
        bar.close()
    return results


# One spawn pool per (workers, ground-truth folder), kept for the life of the process: a
# run evaluates dozens of prediction sets against the same ground truth, and a fresh pool
# per set would pay the workers' start-up (imports) and their object caches every time.
_POOLS: dict = {}


def worker_pool(workers: int, gt_dir: Path, mesh_options=None) -> ProcessPoolExecutor:
    """The process pool for ``gt_dir`` (created on first use; others are shut down)."""
    import atexit
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    key = (int(workers), str(Path(gt_dir).resolve()), mesh_options)
    if key not in _POOLS:
        if not _POOLS:
            atexit.register(close_pools)
        close_pools()
        _POOLS[key] = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                          initializer=_init_pool_worker,
                                          initargs=(str(gt_dir), mesh_options))
    return _POOLS[key]


def close_pools() -> None:
    """Shut down the kept worker pools (at exit, or after a failure)."""
    while _POOLS:
        _POOLS.popitem()[1].shutdown(wait=True, cancel_futures=True)


# ------------------------------------------------------------------ entry point
def evaluate_dirs(pred_dir: str | os.PathLike, gt_dir: str | os.PathLike,
                  out_dir: str | os.PathLike, *, method: str = "method",
                  metrics: Iterable[str] | None = None,
                  per_frame: bool = False, workers: int = 1, progress: bool = False,
                  split: str = "test", options: EvalOptions | None = None,
                  contact_stats: bool = False, mesh_options=None,
                  mesh_reports: dict | None = None) -> dict:
    """Evaluate every prediction of ``pred_dir`` against ``gt_dir``; write to ``out_dir``.

    metrics: ids (None: all registered); workers: processes; split: GT split ("all" for
    every sequence); contact_stats: also write ``contact_stats.npz`` (figure data of the
    set, :func:`pool_contact_stats`). Returns the ``evaluation.json`` content. Nothing is
    written when the folders do not match (:class:`InputError`).
    """
    start = time.perf_counter()
    pred_dir, gt_dir, out_dir = Path(pred_dir), Path(gt_dir), Path(out_dir)
    options = options or EvalOptions()
    if metrics is not None:
        options = EvalOptions(**{**asdict(options), "metrics": tuple(metrics)})
    options.metric_ids()  # unknown ids fail before any work
    pairs, ignored = match_sequences(pred_dir, gt_dir, split)
    pred_manifest = _manifest(pred_dir)
    labels = RowLabels(method, dataset_name(gt_dir, _manifest(gt_dir)), split,
                       perturbation_name(pred_manifest))
    tasks = [Task(str(pred_dir / rel), str(gt_dir / rel), labels, options, per_frame,
                  contact_stats) for rel, _, _ in pairs]
    results = run_tasks(tasks, gt_dir, max(1, int(workers)), progress, mesh_options)
    stats = [r[3] for r in results if len(r) > 3]
    results = [tuple(r[:3]) for r in results]
    info = _summary(labels, options, pred_dir, gt_dir, pred_manifest, results, ignored)
    info["wall_time_s"] = round(time.perf_counter() - start, 3)
    if mesh_reports is not None:  # object meshes as taken in (geometry.repair.MeshOptions)
        info["meshes"] = {"options": mesh_options and mesh_options.as_dict(), **mesh_reports}
    _write_outputs(out_dir, results, per_frame, info)
    if contact_stats:
        try:
            write_npz(out_dir / CONTACT_STATS_FILE, pool_contact_stats(stats, options.sides))
        except ValueError:  # mixed hand models: no figure data, the metrics stand
            pass
    return info


def _physics_subsampling(options: EvalOptions) -> str:
    """The manifest's line on the physics frames (``metrics.evaluate.physics_frames``)."""
    sim = options.max_physics_frames if options.max_sim_frames is None else min(
        options.max_sim_frames, options.max_physics_frames)
    return (f"physics tests on at most {options.max_physics_frames} held frames per sequence "
            f"and hand, drawn with seed {options.physics_seed}; the support test and the "
            f"articulated test's variants on at most {sim} of them")


def _summary(
    labels: RowLabels,
    options: EvalOptions,
    pred_dir: Path,
    gt_dir: Path,
    pred_manifest: dict,
    results: list[tuple],
    ignored: int,
) -> dict:
    from ..core.version import __version__
    from ..data.grab_io import dataset_hash

    failures: Counter = Counter()
    for _, _, f in results:
        failures.update(f)
    return {
        "grip_bench_version": __version__, **asdict(labels),
        "gt_dir": str(gt_dir.resolve()), "gt_dataset_hash": dataset_hash(gt_dir),
        "pred_dir": str(pred_dir.resolve()), "pred_manifest": pred_manifest or None,
        "options": {**asdict(options), "metric_ids": options.metric_ids()},
        "physics_subsampling": _physics_subsampling(options),
        "iv_subsampling": (f"exact intersection volume on at most {options.max_iv_frames} evenly "
                           "spaced grasp frames per sequence and hand" if options.max_iv_frames
                           else "exact intersection volume on every grasp frame"),
        "n_sequences": len(results), "ignored_predictions_other_split": ignored,
        "failures": {"count": sum(failures.values()), "reasons": dict(sorted(failures.items()))},
    }


def _write_outputs(out_dir: Path, results: list[tuple], per_frame: bool, info: dict) -> None:
    from ..core.io import atomic_write_text
    from ..results.schema import write_results

    out_dir.mkdir(parents=True, exist_ok=True)
    write_results([r for rows, _, _ in results for r in rows], out_dir / "results.csv")
    if per_frame:
        write_results([r for _, frames, _ in results for r in frames], out_dir / "frames.csv")
    text = json.dumps(info, indent=2, sort_keys=True, default=str) + "\n"
    atomic_write_text(out_dir / "evaluation.json", text)


# ------------------------------------------------------------------ figure data
CONTACT_STATS_FILE = "contact_stats.npz"
CONTACT_STATS_FORMAT = 1


def pool_contact_stats(
    per_sequence: list[dict], sides: Iterable[str] = ("right", "left")
) -> dict[str, np.ndarray]:
    """Pool ``evaluate.contact_stats`` of sequences (in the given order) into the arrays of
    ``contact_stats.npz``: per side ``<side>_counts`` (V,) int64 (contact counts summed over
    grasp frames), ``<side>_frames`` (1,) int64 (grasp frames) and ``<side>_depths`` (K,)
    float64 (per-frame penetration depths, mm, concatenated). Contact frequency of the set:
    counts / frames; sets pool exactly by summing counts and frames. Sequences whose vertex
    count differs from the first one's raise ``ValueError``."""
    out: dict[str, np.ndarray] = {"format": np.array([CONTACT_STATS_FORMAT], np.int64)}
    for side in sides:
        items = [s[side] for s in per_sequence if side in s]
        shapes = {np.shape(it["counts"]) for it in items}
        if len(shapes) > 1:
            raise ValueError(f"{side} hands of different vertex counts: {sorted(shapes)}")
        n_verts = shapes.pop()[0] if shapes else 0
        counts = np.zeros(n_verts, np.int64)
        for it in items:
            counts += np.asarray(it["counts"], np.int64)
        out[f"{side}_counts"] = counts
        out[f"{side}_frames"] = np.array([sum(int(it["frames"]) for it in items)], np.int64)
        depths = [np.asarray(it["depths"], np.float64).reshape(-1) for it in items]
        out[f"{side}_depths"] = np.concatenate(depths) if depths else np.zeros(0)
    return out


def write_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> Path:
    """Atomic ``.npz`` of numeric / fixed-width string arrays (no pickles), in the given key
    order with a fixed zip date, so equal arrays give equal bytes."""
    import io
    import zipfile

    from ..core.io import atomic_write_bytes

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for key, a in arrays.items():
            npy = io.BytesIO()
            np.lib.format.write_array(npy, np.ascontiguousarray(a), allow_pickle=False)
            zf.writestr(zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0)),
                        npy.getvalue(), compress_type=zipfile.ZIP_DEFLATED)
    return atomic_write_bytes(path, buf.getvalue())


def read_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` written by :func:`write_npz` (no pickles)."""
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def default_workers() -> int:
    """One process per CPU (each single-threaded: MuJoCo and manifold3d are), at most 8."""
    return max(1, min(8, os.cpu_count() or 1))
