"""``grip-bench run``: the whole benchmark as a resumable pipeline of cached work units.

Stages (each a small function; units run in a deterministic order)::

    data -> counterfactual split -> perturbed test sets -> train -> predict -> evaluate
    -> sensitivity -> runtime -> validity -> report

A **profile** (``smoke``, ``default``, ``paper`` or any ``.toml`` path, loaded by
``grip_bench.profiles.load_profile``) is data, not a code branch: its sections set data
size, network widths, epochs and seeds for the methods, and its ``[run]`` section
(:data:`RUN_KEYS`; ``profiles/default.toml`` is the schema) says what the runner does:
data source and size, tables, methods, perturbations, metrics, seeds, bootstrap, timing.

Which units exist follows from the tables: every chosen method predicts on the clean
test split (leaderboard) and on each perturbed set a chosen table reads it on (Table 3
and its "before" row); a method the tables name but nobody registered yet is skipped
with a note, and its cells stay empty. On perturbed sets ``PredictContext.refine`` is set
(refine the given noisy hands, GRIP Table 3).

Layout of ``OUT`` (default ``runs/<profile>``)::

    OUT/cache/<kind>/<hh>/<key>/   work units (bench.cache), each with a unit.json
        dataset      data/ (GRAB layout: generated SynthGRAB or the imported --data)
        perturbed    data/ (the test split with GRAB-T / GRAB-R noise)
        checkpoint   model.ckpt (trainable methods only)
        prediction   grab/... + tools/... + splits.json (a GRAB-layout folder)
        metrics      results.csv [frames.csv] evaluation.json contact_stats.npz
        runtime      runtime.json (timed predictions, rows of runtime.csv)
        validity     validity.csv (metric validity: [run] validity_sequences > 0)
        counterfactual  data/ (the counterfactual geometry split: pairs.json, GRAB layout;
                     [run] counterfactual_sources > 0, generated data only)
        sensitivity  sensitivity_pairs.csv (every method's scores on every pair)
    OUT/cache/features/<code>/     GRIP's sensor features per data hash, shared by its variants
    OUT/results.csv                tidy results of every metric unit (docs/contract.md, "Results")
    OUT/frames.csv                 per-frame values (when [run] per_frame = true)
    OUT/runtime.csv                prediction time per frame per method and mode
    OUT/leaderboard.{csv,md,html}  every method on the clean test split, figures embedded
    OUT/tables/<table>.{md,csv,tex,html}
    OUT/figures/*.png              contact heatmaps, penetration CDF, per-object bars (+ data)
        heatmap_data.npz           per-vertex contact frequency, gt + [run] figure_methods
        penetration_depths.npz     per-frame penetration depths (mm), the same methods
        contact_heatmaps.png  penetration_cdf.png  per_object_<metric>.png (mpvpe, iv)
        metric_validity.png        each metric's response to degraded ground truth
    OUT/validity.csv               the validity unit's responses ([run] validity_sequences > 0)
    OUT/validity.json              which unit they came from: its key and inputs
    OUT/tables/metric_validity.{md,csv}  the same as a table, each claim PASS / FAIL
    OUT/sensitivity_pairs.csv      the sensitivity unit's per-pair scores (SI units)
    OUT/tables/geometry_sensitivity.{md,csv,html}  methods on the counterfactual split, with
                                   its sanity gate (also in leaderboard.html and run.log)
    OUT/manifest.json              versions, git revision, profile, config, seeds, data hash,
                                   wall time per stage (docs/contract.md, "Results")
    OUT/viewer/*.html, index.json  3D pages of each method's worst / median test sequence
                                   ([run] viewer_sequences), linked from the HTML report
    OUT/run.log                    what each run did (appended)

Cache keys (``bench.plan``): ``bench.cache.unit_key(kind, inputs)`` where ``inputs`` holds
everything the unit's content depends on: its configuration (profile sections, seeds,
sigmas, metric ids, versions and evaluation options), the **keys of the units it reads** (so
a change upstream invalidates everything downstream and nothing else) and a digest of the
code it runs (``bench.codehash``: the import closure of the unit kind's stage module and of
the method's module; docs/architecture.md, "Cache keys"), so editing code does not silently
reuse stale results. ``device`` enters the keys of units that run a trainable network (GPU and CPU
weights differ); fixed methods are device-independent. Methods reporting the same
``train_key()`` (GRIP variants that differ only at inference) share one checkpoint unit.

Units are written through ``Cache.atomic``: a killed run leaves either a complete unit or
nothing, and the next run does only what is missing. Training writes into
``cache/work/<key>/`` first, so a method that checkpoints its progress (GRIP's
``.partial``) resumes there after a kill.

This module runs the stages in order (``STAGE_FUNCTIONS``; the work of each unit kind is
in ``bench.stages``, the plan in ``bench.plan``, execution in ``bench.execute``, or with
``--executor ray`` as Ray tasks over the same cache in ``bench.ray_executor``) and
assembles the report. With ``[run] shard_sequences`` > 0 a method's prediction and
evaluation of a test set are several units (``bench.stages.shards``), planned once the
dataset exists (:func:`replan`) and merged here into the same bytes as one unit's.
``grip-bench report OUT`` re-renders tables, leaderboard and figures
from ``OUT`` alone with ``report.write.write_report``, the very function ``run`` ends with,
so both write the same bytes.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

from ..report.write import (
    DEPTH_DATA,
    DEPTH_FORMAT,
    HEATMAP_DATA,
    SENSITIVITY_PAIRS,
    figure_methods,
    write_report,
)
from ..results.layout import CLEAN, MAIN_SPLIT
from .cache import Cache
from .execute import RunLog, RunState, run_stage, stage_workers
from .plan import RunConfig, Unit, build_plan
from .stages.counterfactual import make_counterfactual
from .stages.data import make_dataset
from .stages.perturb import make_perturbed
from .stages.runtime import time_method
from .stages.sensitivity import PAIRS_FILE, score_sensitivity
from .stages.shards import evaluate_unit, predict_unit
from .stages.train import train_method
from .stages.validity import VALIDITY_FILE, measure_validity

StageFunction = Callable[[RunState, Unit, Path], dict]


# --- stage: report --------------------------------------------------------------------------
def assemble_results(st: RunState) -> None:
    """Merge the metric units into ``OUT/results.csv`` (+ ``frames.csv``) and ``runtime.csv``."""
    from ..results.schema import read_results, write_results, write_runtime

    out = st.cfg.out
    for name in ("results.csv", "frames.csv"):
        parts = [read_results(st.unit_dir(u.key) / name) for u in st.plan.of("metrics")
                 if (st.unit_dir(u.key) / name).is_file()]
        if parts:
            write_results(pd.concat(parts, ignore_index=True), out / name)
        elif (out / name).exists():
            (out / name).unlink()  # a stale file of an earlier run with other settings
    if not any((st.unit_dir(u.key) / "results.csv").is_file() for u in st.plan.of("metrics")):
        write_results([], out / "results.csv")
    rows = [r for u in st.plan.of("runtime")
            for r in json.loads((st.unit_dir(u.key) / "runtime.json").read_text("utf-8"))]
    write_runtime(pd.DataFrame(rows, columns=list(_runtime_columns())), out / "runtime.csv")


def _runtime_columns() -> tuple[str, ...]:
    from ..results.schema import RUNTIME_COLUMNS

    return RUNTIME_COLUMNS


def assemble_figure_data(st: RunState) -> None:
    """``OUT/figures/{heatmap_data,penetration_depths}.npz`` from the clean-split metric units'
    ``contact_stats.npz`` (stale files are removed when there is nothing to write)."""
    from ..core.frames import SIDES
    from ..metrics.aggregate import CONTACT_STATS_FILE, read_npz, write_npz
    from ..report.figures import write_heatmap_data

    figs = st.cfg.out / "figures"
    parts: dict[str, list] = {}  # method -> its clean-split units' stats (shards in order)
    for u in st.plan.of("metrics"):
        labels = u.params["labels"]
        if labels["perturbation"] == CLEAN and labels["split"] == MAIN_SPLIT:
            path = st.unit_dir(u.key) / CONTACT_STATS_FILE
            parts.setdefault(labels["method"], []).append(
                read_npz(path) if path.is_file() else None)
    stats = {m: pool_shard_stats(p) for m, p in parts.items() if None not in p}
    from ..methods.api import predicted_hands

    methods = [m for m in figure_methods(st.cfg.settings) if m in stats]
    hands = predicted_hands()  # a hand the method returns as given is not its contact
    freqs: dict[str, dict] = {}
    for m in methods:
        freqs[m] = {}
        for side in SIDES:
            if f"{side}_counts" not in stats[m] or side not in hands.get(m, SIDES):
                continue
            counts, n = stats[m][f"{side}_counts"], int(stats[m][f"{side}_frames"][0])
            freqs[m][side] = counts / n if n else np.full(counts.shape, np.nan)
    freqs = {m: f for m, f in freqs.items() if f}
    if freqs:
        write_heatmap_data(figs / HEATMAP_DATA, freqs)
    elif (figs / HEATMAP_DATA).exists():
        (figs / HEATMAP_DATA).unlink()
    if methods:
        depths = [np.concatenate([stats[m].get(f"{side}_depths", np.zeros(0)) for side in SIDES
                                  if side in hands.get(m, SIDES)])
                  for m in methods]
        write_npz(figs / DEPTH_DATA, {
            "format": np.array([DEPTH_FORMAT], np.int64), "methods": np.array(methods, dtype=str),
            "depths": np.concatenate(depths).astype(np.float64),
            "offsets": np.cumsum([0, *(len(d) for d in depths)]).astype(np.int64)})
    elif (figs / DEPTH_DATA).exists():
        (figs / DEPTH_DATA).unlink()


def pool_shard_stats(parts: list[dict]) -> dict:
    """One set's ``contact_stats.npz`` arrays from its shards' (in shard order), equal to
    the unsharded set's: counts and frames sum (int64, exact), depths concatenate in
    sequence order (``metrics.aggregate.pool_contact_stats``). One part is returned as is."""
    if len(parts) == 1:
        return parts[0]
    out = dict(parts[0])
    for part in parts[1:]:
        for key, a in part.items():
            have = out.get(key)
            if key == "format" or have is None or not a.size:
                out.setdefault(key, a)
            elif not have.size:  # a side no sequence of the earlier shards had
                out[key] = a
            elif key.endswith("_depths"):
                out[key] = np.concatenate([have, a])
            else:  # *_counts (V,), *_frames (1,)
                out[key] = have + a
    return out


VALIDITY_REPORT = ("validity.csv", "validity.json", "tables/metric_validity.md",
                   "tables/metric_validity.csv", "figures/metric_validity.png")


def assemble_validity(st: RunState) -> None:
    """``OUT/validity.csv`` (and ``validity.json``: the unit's key and inputs) from the
    validity unit; without one (``[run] validity_sequences = 0``) the files of an earlier
    run, and the table and figure drawn from them, are removed."""
    from ..core.io import atomic_write_bytes
    from ..report.validity import write_validity_record

    out = st.cfg.out
    units = st.plan.of("validity")
    if not units:
        for rel in VALIDITY_REPORT:
            if (out / rel).exists():
                (out / rel).unlink()
        return
    unit = units[0]
    atomic_write_bytes(out / "validity.csv", (st.unit_dir(unit.key) / VALIDITY_FILE).read_bytes())
    write_validity_record(out, {"unit": unit.key, "inputs": unit.params["inputs"]})


def assemble_sensitivity(st: RunState) -> None:
    """``OUT/sensitivity_pairs.csv`` from the sensitivity unit (``[run]
    counterfactual_sources``), which ``write_report`` draws the geometry-sensitivity table
    from; without one the file of an earlier run is removed (and with it the table)."""
    from ..core.io import atomic_write_bytes

    units = st.plan.of("sensitivity")
    if not units:
        if (st.cfg.out / SENSITIVITY_PAIRS).exists():
            (st.cfg.out / SENSITIVITY_PAIRS).unlink()
        return
    atomic_write_bytes(st.cfg.out / SENSITIVITY_PAIRS,
                       (st.unit_dir(units[0].key) / PAIRS_FILE).read_bytes())


def log_sensitivity_gate(st: RunState) -> None:
    """The geometry-sensitivity table's sanity gate in the run's log (and on stderr)."""
    from ..report.sensitivity import REFERENCES, read_pairs_csv, sanity_gate

    path = st.cfg.out / SENSITIVITY_PAIRS
    if not st.plan.of("sensitivity") or not path.is_file():
        return
    rows = read_pairs_csv(path)
    if not len(rows):
        st.log("geometry sensitivity: the counterfactual split holds no pairs (every twin "
               "was rejected); no table")
        return
    gate = sanity_gate(rows)
    st.log(f"geometry sensitivity: {rows['pair'].nunique()} pairs, "
           f"{rows.loc[~rows['method'].isin(REFERENCES), 'method'].nunique()} "
           f"method(s); sanity gate {'PASS' if all(ok for _, ok, _ in gate) else 'FAIL'} "
           f"({st.cfg.out / 'tables' / 'geometry_sensitivity.md'})")
    for name, ok, got in gate:
        st.log(f"  {'PASS' if ok else 'FAIL'}: {name} ({got})")


def log_table_gates(st: RunState) -> None:
    """The sanity gates of the tables that declare some (``[[gates]]``), as printed under
    each table, in the run's log (and on stderr)."""
    from ..report.tables import TABLES, compute_table, gate_line
    from ..results.schema import read_results

    path = st.cfg.out / "results.csv"
    specs = [spec for spec in TABLES if spec.gates]
    if not specs or not path.is_file():
        return
    results, opts = read_results(path), st.cfg.report_options()
    for spec in specs:
        data = compute_table(spec, results, n_boot=opts["bootstrap_n"],
                             seed=opts["bootstrap_seed"], averaging=opts["averaging"])
        oks = [ok for _, ok, _ in data.gates]
        verdict = "FAIL" if False in oks else ("NOT CHECKED" if None in oks else "PASS")
        st.log(f"{spec.id}: sanity gates {verdict} "
               f"({st.cfg.out / 'tables' / (spec.id + '.md')})")
        for gate in data.gates:
            st.log(f"  {gate_line(*gate)}")


def assemble_viewer(st: RunState) -> None:
    """``OUT/viewer/``: 3D pages of each leaderboard method's worst, median, ... clean test
    sequence (``[run] viewer_sequences``, default 2; 0 removes earlier pages) and their
    ``index.json``, which the report links (``report.viewer``). Needs the cache's prediction
    folders, so it runs here, not in ``grip-bench report``. A page whose inputs and viewer
    code are those of the page already there is kept (a cached rerun writes none)."""
    from ..methods.api import variants
    from ..report.viewer import DEFAULT_VIEWER_SEQUENCES, RUN_MAX_FRAMES, write_run_pages
    from ..results.schema import read_results
    from .codehash import CodeIndex

    out = st.cfg.out
    n = int(st.cfg.settings.get("viewer_sequences", DEFAULT_VIEWER_SEQUENCES))
    from ..report.tables import is_seed_label

    skip = variants() | {"gt"}  # ablations have their own tables; gt is on every page
    preds: dict[str, list] = {}  # method -> its clean-split prediction folders (shards)
    gts: dict[str, Path] = {}
    for u in st.plan.of("metrics"):
        labels = u.params["labels"]
        if labels["perturbation"] == CLEAN and labels["split"] == MAIN_SPLIT \
                and labels["method"] not in skip and not is_seed_label(labels["method"]):
            preds.setdefault(labels["method"], []).append(st.unit_dir(u.params["prediction"]))
            gts[labels["method"]] = st.data_dir(u.params["gt"])
    frames = read_results(out / "frames.csv") if (out / "frames.csv").is_file() else None
    with tempfile.TemporaryDirectory(prefix="grip-bench-viewer-") as tmp:
        sources = {m: (_merged_predictions(dirs, Path(tmp) / str(i)), gts[m])
                   for i, (m, dirs) in enumerate(sorted(preds.items()))}
        pages = write_run_pages(out, read_results(out / "results.csv"), sources, n,
                                frames=frames, split=MAIN_SPLIT, model_path=st.cfg.model_path,
                                max_frames=RUN_MAX_FRAMES, workers=stage_workers(st.cfg),
                                code=CodeIndex.installed().digest([write_run_pages.__module__]))
    if pages:
        st.log(f"viewer: {len(pages)} pages in {out / 'viewer'} "
               f"({sum(p['bytes'] for p in pages) / 1e6:.1f} MB)")


def _merged_predictions(dirs: list[Path], dest: Path) -> Path:
    """The one prediction folder of an unsharded set, or for shards ``dest`` holding links to
    every shard's sequence files (the viewer reads ``grab/<sequence>.npz``)."""
    if len(dirs) == 1:
        return dirs[0]
    for d in dirs:
        for f in sorted((d / "grab").rglob("*.npz")):
            link = dest / "grab" / f.relative_to(d / "grab")
            link.parent.mkdir(parents=True, exist_ok=True)
            link.symlink_to(f.resolve())
    return dest


def stage_report(st: RunState) -> None:
    t0 = time.perf_counter()
    assemble_results(st)
    assemble_figure_data(st)
    assemble_validity(st)
    assemble_sensitivity(st)
    assemble_viewer(st)
    written = write_report(st.cfg.out, st.cfg.report_options(), tables=st.cfg.tables)
    pngs = [p.name for p in written if p.suffix == ".png"]
    st.log(f"figures: {', '.join(pngs)}" if pngs else "figures: none drawn (no figure data)")
    log_sensitivity_gate(st)
    log_table_gates(st)
    st.stage_times["report"] = round(time.perf_counter() - t0, 3)


# --- manifest and summary -------------------------------------------------------------------
def _data_hash(st: RunState) -> str:
    return st.info(st.plan.data_key)["info"]["data_hash"]


def run_manifest(st: RunState) -> dict:
    """Manifest of this run (docs/contract.md, "Results"); config has report options, unit keys."""
    from ..results.manifest import build_manifest

    cfg = st.cfg
    config = {"profile_name": cfg.profile_name, "profile_file": cfg.profile_file,
              "run": cfg.settings, "tables": list(cfg.tables), "methods": list(cfg.methods),
              "perturbations": list(cfg.perturbations), "device": cfg.device,
              "workers": cfg.workers, "executor": cfg.executor,
              "data": str(cfg.data) if cfg.data else None,
              "dataset": st.plan.dataset, "report": cfg.report_options(),
              "units": {u.label: u.key for u in st.plan.units}, "cache": st.cache.summary()}
    s = cfg.settings
    seeds = {"data": s["data_seed"], "perturb": s["perturb_seed"], "train_predict": s["seed"],
             "bootstrap": s["bootstrap_seed"]}
    source = st.info(st.plan.data_key)["info"].get("source_hash")
    if source:
        config["data_source_hash"] = source
    return build_manifest(cfg.profile, config, seeds, _data_hash(st), st.stage_times)


def summary_lines(st: RunState) -> list[str]:
    """What was reused and what was computed, per kind, plus the stage times."""
    from ..results.manifest import peak_memory_mib

    lines = [st.cache.summary_line()]
    lines += [f"  {name:<14} {secs:8.2f} s" for name, secs in st.stage_times.items()]
    mem = peak_memory_mib()
    if mem:
        lines.append(f"  peak memory: {mem['self']:.0f} MiB (run), {mem['children']:.0f} MiB "
                     "(largest worker)")
    return lines


# --- the whole run --------------------------------------------------------------------------
def with_unit_seed(fn: StageFunction, st: RunState, unit: Unit, tmp: Path) -> dict:
    """Run stage function ``fn`` for ``unit`` with the unit's own training seed: a unit of a
    further seed of ``[run] seeds`` carries ``seed`` in its parameters (``bench.plan``), and
    the stages read the seed from the run's configuration, so it is swapped in there. Units
    without one (every unit of a single-seed run) run with the state as it is."""
    seed = unit.params.get("seed")
    if seed is not None and seed != st.cfg.seed:
        cfg = dataclasses.replace(st.cfg, settings={**st.cfg.settings, "seed": int(seed)})
        st = dataclasses.replace(st, cfg=cfg)  # same cache, plan, log and loaded methods
    return fn(st, unit, tmp)


def dataset_unit(st: RunState, unit: Unit, tmp: Path) -> dict:
    """A ``dataset`` unit: generation or import (``stages.data``), then the capture-noise
    model when the unit's inputs name one (``[run] capture_noise``; ``stages.capture``,
    which only such units import, so noise-free dataset keys do not depend on it)."""
    if "capture_noise" not in unit.params["inputs"]:
        return make_dataset(st, unit, tmp)
    from .stages.capture import make_noisy_dataset

    return make_noisy_dataset(st, unit, tmp)


STAGE_FUNCTIONS = (("data", "dataset", dataset_unit),
                   ("counterfactual", "counterfactual", make_counterfactual),
                   ("perturb", "perturbed", make_perturbed),
                   ("train", "checkpoint", partial(with_unit_seed, train_method)),
                   ("predict", "prediction", partial(with_unit_seed, predict_unit)),
                   ("evaluate", "metrics", evaluate_unit),
                   ("sensitivity", "sensitivity", score_sensitivity),
                   ("runtime", "runtime", time_method),
                   ("validity", "validity", measure_validity))


def start(cfg: RunConfig) -> RunState:
    """Open the cache, plan the run, log the plan."""
    cfg.out.mkdir(parents=True, exist_ok=True)
    log = RunLog(cfg.out / "run.log", echo=cfg.progress)
    cache = Cache(cfg.out / "cache")
    plan = build_plan(cfg, cache)
    todo = sum(not c for c in plan.cached.values())
    log(f"grip-bench run: profile {cfg.profile_name} ({cfg.profile_file}), out {cfg.out}, "
        f"{len(plan.units)} units, {len(plan.units) - todo} cached")
    log(f"methods: {', '.join(cfg.methods) or 'none'}; tables: {', '.join(cfg.tables)}")
    for note in (*cfg.notes, *plan.notes):
        log(note)
    if cache.removed_stale:
        log(f"removed {cache.removed_stale} unfinished unit(s) of an interrupted run")
    return RunState(cfg, cache, plan, log)


def replan(st: RunState) -> bool:
    """Plan again when the plan waits for the dataset (``Plan.deferred``: sharding lists its
    test sequences) and the dataset unit now exists; True when it did. Every unit planned
    before keeps its key, so nothing done is redone."""
    if not st.plan.deferred or not st.cache.has(st.plan.data_key):
        return False
    st.plan = build_plan(st.cfg, st.cache)
    for note in st.plan.notes:
        st.log(note)
    return True


def run(cfg: RunConfig) -> RunState:
    """Plan, execute the missing units stage by stage, assemble results and report."""
    from ..results.manifest import write_manifest

    t0 = time.perf_counter()
    st = start(cfg)
    try:
        if cfg.executor == "ray":
            from .ray_executor import run_ray

            run_ray(st, STAGE_FUNCTIONS, replan)
        else:
            for name, kind, fn in STAGE_FUNCTIONS:
                replan(st)
                run_stage(st, name, kind, fn)
    except KeyboardInterrupt:
        # a signal between a unit's temp folder and its cleanup must not leave the folder
        st.cache.clean_stale(own=True)
        raise
    stage_report(st)
    st.stage_times["total"] = round(time.perf_counter() - t0, 3)
    write_manifest(cfg.out / "manifest.json", run_manifest(st))
    for line in summary_lines(st):
        st.log(line)
    return st
