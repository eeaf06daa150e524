"""``grip-bench run``: the whole benchmark as a resumable pipeline of cached work units.

Stages (each a small function; units run in a deterministic order)::

    data -> perturbed test sets -> train -> predict -> evaluate -> runtime -> report

A **profile** (``smoke``, ``default``, ``paper`` or any ``.toml`` path, loaded by
``grip_bench.profiles.load_profile``) is data, not a code branch: its sections set data
size, network widths, epochs and seeds for the methods, and its ``[run]`` section
(:data:`RUN_KEYS`; ``profiles/default.toml`` is the schema) says what the runner does:
data source and size, tables, methods, perturbations, metrics, seeds, bootstrap, timing.

Which units exist follows from the tables: every chosen method predicts on the clean
test split (leaderboard) and on each perturbed set a chosen table reads it on (Table 3
and its "before" row); a method the tables name but nobody registered yet is skipped
with a note, and its cells stay empty. On perturbed sets ``ctx.extra["refine"]`` is set
(refine the given noisy hands, GRIP Table 3).

Layout of ``OUT`` (default ``runs/<profile>``)::

    OUT/cache/<kind>/<hh>/<key>/   work units (bench.cache), each with a unit.json
        dataset      data/ (GRAB layout: generated SynthGRAB or the imported --data)
        perturbed    data/ (the test split with GRAB-T / GRAB-R noise)
        checkpoint   model.ckpt (trainable methods only)
        prediction   grab/... + tools/... + splits.json (a GRAB-layout folder)
        metrics      results.csv [frames.csv] evaluation.json contact_stats.npz
        runtime      runtime.json (timed predictions, rows of runtime.csv)
    OUT/cache/features/            GRIP's sensor features per data hash, shared by its variants
    OUT/results.csv                tidy results of every metric unit (DESIGN 4.3)
    OUT/frames.csv                 per-frame values (when [run] per_frame = true)
    OUT/runtime.csv                prediction time per frame per method and mode
    OUT/leaderboard.{csv,md,html}  every method on the clean test split, figures embedded
    OUT/tables/<table>.{md,csv,tex,html}
    OUT/figures/*.png              contact heatmaps, penetration CDF, per-object bars (+ data)
        heatmap_data.npz           per-vertex contact frequency, gt + [run] figure_methods
        penetration_depths.npz     per-frame penetration depths (mm), the same methods
        contact_heatmaps.png  penetration_cdf.png  per_object_<metric>.png (mpvpe, iv)
    OUT/manifest.json              versions, git revision, profile, config, seeds, data hash,
                                   wall time per stage (DESIGN 4.3)
    OUT/run.log                    what each run did (appended)

Cache keys: ``bench.cache.unit_key(kind, inputs)`` where ``inputs`` holds everything the
unit's content depends on: its configuration (profile sections, seeds, sigmas, metric ids,
versions and evaluation options), the **keys of the units it reads** (so a change upstream
invalidates everything downstream and nothing else) and a digest of the code that produces
it (synth generator and data layer folders, metrics folder, a trainable method's package
folder, a fixed method's module file), so editing code does not silently reuse stale
results. ``device`` enters the keys of units that run a trainable network (GPU and CPU
weights differ); fixed methods are device-independent. Methods reporting the same
``train_key()`` (GRIP variants that differ only at inference) share one checkpoint unit.

Units are written through ``Cache.atomic``: a killed run leaves either a complete unit or
nothing, and the next run does only what is missing. Training writes into
``cache/work/<key>/`` first, so a method that checkpoints its progress (GRIP's
``.partial``) resumes there after a kill.

``grip-bench report OUT`` re-renders tables, leaderboard and figures from ``OUT`` alone
with :func:`write_report`, the very function ``run`` ends with, so both write the same
bytes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import re
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from .. import constants as C
from ..errors import InputError
from ..threads import single_thread
from .cache import Cache, jsonable, unit_key

STAGES = ("data", "perturb", "train", "predict", "evaluate", "runtime", "report")
MAIN_SPLIT = "test"
CLEAN = "none"  # the ``perturbation`` label of unperturbed results
UNIT_FILE = "unit.json"
_PERTURBATION_RE = re.compile(r"^(T|R)(\d+(?:\.\d+)?)$")

# [run] keys, as in ``grip_bench/profiles/default.toml`` (the schema every profile follows;
# a profile without [run] gets default's). Empty strings and lists mean "derive it".
RUN_KEYS = ("data", "synth_profile", "data_seed", "dataset", "tables", "methods",
            "extra_methods", "perturbations", "perturb_seed", "seed", "metrics", "per_frame",
            "device", "bootstrap_seed", "bootstrap_n", "runtime_sequences", "runtime_repeats",
            "figure_methods", "physics_frames", "iv_frames")


# --- profiles -------------------------------------------------------------------------------
def load_run_profile(name_or_path: str) -> tuple[str, dict, Path]:
    """``(name, profile dict, file)`` of a built-in profile name or a ``.toml`` path.

    Loading and key/type checks are ``grip_bench.profiles``' (shared with ``train``).
    """
    from ..profiles import load_profile, profile_path

    path = profile_path(name_or_path)
    data = load_profile(path)
    return data.get("name", path.stem), data, path


def run_settings(profile: dict, where) -> dict:
    """The profile's ``[run]`` section with its meaning checked."""
    s = dict(profile.get("run") or {})
    missing = [k for k in RUN_KEYS if k not in s]
    if missing:
        raise InputError(f"[run] lacks {', '.join(missing)}", where=where)
    if s["data"] not in ("synth", "grab"):
        raise InputError("[run] data must be 'synth' or 'grab'", where=f"{where}: run.data")
    for key in ("runtime_sequences", "runtime_repeats", "bootstrap_n", "physics_frames",
                "iv_frames"):
        if s[key] < (0 if key in ("runtime_sequences", "physics_frames", "iv_frames") else 1):
            raise InputError(f"[run] {key} is too small: {s[key]}", where=f"{where}: run.{key}")
    for label in s["perturbations"]:
        parse_perturbation(label)
    return s


