"""The plan of a run: configuration from profile and command line, and every work unit
with the cache key that names its content (``docs/architecture.md``, "Cache keys").

A unit's key holds its configuration, the keys of the units it reads and a digest of the
code it runs (:mod:`grip_bench.bench.codehash`): the import closure of the unit's stage
module and, for a method's units, of the method's module, plus the method's version.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core import constants as C
from ..core.errors import InputError
from ..results.layout import CLEAN, MAIN_SPLIT
from .cache import Cache, jsonable, unit_key
from .codehash import CodeIndex

if TYPE_CHECKING:
    from ..methods.api import MethodSpec
    from ..metrics.evaluate import EvalOptions
    from ..report.tables import ColumnSpec

STAGES = ("data", "counterfactual", "perturb", "train", "predict", "evaluate", "sensitivity",
          "runtime", "validity", "report")
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


def run_settings(profile: dict, where: str | os.PathLike) -> dict:
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
    if s.get("validity_sequences", 0) < 0:  # optional key
        raise InputError(f"[run] validity_sequences is too small: {s['validity_sequences']}",
                         where=f"{where}: run.validity_sequences")
    if s.get("viewer_sequences", 0) < 0:  # optional key (runner's report stage)
        raise InputError(f"[run] viewer_sequences is too small: {s['viewer_sequences']}",
                         where=f"{where}: run.viewer_sequences")
    shard = s.get("shard_sequences", 0)  # optional key
    if isinstance(shard, bool) or not isinstance(shard, int) or shard < 0:
        raise InputError(f"[run] shard_sequences must be an integer >= 0 (0 = off): {shard!r}",
                         where=f"{where}: run.shard_sequences")
    if s.get("averaging", "sequence") not in ("sequence", "pooled"):  # optional key
        raise InputError("[run] averaging must be 'sequence' or 'pooled'",
                         where=f"{where}: run.averaging")
    run_seeds(s, where)  # optional key: checked here, used by the planner
    counterfactual_settings(s, where)  # optional keys: checked here, used by the planner
    from ..data.capture_noise import MODELS

    noise = s.get("capture_noise", "none")  # optional key
    if noise not in MODELS:
        raise InputError(f"[run] capture_noise must be one of {', '.join(map(repr, MODELS))}: "
                         f"{noise!r}", where=f"{where}: run.capture_noise")
    if noise != "none" and s["data"] != "synth":
        raise InputError("[run] capture_noise applies to generated SynthGRAB data (data = "
                         "'synth'); real GRAB is captured with its own noise",
                         where=f"{where}: run.capture_noise")
    return s


def run_seeds(settings: dict, where: str | os.PathLike = "profile") -> tuple[int, ...]:
    """The run's training seeds: ``[run] seed`` first (its rows keep the plain method names),
    then the other entries of ``[run] seeds`` in their order; ``seeds = []`` (or absent)
    is ``(seed,)``. A non-empty ``seeds`` must list ``seed`` and no seed twice."""
    seed, seeds = settings["seed"], settings.get("seeds", [])
    bad = [x for x in seeds if isinstance(x, bool) or not isinstance(x, int) or x < 0]
    if bad:
        raise InputError(f"[run] seeds must be integers >= 0: {bad[0]!r}",
                         where=f"{where}: run.seeds")
    if len(set(seeds)) != len(seeds):
        raise InputError(f"[run] seeds lists a seed twice: {list(seeds)}",
                         where=f"{where}: run.seeds")
    if seeds and seed not in seeds:
        raise InputError(f"[run] seeds {list(seeds)} must include seed = {seed} (the seed "
                         "whose rows keep the plain method names)", where=f"{where}: run.seeds")
    return (int(seed), *(int(x) for x in seeds if x != seed))


def counterfactual_settings(settings: dict,
                            where: str | os.PathLike = "profile") -> tuple[int, tuple[str, ...]]:
    """``([run] counterfactual_sources, [run] counterfactual_methods)``, checked: source
    episodes of the counterfactual geometry split (0, or absent: off) and the methods
    scored on it (``[]``: :func:`counterfactual_methods` picks them)."""
    n = settings.get("counterfactual_sources", 0)
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise InputError(f"[run] counterfactual_sources must be an integer >= 0 (0 = off): {n!r}",
                         where=f"{where}: run.counterfactual_sources")
    names = settings.get("counterfactual_methods", [])
    bad = [names] if not isinstance(names, list | tuple) else \
        [m for m in names if not isinstance(m, str) or not m]
    if bad:
        raise InputError(f"[run] counterfactual_methods must be method names: {bad[0]!r}",
                         where=f"{where}: run.counterfactual_methods")
    return int(n), tuple(dict.fromkeys(names))


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
    executor: str = "local"  # "local" (process pool) or "ray" (bench.ray_executor)
    address: str | None = None  # the Ray cluster (--address); None: a private local instance

    @property
    def seed(self) -> int:
        return int(self.settings["seed"])

    @property
    def seeds(self) -> tuple[int, ...]:
        """Training seeds, :attr:`seed` first (:func:`run_seeds`)."""
        return run_seeds(self.settings)

    def report_options(self) -> dict:
        """What ``report`` needs to re-render (saved in the manifest)."""
        s = self.settings
        return {"bootstrap_seed": s["bootstrap_seed"], "bootstrap_n": s["bootstrap_n"],
                "figure_methods": list(s["figure_methods"]), "split": MAIN_SPLIT,
                "averaging": s.get("averaging", "sequence")}


def parse_perturbation(label: str) -> tuple[str, float]:
    """``"T0.01"`` -> ``("T", 0.01)``: GRAB-T translation (m) or GRAB-R pose (rad) noise."""
    m = _PERTURBATION_RE.match(label)
    if not m:
        raise InputError(f"perturbation '{label}' should look like T0.01 or R0.3",
                         where="perturbations")
    return m.group(1), float(m.group(2))


def _select_tables(
    requested: Iterable[str] | None, settings_tables: Iterable[str]
) -> tuple[str, ...]:
    """Table ids from the command line, else the profile; empty or ``all``: every table."""
    from ..report.tables import TABLES

    names = list(requested or settings_tables)
    if not names or names == ["all"]:
        return tuple(TABLES.names())
    for name in names:
        TABLES.get(name)  # InputError listing the known tables
    return tuple(dict.fromkeys(names))


def _select_methods(
    requested: Iterable[str] | None, settings: dict, tables: Iterable[str]
) -> tuple[tuple[str, ...], list[str]]:
    """``(methods, notes)``: explicit methods (command line, then profile ``methods``), else
    every registered method the tables name plus ``extra_methods``.

    An explicit unknown method is an error; a table's or ``extra_methods``' method that is
    not registered (yet) is skipped with a note, and its cells stay empty ("–").
    """
    from ..methods.api import load_all
    from ..report.tables import TABLES

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


def make_config(profile: str, *, data: str | os.PathLike | None = None,
                out: str | os.PathLike | None = None, methods: Sequence[str] | None = None,
                tables: Sequence[str] | None = None, device: str | None = None,
                workers: int | None = None, model_path: str | None = None,
                progress: bool = True, executor: str = "local",
                address: str | None = None) -> RunConfig:
    """Resolve a :class:`RunConfig`; raises :class:`InputError` on bad choices."""
    name, prof, path = load_run_profile(profile)
    settings = run_settings(prof, path)
    if settings["data"] == "grab" and data is None:
        raise InputError(f"profile '{name}' runs on real GRAB data (SMPL-X / MANO): pass --data "
                         "DIR, the folder holding grab/ and tools/", where="--data")
    if data is not None and not Path(data).is_dir():
        raise InputError("data folder not found", where=data)
    if executor not in EXECUTORS:
        raise InputError(f"unknown executor {executor!r} ({' or '.join(EXECUTORS)})",
                         where="--executor")
    if address is not None and executor != "ray":
        raise InputError("only with --executor ray", where="--address")
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
        methods_explicit=bool(methods or settings["methods"]), executor=executor,
        address=address)


EXECUTORS = ("local", "ray")


def _check_device(device: str) -> None:
    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        raise InputError(f"unknown device '{device}' (cpu or cuda)", where="--device")
    if device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise InputError("CUDA is not available on this machine (use --device cpu)",
                             where="--device")


# --- the plan -------------------------------------------------------------------------------
# --- code in the keys ------------------------------------------------------------------------
# The module holding each unit kind's work; its import closure is the kind's code.
STAGE_MODULES = {"dataset": "data", "perturbed": "perturb", "checkpoint": "train",
                 "prediction": "predict", "metrics": "evaluate", "runtime": "runtime",
                 "validity": "validity", "counterfactual": "counterfactual",
                 "sensitivity": "sensitivity"}


# What a shard unit runs besides its kind's stage module ([run] shard_sequences > 0).
SHARD_MODULE = f"{__package__}.stages.shards"
# What a dataset unit with capture noise runs besides generation ([run] capture_noise).
CAPTURE_MODULE = f"{__package__}.stages.capture"


def stage_code(kind: str, *modules: str) -> str:
    """Digest of the code a unit of ``kind`` runs: the import closure of its stage module
    and of ``modules`` (a method's module: methods are found by name, not imported).
    Units that compute metrics also name the installed metric plug-ins' modules (the
    registry imports them through entry points, out of sight of the import closure)."""
    from ..core.plugins import METRICS_GROUP, plugin_modules

    entries = [f"{__package__}.stages.{STAGE_MODULES[kind]}", *modules]
    if kind in _METRIC_KINDS:
        entries += plugin_modules(METRICS_GROUP)
    return CodeIndex.installed().digest(entries)


_METRIC_KINDS = ("metrics", "validity", "sensitivity")  # unit kinds whose work computes metrics


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
    # sharded runs: prediction and metrics units are planned once the dataset unit exists
    # (their shards list its test sequences); the runner plans again after the data stage
    deferred: bool = False

    def of(self, kind: str) -> list[Unit]:
        return [u for u in self.units if u.kind == kind]

    def lines(self) -> list[str]:
        """Human-readable plan: one line per unit, ``[cached]`` or ``[todo]``."""
        return [f"{'[cached]' if self.cached[u.key] else '[todo]  '} {u.kind:<10} {u.label}"
                for u in self.units] + list(self.notes)


def _add(
    units: list[Unit],
    kind: str,
    title: str,
    inputs: dict,
    deps: Iterable[str] = (),
    **params: Any,
) -> Unit:
    unit = Unit(kind, unit_key(kind, inputs), title, {**params, "inputs": inputs}, tuple(deps))
    units.append(unit)
    return unit


def _data_unit(cfg: RunConfig, units: list[Unit]) -> Unit:
    s = cfg.settings
    if cfg.data is not None:
        from ..data.grab_io import dataset_hash

        source = dataset_hash(cfg.data)
        inputs = {"source": "import", "source_hash": source, "model_path": cfg.model_path,
                  "code": stage_code("dataset")}
        return _add(units, "dataset", f"import {cfg.data}", inputs, source_hash=source)
    inputs = {"source": "synthgrab", "profile": s["synth_profile"], "seed": s["data_seed"],
              "code": stage_code("dataset")}
    title = f"synthgrab profile={s['synth_profile']} seed={s['data_seed']}"
    noise = s.get("capture_noise", "none")
    if noise != "none":  # absent at "none", so noise-free keys are unchanged
        from ..data.capture_noise import MODELS

        inputs["capture_noise"] = {"model": noise, **asdict(MODELS[noise])}
        inputs["code"] = stage_code("dataset", CAPTURE_MODULE)
        title += f" capture_noise={noise}"
    return _add(units, "dataset", title, inputs)


def _table_cells(cfg: RunConfig) -> Iterator[tuple[ColumnSpec, dict]]:
    """``(column, filters)`` of every cell of the chosen tables."""
    from ..report.tables import TABLES

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
    from ..methods.api import METHODS

    needs = {m: {CLEAN} if METHODS.get(m).clean else set() for m in cfg.methods}
    for col, flt in _table_cells(cfg):
        pert = flt.get("perturbation", CLEAN)
        for method in _cell_methods(col, flt):
            if method in needs and pert in cfg.perturbations:
                needs[method].add(pert)
    order = [CLEAN, *cfg.perturbations]
    return {m: [p for p in order if p in sets] for m, sets in needs.items()}


def _method_inputs(spec: MethodSpec, kind: str) -> dict:
    """A method unit's identity: name, options, version and the code the unit runs (its
    stage module and the method's module, each with everything they import)."""
    return {"method": spec.name, "options": spec.options, "trainable": spec.trainable,
            "version": spec.version, "code": stage_code(kind, spec.factory.__module__)}