# --- configuration --------------------------------------------------------------------------
@dataclass(frozen=True)
class RunConfig:
    """Everything one run needs, resolved from the profile and the command line."""

    profile_name: str
    profile: dict
    profile_file: str
    out: Path
    data: Path | None
    settings: dict
    tables: tuple[str, ...]
    methods: tuple[str, ...]
    perturbations: tuple[str, ...]
    device: str
    workers: int | None = None
    model_path: str | None = None
    progress: bool = True
    notes: tuple[str, ...] = ()
    methods_explicit: bool = False  # named by --methods or [run] methods, not derived from tables

    @property
    def seed(self) -> int:
        return int(self.settings["seed"])

    def report_options(self) -> dict:
        """What ``report`` needs to re-render (saved in the manifest)."""
        s = self.settings
        return {"bootstrap_seed": s["bootstrap_seed"], "bootstrap_n": s["bootstrap_n"],
                "figure_methods": list(s["figure_methods"]), "split": MAIN_SPLIT}


def parse_perturbation(label: str) -> tuple[str, float]:
    """``"T0.01"`` -> ``("T", 0.01)``: GRAB-T translation (m) or GRAB-R pose (rad) noise."""
    m = _PERTURBATION_RE.match(label)
    if not m:
        raise InputError(f"perturbation '{label}' should look like T0.01 or R0.3",
                         where="perturbations")
    return m.group(1), float(m.group(2))


def _select_tables(requested, settings_tables) -> tuple[str, ...]:
    """Table ids from the command line, else the profile; empty or ``all``: every table."""
    from .tables import TABLES

    names = list(requested or settings_tables)
    if not names or names == ["all"]:
        return tuple(TABLES.names())
    for name in names:
        TABLES.get(name)  # InputError listing the known tables
    return tuple(dict.fromkeys(names))


def _select_methods(requested, settings: dict, tables) -> tuple[tuple[str, ...], list[str]]:
    """``(methods, notes)``: explicit methods (command line, then profile ``methods``), else
    every registered method the tables name plus ``extra_methods``.

    An explicit unknown method is an error; a table's or ``extra_methods``' method that is
    not registered (yet) is skipped with a note, and its cells stay empty ("–").
    """
    from .methods import load_all
    from .tables import TABLES

    registry = load_all()
    names = list(requested or settings["methods"])
    if names == ["all"]:
        return tuple(registry.names()), []
    if names:
        for name in names:
            registry.get(name)  # InputError listing the known methods
        return tuple(dict.fromkeys(names)), []
    wanted = sorted({m for t in tables for m in TABLES.get(t).methods()})
    wanted += [m for m in settings["extra_methods"] if m not in wanted]
    missing = [m for m in wanted if m not in registry]
    notes = [f"not registered, skipped (its table cells stay empty): {', '.join(missing)}"] \
        if missing else []
    return tuple(m for m in wanted if m in registry), notes


def make_config(profile: str, *, data=None, out=None, methods=None, tables=None, device=None,
                workers=None, model_path=None, progress=True) -> RunConfig:
    """Resolve a :class:`RunConfig`; raises :class:`InputError` on bad choices."""
    name, prof, path = load_run_profile(profile)
    settings = run_settings(prof, path)
    if settings["data"] == "grab" and data is None:
        raise InputError(f"profile '{name}' runs on real GRAB data (SMPL-X / MANO): pass --data "
                         "DIR, the folder holding grab/ and tools/", where="--data")
    if data is not None and not Path(data).is_dir():
        raise InputError("data folder not found", where=data)
    device = device or settings["device"]
    _check_device(device)
    chosen_tables = _select_tables(tables, settings["tables"])
    chosen_methods, notes = _select_methods(methods, settings, chosen_tables)
    return RunConfig(
        profile_name=name, profile=prof, profile_file=str(path),
        out=Path(out) if out is not None else Path(C.RUN_DEFAULT_OUT) / name,
        data=Path(data) if data is not None else None, settings=settings,
        tables=chosen_tables, methods=chosen_methods,
        perturbations=tuple(settings["perturbations"]), device=device, workers=workers,
        model_path=model_path, progress=progress, notes=tuple(notes),
        methods_explicit=bool(methods or settings["methods"]))


def _check_device(device: str) -> None:
    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        raise InputError(f"unknown device '{device}' (cpu or cuda)", where="--device")
    if device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise InputError("CUDA is not available on this machine (use --device cpu)",
                             where="--device")


# --- code digests (part of the keys) --------------------------------------------------------
def folder_digest(folder: Path) -> str:
    """sha256 over the names and bytes of the ``.py`` files directly in ``folder``."""
    h = hashlib.sha256()
    for p in sorted(Path(folder).glob("*.py")):
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def code_digest(obj, folder: bool = True) -> str:
    """Digest of the code defining ``obj`` (a class or function): its module's whole source
    folder, or with ``folder=False`` the module file alone."""
    module = sys.modules.get(getattr(obj, "__module__", ""), None)
    file = getattr(module, "__file__", None)
    if not file:
        return "unknown"
    if folder:
        return folder_digest(Path(file).parent)
    return hashlib.sha256(Path(file).read_bytes()).hexdigest()


def _package_digest(package: str) -> str:
    return folder_digest(Path(str(resources.files(package))))


# --- the plan -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Unit:
    """One cached piece of work: its key, what it reads (``deps``) and its parameters."""

    kind: str
    key: str
    label: str
    params: dict
    deps: tuple[str, ...] = ()


@dataclass
class Plan:
    """Every unit of a run in execution order, with the cached ones marked."""

    units: list[Unit]
    cached: dict[str, bool]
    data_key: str
    dataset: str
    notes: list[str] = field(default_factory=list)

    def of(self, kind: str) -> list[Unit]:
        return [u for u in self.units if u.kind == kind]

    def lines(self) -> list[str]:
        """Human-readable plan: one line per unit, ``[cached]`` or ``[todo]``."""
        return [f"{'[cached]' if self.cached[u.key] else '[todo]  '} {u.kind:<10} {u.label}"
                for u in self.units]


def _add(units: list[Unit], kind: str, title: str, inputs: dict, deps=(), **params) -> Unit:
    unit = Unit(kind, unit_key(kind, inputs), title, {**params, "inputs": inputs}, tuple(deps))
    units.append(unit)
    return unit