def _train_identity(spec: MethodSpec, method: object) -> dict:
    """What makes a checkpoint: the method, or its ``train_key()`` when it has one
    (``method``: ``spec.build()``).

    GRIP variants that differ only at inference (``grip`` / ``grip-no-rnet``) report the
    same train key, so they share one checkpoint unit instead of training twice.
    """
    ident = {"method": spec.name, "options": spec.options}
    train_key = getattr(method, "train_key", None)
    if callable(train_key):
        factory = f"{spec.factory.__module__}.{spec.factory.__qualname__}"
        ident = {"factory": factory, "train_key": train_key()}
    return {**ident, "version": spec.version,
            "code": stage_code("checkpoint", spec.factory.__module__)}


def _train_profile(method: object, profile: dict) -> dict:
    """The profile sections a method object's training reads: its ``profile_sections`` (a
    baseline's own section, GRIP's ``[grip]``), or every section but ``[run]`` for a method
    that declares none. A checkpoint's key holds only these, so editing ``[grip]`` retrains GRIP
    and leaves GrabNet's checkpoint cached (before s56 every checkpoint keyed the whole
    profile). Training is handed the same sections (``stages/train.py``)."""
    names = getattr(method, "profile_sections", None)
    if names is None:
        return {k: v for k, v in profile.items() if k not in ("run", "name")}
    return {k: profile[k] for k in names if k in profile}