def _data_unit(cfg: RunConfig, units: list[Unit]) -> Unit:
    s = cfg.settings
    if cfg.data is not None:
        from ..data.grab_io import dataset_hash

        source = dataset_hash(cfg.data)
        inputs = {"source": "import", "source_hash": source, "model_path": cfg.model_path,
                  "code": _package_digest("grip_bench.data")}
        return _add(units, "dataset", f"import {cfg.data}", inputs, source_hash=source)
    inputs = {"source": "synthgrab", "profile": s["synth_profile"], "seed": s["data_seed"],
              "code": [_package_digest("grip_bench.data"),
                       _package_digest("grip_bench.data.synth")]}
    return _add(units, "dataset", f"synthgrab profile={s['synth_profile']} seed={s['data_seed']}",
                inputs)


def _table_cells(cfg: RunConfig):
    """``(column, filters)`` of every cell of the chosen tables."""
    from .tables import TABLES

    for tid in cfg.tables:
        spec = TABLES.get(tid)
        for row in spec.rows:
            for col in spec.columns:
                yield col, spec.cell_filters(row, col)


def method_needs(cfg: RunConfig) -> dict[str, list[str]]:
    """Per chosen method, the test sets (``none`` + perturbation labels) it predicts on.

    Every method runs on the clean test split (leaderboard) unless its spec says
    ``clean=False``; a method also runs on a perturbed set when a chosen table reads it
    there (Table 3 and its ``before`` rows) and the profile builds that set.
    """
    from .methods import METHODS

    needs = {m: {CLEAN} if METHODS.get(m).clean else set() for m in cfg.methods}
    for col, flt in _table_cells(cfg):
        pert = flt.get("perturbation", CLEAN)
        for method in (flt.get("method"), (col.before or {}).get("method")):
            if method in needs and pert in cfg.perturbations:
                needs[method].add(pert)
    order = [CLEAN, *cfg.perturbations]
    return {m: [p for p in order if p in sets] for m, sets in needs.items()}


def _method_inputs(spec, cfg: RunConfig) -> dict:
    # A trainable method's code spans its package (networks, training); a fixed method is
    # one small module, and hashing only that keeps edits to other baselines from
    # invalidating it.
    return {"method": spec.name, "options": spec.options, "trainable": spec.trainable,
            "code": code_digest(spec.factory, folder=spec.trainable)}


def _train_identity(spec) -> dict:
    """What makes a checkpoint: the method, or its ``train_key()`` when it has one.

    GRIP variants that differ only at inference (``grip`` / ``grip-no-rnet``) report the
    same train key, so they share one checkpoint unit instead of training twice.
    """
    ident = {"method": spec.name, "options": spec.options}
    train_key = getattr(spec.build(), "train_key", None)
    if callable(train_key):
        factory = f"{spec.factory.__module__}.{spec.factory.__qualname__}"
        ident = {"factory": factory, "train_key": train_key()}
    return {**ident, "code": code_digest(spec.factory)}


def _train_units(cfg, data: Unit, units: list[Unit]) -> dict[str, Unit | None]:
    from .methods import METHODS

    out: dict[str, Unit | None] = {}
    by_key: dict[str, Unit] = {}
    leaders: dict[str, str] = {}  # family -> key of its first checkpoint unit
    train_cfg = {k: v for k, v in cfg.profile.items() if k not in ("run", "name")}
    for name in cfg.methods:
        spec = METHODS.get(name)
        if not spec.trainable:
            out[name] = None
            continue
        ident = _train_identity(spec)
        inputs = {**ident, "data": data.key, "profile": train_cfg,
                  "seed": cfg.seed, "device": cfg.device}
        key = unit_key("checkpoint", inputs)
        if key not in by_key:
            # variants of one family (same factory, a train_key) share cached features:
            # the first builds them, the others start after it (run_parallel)
            family = ident.get("factory")
            after = leaders.setdefault(family, key) if family else None
            by_key[key] = _add(units, "checkpoint", f"train {name}", inputs, [data.key],
                               method=name, after=None if after == key else after)
        out[name] = by_key[key]
    return out


def _test_sets(cfg, data: Unit, units: list[Unit]) -> dict[str, Unit]:
    sets = {CLEAN: data}
    for label in cfg.perturbations:
        kind, sigma = parse_perturbation(label)
        inputs = {"data": data.key, "kind": kind, "sigma": sigma,
                  "seed": cfg.settings["perturb_seed"], "split": MAIN_SPLIT,
                  "code": _package_digest("grip_bench.data")}
        sets[label] = _add(units, "perturbed", f"perturb {label}", inputs, [data.key],
                           label=label, noise=kind, sigma=sigma)
    return sets


def world_up(cfg: RunConfig) -> tuple[float, float, float]:
    """Gravity axis for physics: SynthGRAB (procedural bodies) is y-up, real GRAB z-up."""
    if cfg.data is None:
        return tuple(float(x) for x in C.UP)
    from ..data.grab_io import list_sequences, read_grab_header

    files = list_sequences(cfg.data)
    procedural = bool(files) and read_grab_header(files[0]).get("body_model") == "procedural"
    return tuple(float(x) for x in C.UP) if procedural else (0.0, 0.0, 1.0)


def set_metrics(cfg: RunConfig, label: str, method: str | None = None) -> list[str]:
    """Metric ids evaluated on test set ``label`` (for ``method``), sorted.

    The clean set gets every chosen metric (the leaderboard shows them all), except for
    an ablation variant (``MethodSpec.variant_of``), which is compared only in its tables;
    a perturbed set gets only those a chosen table reads on it (Table 3: MPVPE, MPJPE).
    This spares the costly physics and intersection metrics where no table shows them.
    """
    from ..metrics.registry import METRICS
    from .methods import METHODS

    chosen = list(cfg.settings["metrics"] or METRICS.names())
    variant = method is not None and method in METHODS and METHODS.get(method).variant_of
    if label == CLEAN and not variant:
        return sorted(chosen)
    read = {flt.get("metric") for _, flt in _table_cells(cfg)
            if flt.get("perturbation", CLEAN) == label
            and (not variant or flt.get("method") == method)}
    return sorted(m for m in chosen if m in read)