Checkpoints = dict[tuple[str, int], Unit | None]  # (method, seed) -> its checkpoint unit


def _train_units(cfg: RunConfig, data: Unit, units: list[Unit]) -> Checkpoints:
    """A checkpoint unit per trainable method and seed (``[run] seeds``; the first seed's
    units are those of a single-seed run), None for a fixed method (its first seed only)."""
    from ..methods.api import METHODS

    out: Checkpoints = {}
    by_key: dict[str, Unit] = {}
    leaders: dict[tuple, str] = {}  # (family, seed) -> key of its first checkpoint unit
    for seed in cfg.seeds:
        for name in cfg.methods:
            spec = METHODS.get(name)
            if not spec.trainable:
                if seed == cfg.seed:
                    out[(name, seed)] = None
                continue
            method = spec.build()
            ident = _train_identity(spec, method)
            inputs = {**ident, "data": data.key, "profile": _train_profile(method, cfg.profile),
                      "seed": seed, "device": cfg.device}
            nproc = int(cfg.settings.get("train_nproc", 1))
            if nproc != 1:  # DDP equals one process only up to float rounding: its own unit
                inputs["nproc"] = nproc  # (absent at 1, so single-process keys are unchanged)
            key = unit_key("checkpoint", inputs)
            if key not in by_key:
                # variants of one family (same factory, a train_key) share cached features
                # and, per seed, ANet: the first builds them, the others start after it
                family = ident.get("factory")
                after = leaders.setdefault((family, seed), key) if family else None
                tag = "" if seed == cfg.seed else f" (seed {seed})"
                extra = {} if seed == cfg.seed else {"seed": seed}
                by_key[key] = _add(units, "checkpoint", f"train {name}{tag}", inputs, [data.key],
                                   method=name, after=None if after == key else after, **extra)
            out[(name, seed)] = by_key[key]
    return out