def _metric_inputs(cfg: RunConfig, label: str = CLEAN, method: str | None = None) -> dict:
    from ..metrics.registry import METRICS

    chosen = set_metrics(cfg, label, method)
    versions = {m: METRICS.get(m).version for m in chosen}
    return {"metrics": chosen, "versions": versions, "per_frame": cfg.settings["per_frame"],
            "options": asdict(eval_options(cfg)), "code": _package_digest("grip_bench.metrics")}


def _predict_eval_units(cfg, plan_units, data, sets, ckpts, dataset) -> None:
    from .methods import METHODS

    for name, labels in method_needs(cfg).items():
        spec = METHODS.get(name)
        ckpt = ckpts[name]
        for label in labels:
            src = sets[label]
            inputs = {**_method_inputs(spec, cfg), "checkpoint": ckpt.key if ckpt else None,
                      "input": src.key, "split": MAIN_SPLIT, "seed": cfg.seed,
                      "device": cfg.device if spec.trainable else None}
            deps = [src.key] + ([ckpt.key] if ckpt else [])
            pred = _add(plan_units, "prediction", f"predict {name} @ {label}", inputs, deps,
                        method=name, input=src.key, checkpoint=ckpt.key if ckpt else None,
                        perturbation=label)
            labels_ = {"method": name, "dataset": dataset, "split": MAIN_SPLIT,
                       "perturbation": label}
            _add(plan_units, "metrics", f"evaluate {name} @ {label}",
                 {**_metric_inputs(cfg, label, name), "prediction": pred.key, "gt": data.key,
                  "labels": labels_},
                 [pred.key, data.key], prediction=pred.key, gt=data.key, labels=labels_)


def timed_methods(cfg: RunConfig) -> list[str]:
    """Methods the runtime stage times: all of them when named explicitly, else those the
    chosen runtime tables list (timing every ablation variant would tell nothing new)."""
    from .tables import TABLES

    if cfg.methods_explicit:
        return list(cfg.methods)
    named = {m for t in cfg.tables if TABLES.get(t).source == "runtime" for m in TABLES.get(t).methods()}
    return [m for m in cfg.methods if m in named]


def _runtime_units(cfg, data: Unit, ckpts, units: list[Unit]) -> None:
    from .methods import METHODS

    s = cfg.settings
    for name in timed_methods(cfg):
        spec = METHODS.get(name)
        ckpt = ckpts[name]
        inputs = {**_method_inputs(spec, cfg), "checkpoint": ckpt.key if ckpt else None,
                  "data": data.key, "device": cfg.device, "sequences": s["runtime_sequences"],
                  "repeats": s["runtime_repeats"], "seed": cfg.seed}
        _add(units, "runtime", f"time {name}", inputs, [data.key] + ([ckpt.key] if ckpt else []),
             method=name, checkpoint=ckpt.key if ckpt else None, data=data.key)


def dataset_name(cfg: RunConfig) -> str:
    """The ``dataset`` column: [run] dataset, else SynthGRAB or GRAB by the data's origin."""
    if cfg.settings["dataset"]:
        return cfg.settings["dataset"]
    if cfg.data is None:
        return "synthgrab"
    try:
        gen = json.loads((cfg.data / "manifest.json").read_text(encoding="utf-8"))["generator"]
    except (OSError, ValueError, KeyError, TypeError):
        return "grab"
    return "synthgrab" if "synth" in str(gen).lower() else "grab"


def build_plan(cfg: RunConfig, cache: Cache) -> Plan:
    """List every unit of the run in execution order and mark those already cached."""
    units: list[Unit] = []
    dataset = dataset_name(cfg)
    data = _data_unit(cfg, units)
    sets = _test_sets(cfg, data, units)
    ckpts = _train_units(cfg, data, units)
    _predict_eval_units(cfg, units, data, sets, ckpts, dataset)
    _runtime_units(cfg, data, ckpts, units)
    order = {k: i for i, k in enumerate(("dataset", "perturbed", "checkpoint", "prediction",
                                          "metrics", "runtime"))}
    units.sort(key=lambda u: order[u.kind])  # stable: plan order within a kind
    cached = {u.key: cache.has(u.key) for u in units}
    return Plan(units, cached, data.key, dataset)


# --- execution helpers ----------------------------------------------------------------------
class RunLog:
    """Messages to stderr (above the progress bars) and appended to ``OUT/run.log``."""

    def __init__(self, path: Path, echo: bool = True):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.echo = echo

    def __call__(self, msg: str) -> None:
        if self.echo:
            from tqdm import tqdm

            tqdm.write(msg, file=sys.stderr)
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {msg}\n")


def bar(items, desc: str, enabled: bool, unit: str = "unit"):
    """A tqdm progress bar on stderr (a plain iterator when progress is off)."""
    if not enabled:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=desc, unit=unit, leave=False, file=sys.stderr, dynamic_ncols=True)


@dataclass
class RunState:
    """What the stages share: configuration, cache, plan, log, timings, loaded methods."""

    cfg: RunConfig
    cache: Cache
    plan: Plan
    log: RunLog
    stage_times: dict = field(default_factory=dict)
    methods: dict = field(default_factory=dict)

    def unit_dir(self, key: str) -> Path:
        return self.cache.path(key)

    def data_dir(self, key: str) -> Path:
        """The GRAB-layout folder of a dataset or perturbed unit."""
        return self.cache.path(key) / "data"

    def info(self, key: str) -> dict:
        return json.loads((self.cache.path(key) / UNIT_FILE).read_text(encoding="utf-8"))


def execute(st: RunState, unit: Unit, work: Callable[[Path], dict | None]) -> Path:
    """Run ``work(tmp)`` for a unit unless it is cached; the unit appears atomically.

    ``work`` returns a small dict recorded in the unit's ``unit.json`` beside its inputs and
    the unit's wall time (``seconds``; not part of any result).
    """
    if st.cache.has(unit.key):
        return st.unit_dir(unit.key)
    with st.cache.atomic(unit.key) as tmp:
        t0 = time.perf_counter()
        info = work(tmp) or {}
        record = {"kind": unit.kind, "label": unit.label, "inputs": unit.params["inputs"],
                  "info": info, "seconds": round(time.perf_counter() - t0, 3)}
        text = json.dumps(jsonable(record), sort_keys=True, indent=1) + "\n"
        (tmp / UNIT_FILE).write_text(text, encoding="utf-8")
    return st.unit_dir(unit.key)