def _test_sets(cfg: RunConfig, data: Unit, units: list[Unit]) -> dict[str, Unit]:
    sets = {CLEAN: data}
    for label in cfg.perturbations:
        kind, sigma = parse_perturbation(label)
        inputs = {"data": data.key, "kind": kind, "sigma": sigma,
                  "seed": cfg.settings["perturb_seed"], "split": MAIN_SPLIT,
                  "code": stage_code("perturbed")}
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

    The clean set gets every leaderboard metric (the leaderboard shows them all) and the
    table-only ones (``MetricSpec.leaderboard`` False: the articulated hold test, the hold
    check's friction and gravity variants) where a chosen table reads them for that method;
    metrics the profile names (``[run] metrics``) go to every method. An ablation variant
    (``MethodSpec.variant_of``) is compared only in its tables; a perturbed set gets only
    those a chosen table reads on it for that method (Table 3: MPVPE, MPJPE; the physics
    table: its columns for the GRAB-T 0.01 input, not for the methods refining that input).
    This spares the costly physics and intersection metrics where nothing shows them.
    """
    from ..methods.api import METHODS
    from ..metrics.registry import METRICS

    named = list(cfg.settings["metrics"])
    chosen = named or METRICS.names()
    variant = method is not None and method in METHODS and METHODS.get(method).variant_of
    if label == CLEAN and not variant and named:
        return sorted(chosen)
    read = {flt.get("metric") for col, flt in _table_cells(cfg)
            if flt.get("perturbation", CLEAN) == label
            and (method is None or method in _cell_methods(col, flt)
                 or (not variant and flt.get("method") is None))}
    if label == CLEAN and not variant:
        return sorted(m for m in chosen if METRICS.get(m).leaderboard or m in read)
    return sorted(m for m in chosen if m in read)


def _cell_methods(col: ColumnSpec, flt: dict) -> set[str | None]:
    """The methods a table cell reads: its own and its column's ``before`` pairing's."""
    return {flt.get("method"), (col.before or {}).get("method")}


def _metric_inputs(cfg: RunConfig, label: str = CLEAN, method: str | None = None) -> dict:
    from ..metrics.registry import METRICS

    chosen = set_metrics(cfg, label, method)
    versions = {m: METRICS.get(m).version for m in chosen}
    return {"metrics": chosen, "versions": versions, "per_frame": cfg.settings["per_frame"],
            "options": asdict(eval_options(cfg)), "code": stage_code("metrics")}


def shard_sequences(cfg: RunConfig) -> int:
    """``[run] shard_sequences``: at most this many test sequences per prediction / metrics
    unit (0: one unit per method and test set, the keys of unsharded runs)."""
    return int(cfg.settings.get("shard_sequences", 0))


def sequence_shards(cfg: RunConfig, data: Unit, cache: Cache) -> list[list[str] | None] | None:
    """The sequence lists of a method's units on one test set: ``[None]`` (every sequence,
    one unit) when sharding is off; with ``[run] shard_sequences = N``, the dataset's test
    sequences (paths relative to its data folder, sorted as evaluation sorts them) in
    consecutive runs of at most N, so concatenating the shards' per-sequence outputs in
    order gives the unsharded outputs; None while the dataset unit is not built yet.
    Perturbed sets hold the same relative paths as the test split they perturb."""
    n = shard_sequences(cfg)
    if n <= 0:
        return [None]
    if not cache.has(data.key):
        return None
    from ..data.splits import sequences_in_split

    root = cache.path(data.key) / "data"
    rels = sorted(p.relative_to(root).as_posix() for p in sequences_in_split(root, MAIN_SPLIT))
    return [rels[i:i + n] for i in range(0, len(rels), n)]


def _predict_eval_units(
    cfg: RunConfig,
    plan_units: list[Unit],
    data: Unit,
    sets: dict[str, Unit],
    ckpts: Checkpoints,
    dataset: str,
    shards: list[list[str] | None],
) -> None:
    """Per method, seed and test set, a prediction unit and a metrics unit per shard (one
    shard, ``None``, without sharding: then neither inputs nor labels mention shards).

    A trainable method runs once per seed of ``[run] seeds``; the first seed's units and
    result rows are exactly a single-seed run's, a further seed's rows are labelled
    ``<method>@seed<N>`` (``report.tables.seed_label``) and its units carry ``seed`` in their
    parameters (the runner trains and predicts them with that seed)."""
    from ..methods.api import METHODS
    from ..report.tables import seed_label

    needs = method_needs(cfg)
    runs = [(name, seed) for seed in cfg.seeds for name in needs if (name, seed) in ckpts]
    for name, seed in runs:
        labels = needs[name]
        spec = METHODS.get(name)
        ckpt = ckpts[(name, seed)]
        first = seed == cfg.seed  # the first seed's units and rows are a single-seed run's
        row_name = name if first else seed_label(name, seed)
        stag = "" if first else f" (seed {seed})"
        extra = {} if first else {"seed": seed}
        for label in labels:
            src = sets[label]
            for i, seqs in enumerate(shards):
                part = {} if seqs is None else {"sequences": seqs}
                tag = "" if seqs is None else f" [shard {i + 1}/{len(shards)}]"
                # a shard also runs bench.stages.shards (unsharded keys stay as they were)
                shard_code = {} if seqs is None else {
                    "code": stage_code("prediction", spec.factory.__module__, SHARD_MODULE)}
                inputs = {
                    **_method_inputs(spec, "prediction"),
                    **shard_code,
                    "checkpoint": ckpt.key if ckpt else None,
                    "input": src.key,
                    "split": MAIN_SPLIT,
                    "seed": seed,
                    "device": cfg.device if spec.trainable else None,
                    **part,
                }
                deps = [src.key] + ([ckpt.key] if ckpt else [])
                pred = _add(plan_units, "prediction", f"predict {name} @ {label}{tag}{stag}",
                            inputs, deps, method=name, input=src.key,
                            checkpoint=ckpt.key if ckpt else None, perturbation=label, **part,
                            **extra)
                labels_ = {"method": row_name, "dataset": dataset, "split": MAIN_SPLIT,
                           "perturbation": label}
                metric_inputs = _metric_inputs(cfg, label, name)
                if seqs is not None:
                    metric_inputs["code"] = stage_code("metrics", SHARD_MODULE)
                _add(plan_units, "metrics", f"evaluate {row_name} @ {label}{tag}",
                     {**metric_inputs, "prediction": pred.key, "gt": data.key,
                      "labels": labels_, **part},
                     [pred.key, data.key], prediction=pred.key, gt=data.key, labels=labels_,
                     **part)


def timed_methods(cfg: RunConfig) -> list[str]:
    """Methods the runtime stage times: all of them when named explicitly, else those the
    chosen runtime tables list (timing every ablation variant would tell nothing new)."""
    from ..report.tables import TABLES

    if cfg.methods_explicit:
        return list(cfg.methods)
    named = {
        m for t in cfg.tables if TABLES.get(t).source == "runtime" for m in TABLES.get(t).methods()
    }
    return [m for m in cfg.methods if m in named]


def _runtime_units(cfg: RunConfig, data: Unit, ckpts: Checkpoints, units: list[Unit]) -> None:
    """Timing units of the first seed's checkpoints (a seed does not change the cost)."""
    from ..methods.api import METHODS

    s = cfg.settings
    for name in timed_methods(cfg):
        spec = METHODS.get(name)
        ckpt = ckpts[(name, cfg.seed)]
        inputs = {**_method_inputs(spec, "runtime"), "checkpoint": ckpt.key if ckpt else None,
                  "data": data.key, "device": cfg.device, "sequences": s["runtime_sequences"],
                  "repeats": s["runtime_repeats"], "seed": cfg.seed}
        _add(units, "runtime", f"time {name}", inputs, [data.key] + ([ckpt.key] if ckpt else []),
             method=name, checkpoint=ckpt.key if ckpt else None, data=data.key)


def _validity_unit(cfg: RunConfig, data: Unit, units: list[Unit]) -> None:
    """The metric-validity unit when ``[run] validity_sequences`` > 0: the dataset's first
    test sequences degraded at every level of ``metrics.validity.DEGRADATIONS`` and
    evaluated with the run's metrics on the validity budget (``validity_options``)."""
    from ..metrics.registry import METRICS
    from ..metrics.validity import degradation_levels, validity_options

    n = int(cfg.settings.get("validity_sequences", 0))
    if n <= 0:
        return
    options = replace(validity_options(eval_options(cfg)),
                      metrics=tuple(cfg.settings["metrics"]) or None)
    ids = options.metric_ids()
    inputs = {"data": data.key, "split": MAIN_SPLIT, "sequences": n, "seed": cfg.seed,
              "levels": degradation_levels(), "options": asdict(options),
              "versions": {m: METRICS.get(m).version for m in ids},
              "code": stage_code("validity")}
    _add(units, "validity", f"metric validity on {n} sequence(s)", inputs, [data.key])


# --- the counterfactual geometry split ([run] counterfactual_sources > 0) --------------------
# Learned methods of the leaderboard scored on the split besides Table 2's rows (its GRIP
# variants and probes) when [run] counterfactual_methods is empty (docs/counterfactual.md).
CF_LEADERBOARD_METHODS = ("grip", "grip-blind", "nearest-neighbour", "nearest-arm",
                          "grabnet-smplx", "manipnet")