def run_stage(st: RunState, name: str, kind: str, fn: Callable[[RunState, Unit, Path], dict]):
    """Execute every unit of ``kind`` with one progress bar; time the stage.

    Training and prediction units run in parallel worker processes when ``--workers`` > 1
    on the CPU (:func:`run_parallel`); everything else runs here in plan order.
    """
    t0 = time.perf_counter()
    units = st.plan.of(kind)
    todo = [u for u in units if not st.plan.cached[u.key]]
    if units:
        st.log(f"stage {name}: {len(units)} unit(s), {len(units) - len(todo)} cached")
    workers = min(stage_workers(st.cfg), len(todo))
    if kind in PARALLEL_KINDS and workers > 1:
        run_parallel(st, name, todo, fn, workers)
    else:
        for unit in bar(units, name, st.cfg.progress):
            if not st.plan.cached[unit.key]:
                st.log(f"  {unit.label}")
            execute(st, unit, lambda tmp, u=unit: fn(st, u, tmp))
    st.stage_times[name] = round(time.perf_counter() - t0, 3)


# --- parallel units -------------------------------------------------------------------------
# Training and prediction run single-threaded (grip_bench.threads), so W processes give
# about W times the throughput of one process with W threads, and a unit's result does not
# depend on how many run beside it.
PARALLEL_KINDS = ("checkpoint", "prediction")


def stage_workers(cfg: RunConfig) -> int:
    from ..metrics.aggregate import default_workers

    return 1 if cfg.device != "cpu" else (cfg.workers or default_workers())


def _init_unit_worker() -> None:
    import signal

    import torch

    from .methods import load_all

    torch.set_num_threads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops its workers itself
    load_all()  # a spawned process starts with an empty method registry


def _unit_task(st: RunState, unit: Unit, fn) -> str:
    execute(st, unit, lambda tmp: fn(st, unit, tmp))
    return unit.key


def _ready(unit: Unit, pending_keys: set[str]) -> bool:
    """A unit waits for the unit named in its ``after`` parameter (a shared-cache leader)."""
    return unit.params.get("after") not in pending_keys


def run_parallel(st: RunState, name: str, units: list[Unit], fn, workers: int) -> None:
    """Run ``units`` in a spawn pool of ``workers`` processes, at most ``workers`` at a time.

    Units are started leaders first (a unit with ``after`` waits for that unit: GRIP's
    variants wait for the first one, which builds the shared sensor features and ANet),
    then the costliest predictions (``MethodSpec.predict_cost``), otherwise in plan order,
    so that the stage does not end with one long unit on one worker. On an interrupt or a
    failure the workers are terminated and their unfinished temp folders removed; finished
    units stay in the cache.
    """
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from .methods import METHODS

    child = RunState(dataclasses.replace(st.cfg, progress=False), st.cache, st.plan, st.log)
    leaders = {u.params.get("after") for u in units}
    pending = sorted(units, key=lambda u: (u.key not in leaders, -_predict_cost(u, METHODS)))
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                               initializer=_init_unit_worker)
    running: dict = {}
    progress = _counter(len(units), name, st.cfg.progress)
    try:
        while pending or running:
            keys = {u.key for u in pending} | {u.key for u in running.values()}
            for unit in [u for u in pending if _ready(u, keys)][:workers - len(running)]:
                st.log(f"  {unit.label}")
                running[pool.submit(_unit_task, child, unit, fn)] = unit
                pending.remove(unit)
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in done:
                running.pop(fut)
                fut.result()  # re-raise a unit's error here
                progress.update()
    except BaseException:
        _stop_workers(pool)
        st.cache.clean_stale()
        raise
    finally:
        progress.close()
        pool.shutdown(wait=True, cancel_futures=True)


def _counter(total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="unit", leave=False, file=sys.stderr,
                dynamic_ncols=True, disable=not enabled)


def _predict_cost(unit: Unit, methods) -> float:
    name = unit.params.get("method")
    if unit.kind != "prediction" or name not in methods:
        return 0.0
    return methods.get(name).predict_cost


def _stop_workers(pool) -> None:
    """Terminate the pool's processes now (``shutdown`` would wait for running units)."""
    for proc in list(getattr(pool, "_processes", {}).values()):  # private, but the only handle
        proc.terminate()
    for proc in list(getattr(pool, "_processes", {}).values()):
        proc.join(timeout=10)


# --- stage: data ----------------------------------------------------------------------------
def _copy_sequence_meshes(seq, src: Path, dest: Path) -> None:
    """Copy the object mesh (and any subject / table mesh the file names) into ``dest``."""
    from ..data.grab_io import object_mesh_relpath, resolve_object_mesh

    rel = seq.object_mesh if seq.object_mesh and not Path(seq.object_mesh).is_absolute() \
        else object_mesh_relpath(seq.obj_name)
    pairs = [(resolve_object_mesh(seq, src), dest / rel)]
    for r in (seq.table_mesh, seq.body_vtemp, seq.rhand_vtemp, seq.lhand_vtemp):
        if r and not Path(r).is_absolute() and (src / r).is_file():
            pairs.append((src / r, dest / r))
    for a, b in pairs:
        if not b.exists():
            b.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(a, b)


def import_data(src: Path, dest: Path, model_path: str | None, progress: bool) -> None:
    """Normalise a GRAB-layout folder: 30 fps, full axis-angle hands, meshes, splits.json.

    Every later stage then reads our own files, whatever the source (real GRAB at 120 fps
    with PCA hands, or SynthGRAB).
    """
    from ..data.grab_io import list_sequences, load_mano_backend, read_grab, write_grab
    from ..data.splits import read_splits, write_splits

    backend = load_mano_backend(model_path) if model_path else None
    splits = read_splits(src, default="grip")
    for path in bar(list_sequences(src), "import", progress, unit="seq"):
        seq = read_grab(path, mano_backend=backend)
        write_grab(seq, dest / path.relative_to(src))
        _copy_sequence_meshes(seq, src, dest)
    write_splits(dest, splits)