CF_TABLE = "table2_ablation"  # whose methods are scored by default (with the list above)
CF_PREDICTION_SET = "counterfactual"  # ``test_set`` of the split's prediction units


def counterfactual_methods(cfg: RunConfig) -> tuple[list[str], list[str]]:
    """``(methods, notes)``: the methods scored on the counterfactual split, in the run's
    method order. ``[run] counterfactual_methods`` when given (each must be one of the run's
    methods, predict the clean split and not be named like a reference row of the table);
    else the methods of Table 2 (``CF_TABLE``) and ``CF_LEADERBOARD_METHODS`` that this run
    has, with a note naming those it has not."""
    from ..methods.api import METHODS
    from ..report.sensitivity import REFERENCES
    from ..report.tables import TABLES

    _, named = counterfactual_settings(cfg.settings)
    where = f"{cfg.profile_file}: run.counterfactual_methods"
    if named:
        for name in named:
            METHODS.get(name)  # InputError listing the known methods
            if name in REFERENCES:
                raise InputError(f"{name!r} is a reference row of the geometry-sensitivity "
                                 "table, scored from the data itself; name methods", where)
            if name not in cfg.methods:
                run = ", ".join(cfg.methods)
                raise InputError(f"{name!r} is not one of this run's methods ({run}): add it "
                                 "to [run] methods or extra_methods", where)
            if not METHODS.get(name).clean:
                raise InputError(f"{name!r} does not predict the clean test split", where)
        return list(named), []
    wanted = set(CF_LEADERBOARD_METHODS)
    if CF_TABLE in TABLES:
        wanted |= set(TABLES.get(CF_TABLE).methods())
    wanted -= set(REFERENCES)
    chosen = [m for m in cfg.methods if m in wanted and METHODS.get(m).clean]
    missing = sorted(wanted - set(chosen))
    notes = [f"counterfactual: not in this run, not scored: {', '.join(missing)}"] \
        if missing else []
    return chosen, notes