def make_dataset(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Generate SynthGRAB or import ``--data`` into ``tmp/data``."""
    from ..data.grab_io import dataset_hash

    cfg, dest = st.cfg, tmp / "data"
    if cfg.data is not None:
        import_data(cfg.data, dest, cfg.model_path, cfg.progress)
    else:
        from ..data.synth.generate import generate

        generate(dest, profile=cfg.settings["synth_profile"], seed=cfg.settings["data_seed"],
                 workers=cfg.workers, progress=cfg.progress)
    return {"data_hash": dataset_hash(dest), "source_hash": unit.params.get("source_hash")}


def make_perturbed(st: RunState, unit: Unit, tmp: Path) -> dict:
    """The test split of the dataset with GRAB-T / GRAB-R noise (data.perturb)."""
    from ..data.perturb import perturb_dataset

    p = unit.params
    perturb_dataset(st.data_dir(unit.deps[0]), tmp / "data", p["noise"], p["sigma"],
                    seed=st.cfg.settings["perturb_seed"], split=MAIN_SPLIT)
    return {"perturbation": p["label"]}


# --- stage: train ---------------------------------------------------------------------------
def train_method(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Train one method on the dataset's train split; the checkpoint is the unit.

    Training writes into ``cache/work/<key>/`` (outside the atomic temp folder) so that a
    method that checkpoints its progress (GRIP's ``<out>.partial``) resumes after a kill;
    the finished file is then moved into the unit.
    """
    from ..grip.train import FEATURE_CACHE_ENV
    from .methods import METHODS

    work = st.cache.root / "work" / unit.key
    work.mkdir(parents=True, exist_ok=True)
    method = METHODS.get(unit.params["method"]).build()
    # one feature cache per run and code version: GRIP's variants share the sensor features
    # of the data (keyed by its hash) instead of rebuilding them in each work folder
    code = _package_digest("grip_bench.grip") + _package_digest("grip_bench")  # + sensors.py
    features = st.cache.root / "features" / hashlib.sha256(code.encode()).hexdigest()[:16]
    with _env(FEATURE_CACHE_ENV, os.environ.get(FEATURE_CACHE_ENV) or str(features)), \
            single_thread():  # the same floating-point path in a worker and in-process
        path = Path(method.train(st.data_dir(unit.deps[0]), work / "model.ckpt",
                                 profile=st.cfg.profile, seed=st.cfg.seed, device=st.cfg.device,
                                 progress=st.cfg.progress))
    shutil.move(path, tmp / path.name)
    shutil.rmtree(work, ignore_errors=True)
    return {"file": path.name}


@contextlib.contextmanager
def _env(name: str, value: str):
    """Set the environment variable ``name`` inside the block, restoring it afterwards."""
    before = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = before


def loaded_method(st: RunState, name: str, ckpt_key: str | None):
    """The method ``name`` built and loaded once per run (weights from its checkpoint unit)."""
    if (name, ckpt_key) not in st.methods:
        from .methods import METHODS

        method = METHODS.get(name).build()
        ckpt = None
        if ckpt_key is not None:
            ckpt = st.unit_dir(ckpt_key) / st.info(ckpt_key)["info"]["file"]
        method.load(ckpt, device=st.cfg.device)
        st.methods[(name, ckpt_key)] = method
    return st.methods[(name, ckpt_key)]


# --- stage: predict -------------------------------------------------------------------------
def _predict_context(st: RunState, in_dir: Path, perturbation: str, online: bool = False):
    from ..data.library import ObjectLibrary
    from .methods import PredictContext

    # refine: on a perturbed set the task is Table 3's, refining the given noisy hands
    extra = {"data_dir": st.data_dir(st.plan.data_key), "split": MAIN_SPLIT,
             "perturbation": perturbation, "refine": perturbation != CLEAN}
    return PredictContext(library=ObjectLibrary(in_dir), device=st.cfg.device, seed=st.cfg.seed,
                          online=online, extra=extra)


def _copy_dataset_files(in_dir: Path, dest: Path) -> None:
    """Meshes and splits beside the predictions, so the folder is a complete dataset."""
    from ..data.splits import read_splits, write_splits

    if (in_dir / "tools").is_dir():
        shutil.copytree(in_dir / "tools", dest / "tools", dirs_exist_ok=True)
    write_splits(dest, read_splits(in_dir))


def predict_set(st: RunState, unit: Unit, tmp: Path) -> dict:
    """One method on one test set: GRAB-layout files with the method's hands."""
    from ..data.grab_io import read_grab, write_grab
    from ..data.splits import sequences_in_split

    p = unit.params
    method = loaded_method(st, p["method"], p["checkpoint"])
    in_dir = st.data_dir(p["input"])
    ctx = _predict_context(st, in_dir, p["perturbation"])
    files = sequences_in_split(in_dir, MAIN_SPLIT)
    with single_thread():  # the same floating-point path in a worker and in-process
        for path in bar(files, p["method"], st.cfg.progress, unit="seq"):
            write_grab(method.predict(read_grab(path), ctx), tmp / path.relative_to(in_dir))
    _copy_dataset_files(in_dir, tmp)
    return {"sequences": len(files)}


# --- stage: evaluate ------------------------------------------------------------------------
def _relabel(path: Path, labels: dict) -> None:
    """Set the method / dataset / split / perturbation columns the runner owns."""
    from .results import read_results, write_results

    if path.is_file():
        df = read_results(path)
        for col, value in labels.items():
            df[col] = value
        write_results(df, path)


def eval_options(cfg: RunConfig):
    """Evaluation options of the run (metrics.evaluate.EvalOptions); part of the metric keys."""
    from ..metrics.evaluate import EvalOptions

    return EvalOptions(model_path=cfg.model_path, up=world_up(cfg),
                       max_physics_frames=int(cfg.settings["physics_frames"]),
                       max_iv_frames=int(cfg.settings["iv_frames"]))


def evaluate_set(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Metrics of one prediction set against the clean ground truth (metrics.aggregate)."""
    from ..metrics.aggregate import default_workers, evaluate_dirs

    p, s = unit.params, st.cfg.settings
    info = evaluate_dirs(st.unit_dir(p["prediction"]), st.data_dir(p["gt"]), tmp,
                         method=p["labels"]["method"], metrics=p["inputs"]["metrics"],
                         per_frame=s["per_frame"], workers=st.cfg.workers or default_workers(),
                         progress=st.cfg.progress, split=MAIN_SPLIT,
                         options=eval_options(st.cfg), contact_stats=True)
    for name in ("results.csv", "frames.csv"):
        _relabel(tmp / name, p["labels"])
    return {"sequences": info.get("n_sequences"), "failures": info.get("failures")}


# --- stage: runtime -------------------------------------------------------------------------
def _time_once(method, seqs, ctx, device: str) -> float:
    t0 = time.perf_counter()
    for seq in seqs:
        method.predict(seq, ctx)
    if device.startswith("cuda"):
        import torch

        torch.cuda.synchronize()  # kernels run asynchronously; time their completion
    return time.perf_counter() - t0


def supports_online(method) -> bool:
    """Whether ``predict`` honours ``ctx.online``: a ``supports_online`` attribute, else
    GRIP (whose pipeline streams frame by frame)."""
    flag = getattr(method, "supports_online", None)
    if flag is not None:
        return bool(flag)
    try:
        from ..grip.method import GripMethod
    except ImportError:
        return False
    return isinstance(method, GripMethod)


def time_method(st: RunState, unit: Unit, tmp: Path) -> dict:
    """Prediction seconds per frame: offline (whole sequences) and, if supported, online.

    One untimed warm-up call first (lazy imports, distance fields, CUDA context); then
    ``runtime_repeats`` timed passes over the first ``runtime_sequences`` test sequences,
    one row each. ``batch`` is the number of sequences per ``predict`` call (1).
    """
    from ..data.grab_io import read_grab
    from ..data.splits import sequences_in_split

    p, s, device = unit.params, st.cfg.settings, st.cfg.device
    method = loaded_method(st, p["method"], p["checkpoint"])
    in_dir = st.data_dir(p["data"])
    seqs = [read_grab(f) for f in sequences_in_split(in_dir, MAIN_SPLIT)[:s["runtime_sequences"]]]
    frames = sum(seq.n_frames for seq in seqs)
    modes = [("offline", False)] + ([("online", True)] if supports_online(method) else [])
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


# --- stage: report --------------------------------------------------------------------------
def assemble_results(st: RunState) -> None:
    """Merge the metric units into ``OUT/results.csv`` (+ ``frames.csv``) and ``runtime.csv``."""
    from .results import read_results, write_results, write_runtime

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
    from .results import RUNTIME_COLUMNS

    return RUNTIME_COLUMNS


# figure data (written by ``run`` from the metric units, read by ``write_figures``)
HEATMAP_DATA = "heatmap_data.npz"
DEPTH_DATA = "penetration_depths.npz"
DEPTH_FORMAT = 1
HEATMAP_PNG = "contact_heatmaps.png"
CDF_PNG = "penetration_cdf.png"
BAR_METRICS = ("mpvpe", "iv")  # per_object_<metric>.png
DEFAULT_FIGURE_METHODS = ("grip", "grip-no-rnet")  # when [run] figure_methods is empty


def figure_methods(settings: dict) -> list[str]:
    """Methods of the heatmaps and the CDF: gt first, then ``[run] figure_methods`` (empty:
    :data:`DEFAULT_FIGURE_METHODS`); those without figure data are left out later."""
    chosen = list(settings.get("figure_methods") or DEFAULT_FIGURE_METHODS)
    return ["gt", *dict.fromkeys(m for m in chosen if m != "gt")]


def assemble_figure_data(st: RunState) -> None:
    """``OUT/figures/{heatmap_data,penetration_depths}.npz`` from the clean-split metric units'
    ``contact_stats.npz`` (stale files are removed when there is nothing to write)."""
    from ..metrics.aggregate import CONTACT_STATS_FILE, read_npz, write_npz
    from ..report.figures import SIDES, write_heatmap_data

    figs = st.cfg.out / "figures"
    stats: dict[str, dict] = {}
    for u in st.plan.of("metrics"):
        labels = u.params["labels"]
        path = st.unit_dir(u.key) / CONTACT_STATS_FILE
        if labels["perturbation"] == CLEAN and labels["split"] == MAIN_SPLIT and path.is_file():
            stats.setdefault(labels["method"], read_npz(path))
    from .methods import predicted_hands

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


def read_depth_data(path: Path) -> dict[str, np.ndarray]:
    """``{method: (N,) mm}`` of ``penetration_depths.npz``."""
    from ..metrics.aggregate import read_npz

    d = read_npz(path)
    if int(d["format"][0]) != DEPTH_FORMAT:
        raise InputError(f"penetration depth format {int(d['format'][0])}, expected {DEPTH_FORMAT}",
                         path)
    off = d["offsets"]
    return {m: d["depths"][off[i]:off[i + 1]] for i, m in enumerate(d["methods"].tolist())}


def write_figures(out: Path, results: pd.DataFrame, options: dict) -> list[Path]:
    """Figures under ``OUT/figures/`` from saved results and figure data (report.figures).

    Contact heatmaps (``heatmap_data.npz``), penetration CDF (``penetration_depths.npz``)
    and per-object bars of :data:`BAR_METRICS` on the clean main split (``results``). A
    figure without data (or whose data does not fit, e.g. a hand template of another vertex
    count) is skipped and an older PNG of it removed. Returns the PNG paths (embedded in
    leaderboard.html).
    """
    from ..report import figures as F

    figs = out / "figures"
    drawn: list[Path] = []
    jobs = []
    if (figs / HEATMAP_DATA).is_file():
        jobs.append((HEATMAP_PNG, lambda p: F.contact_heatmap(
            F.read_heatmap_data(figs / HEATMAP_DATA), p,
            title="Contact frequency over grasp frames (clean test split)")))
    if (figs / DEPTH_DATA).is_file():
        jobs.append((CDF_PNG, lambda p: F.penetration_cdf(
            read_depth_data(figs / DEPTH_DATA), p,
            title="Penetration depth per grasp frame (clean test split)")))
    main = results[(results["split"] == options.get("split", MAIN_SPLIT))
                   & (results["perturbation"] == CLEAN)]
    for metric in BAR_METRICS:
        present = set(main.loc[main["metric"] == metric, "method"])
        # the heatmaps' methods (gt first): twenty methods side by side are unreadable
        bar_methods = [m for m in figure_methods(options) if m in present]
        if bar_methods:
            jobs.append((f"per_object_{metric}.png", lambda p, metric=metric, ms=bar_methods:
                         F.per_object_bars(main, metric, p, methods=ms,
                                           n_boot=options["bootstrap_n"],
                                           seed=options["bootstrap_seed"])))
    names = {HEATMAP_PNG, CDF_PNG, *(f"per_object_{m}.png" for m in BAR_METRICS)}
    for name, draw in jobs:
        try:
            drawn.append(draw(figs / name))
            names.discard(name)
        except InputError:
            pass
    for name in sorted(names):  # stale figures of an earlier run
        if (figs / name).exists():
            (figs / name).unlink()
    return drawn


def write_leaderboards(out: Path, results: pd.DataFrame, options: dict,
                       figures: list[Path]) -> list[Path]:
    """``leaderboard.{csv,md,html}`` of the clean main split (one set per dataset)."""
    from .leaderboard import (
        leaderboard,
        write_leaderboard_csv,
        write_leaderboard_html,
        write_leaderboard_md,
    )
    from .methods import predicted_hands, variants

    main = results[results["split"] == options.get("split", MAIN_SPLIT)]
    main = main[~main["method"].isin(variants())]  # ablations: in their own tables
    datasets = sorted(main["dataset"].unique()) or [None]
    hands = predicted_hands()
    written = []
    for ds in datasets:
        df = main if ds is None else main[main["dataset"] == ds]
        lb = leaderboard(df, seed=options["bootstrap_seed"], n_boot=options["bootstrap_n"],
                         hands=hands)
        stem = "leaderboard" if len(datasets) == 1 else f"leaderboard.{ds}"
        written += [write_leaderboard_csv(lb, out / f"{stem}.csv"),
                    write_leaderboard_md(lb, out / f"{stem}.md")]
        if not lb.empty:
            written.append(write_leaderboard_html(lb, out / f"{stem}.html", figures=figures))
    return written


def report_options(out: Path) -> dict:
    """Rendering options saved by ``run`` in ``manifest.json`` (defaults without one)."""
    defaults = {"bootstrap_seed": C.BOOTSTRAP_SEED, "bootstrap_n": C.BOOTSTRAP_N,
                "figure_methods": list(C.RUN_FIGURE_METHODS), "split": MAIN_SPLIT}
    path = Path(out) / "manifest.json"
    if not path.is_file():
        return defaults
    from .manifest import read_manifest

    saved = (read_manifest(path).get("config") or {}).get("report") or {}
    return {**defaults, **saved}


def write_report(out: str | os.PathLike, options: dict | None = None) -> list[Path]:
    """Tables, figures and leaderboard from ``OUT/results.csv`` (+ runtime.csv, figure data).

    Reads only files in ``OUT``: ``grip-bench report OUT`` and the end of ``run`` call this
    same function, so they write the same bytes.
    """
    from ..report.render import render_all
    from .results import read_results

    out = Path(out)
    options = options or report_options(out)
    results = read_results(out / "results.csv")
    written = render_all(out, out / "tables", n_boot=options["bootstrap_n"],
                         seed=options["bootstrap_seed"])
    figures = write_figures(out, results, options)
    written += figures
    written += write_leaderboards(out, results, options, figures)
    return written


def stage_report(st: RunState) -> None:
    t0 = time.perf_counter()
    assemble_results(st)
    assemble_figure_data(st)
    written = write_report(st.cfg.out, st.cfg.report_options())
    pngs = [p.name for p in written if p.suffix == ".png"]
    st.log(f"figures: {', '.join(pngs)}" if pngs else "figures: none drawn (no figure data)")
    st.stage_times["report"] = round(time.perf_counter() - t0, 3)


# --- manifest and summary -------------------------------------------------------------------
def _data_hash(st: RunState) -> str:
    return st.info(st.plan.data_key)["info"]["data_hash"]


def run_manifest(st: RunState) -> dict:
    """DESIGN 4.3 manifest of this run (config includes the report options and unit keys)."""
    from .manifest import build_manifest

    cfg = st.cfg
    config = {"profile_name": cfg.profile_name, "profile_file": cfg.profile_file,
              "run": cfg.settings, "tables": list(cfg.tables), "methods": list(cfg.methods),
              "perturbations": list(cfg.perturbations), "device": cfg.device,
              "workers": cfg.workers, "data": str(cfg.data) if cfg.data else None,
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
    from .manifest import peak_memory_mib

    lines = [st.cache.summary_line()]
    lines += [f"  {name:<9} {secs:8.2f} s" for name, secs in st.stage_times.items()]
    mem = peak_memory_mib()
    if mem:
        lines.append(f"  peak memory: {mem['self']:.0f} MiB (run), {mem['children']:.0f} MiB "
                     "(largest worker)")
    return lines


# --- the whole run --------------------------------------------------------------------------
STAGE_FUNCTIONS = (("data", "dataset", make_dataset), ("perturb", "perturbed", make_perturbed),
                   ("train", "checkpoint", train_method), ("predict", "prediction", predict_set),
                   ("evaluate", "metrics", evaluate_set), ("runtime", "runtime", time_method))


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
    for note in cfg.notes:
        log(note)
    if cache.removed_stale:
        log(f"removed {cache.removed_stale} unfinished unit(s) of an interrupted run")
    return RunState(cfg, cache, plan, log)


def run(cfg: RunConfig) -> RunState:
    """Plan, execute the missing units stage by stage, assemble results and report."""
    from .manifest import write_manifest

    t0 = time.perf_counter()
    st = start(cfg)
    try:
        for name, kind, fn in STAGE_FUNCTIONS:
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


def config_dict(cfg: RunConfig) -> dict:
    """The configuration as plain data (for ``--dry-run`` and tests)."""
    d = asdict(cfg)
    d["out"], d["data"] = str(cfg.out), str(cfg.data) if cfg.data else None
    return jsonable(d)