def _counterfactual_units(cfg: RunConfig, data: Unit, ckpts: Checkpoints,
                          units: list[Unit]) -> list[str]:
    """With ``[run] counterfactual_sources`` > 0 on generated data: the split's dataset unit
    (kind ``counterfactual``), a prediction unit per scored method and seed of ``[run]
    seeds`` (its checkpoint on the split; further seeds labelled ``<method>@seed<N>``,
    untrained methods once; no metrics unit, so nothing reaches ``results.csv``) and one
    ``sensitivity`` unit scoring them all. Returns notes for the run's log; on imported
    data, or when none of the run's methods is scored, the split is skipped with a note.

    Nothing here enters another unit's inputs: with the key at 0 (or absent) every key is
    what it was before these keys existed."""
    from ..methods.api import METHODS
    from ..report.tables import seed_label

    n, _ = counterfactual_settings(cfg.settings)
    if n == 0:
        return []
    s = cfg.settings
    if cfg.data is not None or s["data"] != "synth":
        return [f"counterfactual: counterfactual_sources = {n} skipped: the split is made by "
                "the SynthGRAB generator, and this run's data is imported (real GRAB or "
                "--data), so there is no generator to make pairs of its test objects"]
    methods, notes = counterfactual_methods(cfg)
    if not methods:
        return [*notes, f"counterfactual: counterfactual_sources = {n} skipped: none of this "
                "run's methods is scored on the split"]
    if s.get("capture_noise", "none") != "none":
        notes.append("counterfactual: the split is generated without capture noise (a pair's "
                     "members must differ in the object's shape only)")
    inputs = {"source": "synthgrab-counterfactual", "profile": s["synth_profile"],
              "seed": s["data_seed"], "sources": n,
              "constants": {"variants": C.CF_VARIANTS, "intents": C.CF_INTENTS,
                            "twin_tries": C.CF_TWIN_TRIES, "min_change": C.CF_MIN_CHANGE,
                            "split": C.CF_SPLIT},
              "code": stage_code("counterfactual")}
    cf = _add(units, "counterfactual",
              f"counterfactual split: synthgrab profile={s['synth_profile']} "
              f"seed={s['data_seed']} sources={n}", inputs)
    preds: dict[str, str] = {}
    # every seed of [run] seeds that has a checkpoint: the first seed's units are a
    # single-seed run's, a further seed's rows are ``<method>@seed<N>`` as in the tables
    runs = [(name, seed) for seed in cfg.seeds for name in methods if (name, seed) in ckpts]
    for name, seed in runs:
        spec, ckpt = METHODS.get(name), ckpts[(name, seed)]
        first = seed == cfg.seed  # untrained methods have the first seed only (_train_units)
        inputs = {**_method_inputs(spec, "prediction"), "checkpoint": ckpt.key if ckpt else None,
                  "input": cf.key, "split": MAIN_SPLIT, "seed": seed,
                  "device": cfg.device if spec.trainable else None,
                  "train_data": data.key}  # PredictContext.data_dir: retrieval reads it
        deps = [cf.key, data.key] + ([ckpt.key] if ckpt else [])
        extra = {} if first else {"seed": seed}
        stag = "" if first else f" (seed {seed})"
        # perturbation "none": a clean test set (PredictContext.refine stays False)
        pred = _add(units, "prediction", f"predict {name} @ {CF_PREDICTION_SET}{stag}", inputs,
                    deps, method=name, input=cf.key, checkpoint=ckpt.key if ckpt else None,
                    perturbation=CLEAN, test_set=CF_PREDICTION_SET, **extra)
        preds[name if first else seed_label(name, seed)] = pred.key
    from ..report.sensitivity import TABLE_VERSION

    inputs = {"data": cf.key, "predictions": preds, "model_path": cfg.model_path,
              "min_gt_rms": C.CF_MIN_GT_RMS, "table_version": TABLE_VERSION,
              "code": stage_code("sensitivity")}
    _add(units, "sensitivity", f"geometry sensitivity of {len(preds)} method(s)", inputs,
         [cf.key, *preds.values()], data=cf.key, predictions=preds)
    return notes


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
    shards = sequence_shards(cfg, data, cache)
    if shards is not None:
        _predict_eval_units(cfg, units, data, sets, ckpts, dataset, shards)
    cf_notes = _counterfactual_units(cfg, data, ckpts, units)
    _runtime_units(cfg, data, ckpts, units)
    _validity_unit(cfg, data, units)
    order = {k: i for i, k in enumerate(("dataset", "counterfactual", "perturbed", "checkpoint",
                                          "prediction", "metrics", "sensitivity", "runtime",
                                          "validity"))}
    units.sort(key=lambda u: order[u.kind])  # stable: plan order within a kind
    cached = {u.key: cache.has(u.key) for u in units}
    notes = [] if shards is not None else [
        f"note: shard_sequences = {shard_sequences(cfg)}: the prediction and metrics units "
        "are planned once the dataset unit exists (their shards list its test sequences)"]
    notes += cf_notes
    return Plan(units, cached, data.key, dataset, notes, deferred=shards is None)


def eval_options(cfg: RunConfig) -> EvalOptions:
    """Evaluation options of the run (metrics.evaluate.EvalOptions); part of the metric keys."""
    from ..metrics.evaluate import EvalOptions

    return EvalOptions(model_path=cfg.model_path, up=world_up(cfg),
                       max_physics_frames=int(cfg.settings["physics_frames"]),
                       max_iv_frames=int(cfg.settings["iv_frames"]))


def config_dict(cfg: RunConfig) -> dict:
    """The configuration as plain data (for ``--dry-run`` and tests)."""
    d = asdict(cfg)
    d["out"], d["data"] = str(cfg.out), str(cfg.data) if cfg.data else None
    return jsonable(d)
