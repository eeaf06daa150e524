"""``grip-bench bench``: each hardware floor measured on this machine, then each stage against it.

This machine's absolute speed moves 10-30 % from run to run, so every goal is a ratio to a
floor measured **in the same run** (docs/performance.md):

- floors (:func:`measure_floors`): sgemm fp32 / bf16 GFLOP/s with ``torch.addmm`` (the op
  ``grip.frozen.FrozenMLP`` runs) at the GEMM shapes of GRIP's paper-width blocks and at a
  square reference size; GEMV bandwidth GB/s (fp32 weights larger than the last-level
  cache, ``torch.mv``); one exact signed-distance query (libigl through
  ``geometry.distance``, us per point); one manifold3d boolean of a hand with an object (ms);
- stages (:func:`measure_stages`): GRIP offline frames/s (1 x 300 and 16 x 120 frames, fp32
  and bf16), online latency (batch 1, one new frame), the stage-one sensors (both hands),
  exact intersection volume pairs/s per core, MuJoCo stability tests/s per core, each with
  its floor, ratio (floor time / stage time) and goal where one is defined.

Inputs are one SynthGRAB grasping episode made by the package's own generator (one object,
one subject, about a second), written to a temporary folder for the command's duration;
GRIP's networks are built at the paper's widths with seeded random weights (speed does not
depend on the values). Every measurement is repeated (``Settings.repeats``) and reported as
the median with its spread.
"""

from __future__ import annotations

import contextlib
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

    from ..data.library import ObjectLibrary
    from ..data.sequence import Sequence

PARTS = ("floors", "grip", "sensors", "iv", "physics")
LONG_FRAMES = 300  # one sequence per call: 10 s at 30 fps, about a GRAB sequence
SHORT_FRAMES, N_SHORT = 120, 16  # throughput mode: 16 sequences of 120 frames per call
IV_PUSH = 0.003  # m; held hands are moved this far into the object so every pair needs a boolean
PHYSICS_TESTS = 8  # MuJoCo tests per repeat (the tables' physics_frames per sequence and hand)
DATA_TESTS, DATA_TESTS_QUICK = 48, 16  # tested frames of a dataset timed per repeat (--data)
GEMV_MIN_BYTES, GEMV_MAX_BYTES = 256 * 2**20, 1024 * 2**20
Progress = Callable[[str], None]


# --- settings, samples, goals, rows ---------------------------------------------------------------
def default_threads() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


@dataclass(frozen=True)
class Settings:
    """``repeats``: samples per measurement (median reported); ``quick``: smaller workloads
    and shorter samples; ``threads``: torch intra-op threads for every measurement (IV and
    physics run pinned to one core); ``min_sample_s``: a GEMM sample loops at least this long."""

    repeats: int = 5
    quick: bool = False
    threads: int = field(default_factory=default_threads)
    min_sample_s: float = 0.2
    data: str | None = None  # a GRAB-layout folder: the hold test also on its tested frames
    data_split: str = "test"
    model_path: str | None = None  # MANO / SMPL-X models for real GRAB data

    @classmethod
    def make(cls, quick: bool = False, repeats: int | None = None,
             threads: int | None = None, data: str | None = None, data_split: str = "test",
             model_path: str | None = None) -> Settings:
        return cls(repeats=repeats or (2 if quick else 5), quick=quick,
                   threads=threads or default_threads(), min_sample_s=0.05 if quick else 0.2,
                   data=data, data_split=data_split, model_path=model_path)


@dataclass
class Sample:
    """Repeated measurement ``values`` (one per repeat) in ``unit``."""

    values: list[float]
    unit: str

    @property
    def median(self) -> float:
        return float(statistics.median(self.values))

    @property
    def spread(self) -> float:
        """(max - min) / median: the run-to-run spread of the repeats (0 for one repeat)."""
        m = self.median
        return float((max(self.values) - min(self.values)) / m) if m else 0.0


@dataclass
class Floor:
    """A hardware floor: ``sample`` (its repeats), what it is and how it was measured."""

    key: str
    name: str
    sample: Sample
    detail: dict = field(default_factory=dict)

    @property
    def value(self) -> float:
        return self.sample.median

    def as_dict(self) -> dict:
        return {"key": self.key, "name": self.name, "value": self.value, "unit": self.sample.unit,
                "spread": self.sample.spread, "samples": self.sample.values,
                "detail": self.detail}


@dataclass(frozen=True)
class Goal:
    """``kind``: ``"min_ratio"`` (floor time / stage time >= value), ``"max_time"`` (stage
    time <= value, in the row's unit) or ``"min_rate"`` (the row's rate >= value)."""

    kind: str
    value: float
    text: str

    def met(self, row: Row) -> bool | None:
        """Whether ``row`` meets the goal; None when the row lacks the number it needs."""
        got = {"min_ratio": row.ratio, "max_time": row.time, "min_rate": row.rate}[self.kind]
        if got is None or not np.isfinite(got):
            return None
        return bool(got <= self.value) if self.kind == "max_time" else bool(got >= self.value)


@dataclass
class Row:
    """One stage: median ``time`` per unit of work (``unit``, e.g. ms/frame), ``rate`` (work per
    second, ``rate_unit``), ``floor`` (the floor's time for the same work, same unit) and
    ``ratio`` = floor / time (1 = at the floor), ``goal`` and whether it is met."""

    stage: str
    time: float
    unit: str
    rate: float | None = None
    rate_unit: str = ""
    floor: float | None = None
    floor_name: str = ""
    goal: Goal | None = None
    spread: float = 0.0
    note: str = ""
    samples: list[float] = field(default_factory=list)
    # where one call's time went: {part: (time per unit of work in `unit`, its floor or None)}
    parts: dict[str, tuple[float, float | None]] = field(default_factory=dict)

    @property
    def ratio(self) -> float | None:
        return None if self.floor is None or not self.time else self.floor / self.time

    @property
    def met(self) -> bool | None:
        return None if self.goal is None else self.goal.met(self)

    def as_dict(self) -> dict:
        d = asdict(self)
        d.update(ratio=self.ratio, met=self.met, goal=None if self.goal is None else
                 {"kind": self.goal.kind, "value": self.goal.value, "text": self.goal.text})
        return d


def row_from(stage: str, sample: Sample, per: float, unit: str, rate_unit: str,
             scale: float = 1e3, **kw) -> Row:
    """A :class:`Row` from seconds per repeat ``sample`` covering ``per`` units of work:
    time in ``unit`` (``scale`` x seconds per unit), rate in units per second."""
    per_unit = [v / per for v in sample.values]
    med = float(statistics.median(per_unit))
    return Row(stage, med * scale, unit, rate=1.0 / med if med else None, rate_unit=rate_unit,
               spread=Sample(per_unit, "s").spread, samples=[v * scale for v in per_unit], **kw)


# --- formatting -----------------------------------------------------------------------------
def _num(x: float | None, digits: int = 3) -> str:
    if x is None or not np.isfinite(x):
        return "—"
    return f"{x:.{digits}g}" if abs(x) < 10 ** digits else f"{x:,.0f}"


def format_floors(floors: dict[str, Floor]) -> str:
    """Markdown table ``floor | value | spread | how``."""
    lines = ["| floor | value | spread | measured as |", "|---|---|---|---|"]
    for f in floors.values():
        how = f.detail.get("how", "")
        lines.append(f"| {f.name} | {_num(f.value)} {f.sample.unit} | "
                     f"{f.sample.spread:.0%} | {how} |")
    return "\n".join(lines)


def format_rows(rows: list[Row]) -> str:
    """Markdown table ``stage | time | floor | ratio | goal | met?``."""
    lines = ["| stage | time | floor | ratio | goal | met? |", "|---|---|---|---|---|---|"]
    for r in rows:
        time_s = f"{_num(r.time)} {r.unit} (±{r.spread / 2:.0%})"
        if r.rate is not None:
            time_s += f", {_num(r.rate)} {r.rate_unit}"
        floor = "—" if r.floor is None else f"{_num(r.floor)} {r.unit} ({r.floor_name})"
        ratio = "—" if r.ratio is None else f"{r.ratio:.0%}"
        goal = "—" if r.goal is None else r.goal.text
        met = {None: "—", True: "yes", False: "**no**"}[r.met]
        note = f" {r.note}" if r.note else ""
        lines.append(f"| {r.stage}{note} | {time_s} | {floor} | {ratio} | {goal} | {met} |")
    return "\n".join(lines)


def format_parts(rows: list[Row]) -> str:
    """Markdown table ``stage | part | time | share | floor | ratio`` of the rows that carry
    a breakdown (GRIP offline: where one call's time goes, each part against its own FLOP
    floor): the measured reason behind a row's ratio."""
    lines = ["| stage | part | time | share | floor | ratio |", "|---|---|---|---|---|---|"]
    for r in rows:
        total = sum(t for t, _ in r.parts.values())
        for name, (t, floor) in r.parts.items():
            share = f"{t / total:.0%}" if total else "—"
            ratio = "—" if floor is None or not t else f"{floor / t:.0%}"
            lines.append(f"| {r.stage} | {name} | {_num(t)} {r.unit} | {share} | "
                         f"{'—' if floor is None else _num(floor)} | {ratio} |")
    return "\n".join(lines) if len(lines) > 2 else ""


# --- timing helpers -------------------------------------------------------------------------
def repeat(fn: Callable[[], object], repeats: int) -> Sample:
    """Seconds of each of ``repeats`` calls of ``fn`` (after one warm-up call)."""
    fn()
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return Sample(out, "s")


def looped_rate(fn: Callable[[], object], work: float, settings: Settings) -> Sample:
    """``work`` / seconds per call of ``fn``, each sample looping until ``min_sample_s``."""
    fn()
    t0, n = time.perf_counter(), 0
    while n < 3 or time.perf_counter() - t0 < settings.min_sample_s / 4:
        fn()
        n += 1
    per_call = (time.perf_counter() - t0) / n
    inner = max(1, int(settings.min_sample_s / max(per_call, 1e-9)))
    rates = []
    for _ in range(settings.repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        rates.append(work * inner / (time.perf_counter() - t0))
    return Sample(rates, "")


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


@contextlib.contextmanager
def one_core() -> Iterator[bool]:
    """Pin this process to one of its cores (per-core rates: manifold3d and BLAS may use more);
    yields whether pinning was possible."""
    try:
        cores = os.sched_getaffinity(0)
    except AttributeError:
        yield False
        return
    os.sched_setaffinity(0, {min(cores)})
    try:
        yield True
    finally:
        os.sched_setaffinity(0, cores)


# --- GEMM shapes and floors -----------------------------------------------------------------
def gemm_flops(m: int, k: int, n: int) -> int:
    """FLOPs of ``(m, k) @ (k, n)``: one multiply and one add per term (the bias is O(m n))."""
    return 2 * m * k * n


def grip_block_shapes() -> list[tuple[int, int]]:
    """(K, N) of the two GEMMs of a paper-width residual block (``fc1``: width -> hidden,
    ``fc2``: hidden -> width): equal FLOPs each, most of GRIP's network FLOPs."""
    from ..core import constants as C

    return [(C.GRIP_WIDTH, C.GRIP_HIDDEN), (C.GRIP_HIDDEN, C.GRIP_WIDTH)]


def grip_batch_rows() -> dict[str, int]:
    """Rows per GEMM call: one 300-frame sequence, and 16 sequences (the pipeline's ``BATCH``
    frames per network call)."""
    from ..grip.pipeline import BATCH

    return {"1seq": LONG_FRAMES, "16seq": min(BATCH, N_SHORT * SHORT_FRAMES)}


def sgemm_rate(m: int, k: int, n: int, dtype: torch.dtype, settings: Settings) -> Sample:
    """GFLOP/s of ``torch.addmm(bias, x (m, k), w (n, k).T)`` in ``dtype``."""
    import torch

    g = torch.Generator().manual_seed(0)
    x = torch.randn(m, k, generator=g).to(dtype)
    w = torch.randn(n, k, generator=g).to(dtype)
    b = torch.randn(n, generator=g).to(dtype)
    s = looped_rate(lambda: torch.addmm(b, x, w.T), gemm_flops(m, k, n) / 1e9, settings)
    return Sample(s.values, "GFLOP/s")


def llc_bytes() -> int | None:
    """Size of the largest CPU cache (Linux sysfs), None when unknown."""
    sizes = []
    for p in Path("/sys/devices/system/cpu/cpu0/cache").glob("index*/size"):
        txt = p.read_text().strip()
        mult = {"K": 2**10, "M": 2**20, "G": 2**30}.get(txt[-1:], 1)
        with contextlib.suppress(ValueError):
            sizes.append(int(txt.rstrip("KMG")) * mult)
    return max(sizes) if sizes else None


def gemv_bandwidth(settings: Settings, nbytes: int | None = None) -> tuple[Sample, dict]:
    """GB/s of ``torch.mv`` on fp32 weights of ``nbytes`` (default 2x the last-level cache,
    256 MiB - 1 GiB: streamed from memory on every call)."""
    import torch

    llc = llc_bytes()
    if nbytes is None:
        nbytes = int(np.clip(2 * (llc or 0), GEMV_MIN_BYTES, GEMV_MAX_BYTES))
    cols = 4096
    rows = max(nbytes // (4 * cols), 1)
    w = torch.full((rows, cols), 0.5)
    x = torch.ones(cols)
    s = looped_rate(lambda: torch.mv(w, x), rows * cols * 4 / 1e9, settings)
    size = rows * cols * 4
    detail = {"matrix": [rows, cols], "bytes": size, "llc_bytes": llc,
              "larger_than_llc": llc is not None and size > llc,
              "how": f"torch.mv fp32 {rows}x{cols} ({size / 2**20:.0f} MiB, "
                     f"LLC {'?' if llc is None else f'{llc / 2**20:.0f} MiB'})"}
    return Sample(s.values, "GB/s"), detail


def grip_weight_bytes() -> int:
    """fp32 bytes of GRIP's paper-width networks (ANet + CNet + RNet parameters)."""
    from ..grip import ANetConfig, CNetConfig, RNetConfig

    return sum(weight_bytes({"n": c.build()}) for c in (ANetConfig(), CNetConfig(), RNetConfig()))


def best_sgemm(floors: dict[str, Floor], prec: str) -> Floor:
    """The fastest sgemm floor measured in ``prec`` (GRIP's block shapes or the square
    reference): the rate this machine demonstrably sustains, so no stage can beat its floor."""
    return max((f for k, f in floors.items() if k.startswith(f"sgemm_{prec}_")),
               key=lambda f: f.value)


def _sgemm_floors(settings: Settings, progress: Progress) -> dict[str, Floor]:
    import torch

    from ..core.cpu import cpu_info

    native = cpu_info().native_bf16
    out = {}
    square = 1024 if settings.quick else 2048
    for prec, dtype in (("fp32", torch.float32), ("bf16", torch.bfloat16)):
        tag = prec if prec == "fp32" or native else "bf16 (emulated)"
        for label, m in grip_batch_rows().items():
            samples = [sgemm_rate(m, k, n, dtype, settings) for k, n in grip_block_shapes()]
            # equal FLOPs per shape: the block's rate is the harmonic mean of the two
            vals = [float(statistics.harmonic_mean(v)) for v in zip(*[s.values for s in samples],
                                                                     strict=True)]
            key = f"sgemm_{prec}_{label}"
            out[key] = Floor(key, f"sgemm {tag}, GRIP block, M={m}", Sample(vals, "GFLOP/s"), {
                "m": m, "shapes_kn": grip_block_shapes(), "precision": prec, "native": native,
                "per_shape_gflops": [s.median for s in samples],
                "how": f"addmm M={m}, K x N = 1024x2048 and 2048x1024 (harmonic mean)"})
            progress(f"floor {out[key].name}: {out[key].value:.1f} GFLOP/s")
        key = f"sgemm_{prec}_square"
        s = sgemm_rate(square, square, square, dtype, settings)
        out[key] = Floor(key, f"sgemm {tag}, square {square}", s,
                         {"m": square, "precision": prec, "native": native,
                          "how": f"addmm {square}^3 (reference)"})
        progress(f"floor {out[key].name}: {out[key].value:.1f} GFLOP/s")
    return out


def measure_floors(settings: Settings, scene: Scene | None = None,
                   progress: Progress = lambda s: None) -> dict[str, Floor]:
    """Every floor (sgemm, GEMV, exact distance, manifold3d boolean); ``scene`` supplies the
    object and hand meshes (built when None)."""
    with torch_threads(settings.threads):
        out = _sgemm_floors(settings, progress)
        s, detail = gemv_bandwidth(settings)
        out["gemv_fp32"] = Floor("gemv_fp32", "GEMV fp32 bandwidth, > LLC", s, detail)
        progress(f"floor GEMV > LLC: {s.median:.1f} GB/s")
        s, detail = gemv_bandwidth(settings, grip_weight_bytes())
        out["gemv_fp32_grip"] = Floor("gemv_fp32_grip", "GEMV fp32 bandwidth, GRIP's weight size",
                                      s, detail)
        progress(f"floor GEMV at GRIP's weight size: {s.median:.1f} GB/s")
        scene = scene or build_scene(Path(tempfile.mkdtemp(prefix="grip-bench-perf-")))
        out["exact_distance"] = _exact_distance_floor(scene, settings)
        progress(f"floor exact distance: {out['exact_distance'].value:.2f} us/point")
    out["manifold_boolean"] = _manifold_floor(scene, settings)
    progress(f"floor manifold3d boolean: {out['manifold_boolean'].value:.2f} ms")
    return out


def _exact_distance_floor(scene: Scene, settings: Settings) -> Floor:
    """us per point of ``DistanceField.exact_signed_distance`` on hand vertices near the
    object (one call over every held frame's proximity-range vertices)."""
    pts = scene.near_points(2000 if settings.quick else 20000)
    field = scene.library.field(scene.seq.obj_name)
    s = repeat(lambda: field.exact_signed_distance(pts), settings.repeats)
    return Floor("exact_distance", "exact signed distance (libigl)",
                 Sample([v / len(pts) * 1e6 for v in s.values], "us/point"),
                 {"points": len(pts), "how": f"exact_signed_distance, {len(pts)} hand "
                                             "vertices within 2 cm"})


def _manifold_floor(scene: Scene, settings: Settings) -> Floor:
    """ms of one ``(hand ^ object).volume()`` with both Manifolds built beforehand, pinned to
    one core (the IV stage's per-core setting)."""
    from ..metrics.intersection import to_manifold

    hand = scene.iv_pairs(1)[0]
    vo = np.asarray(scene.mesh.vertices, np.float64)
    origin = 0.5 * (vo.min(axis=0) + vo.max(axis=0))
    a = to_manifold(hand, scene.faces, origin)
    b = to_manifold(vo, scene.mesh.faces, origin)
    with one_core() as pinned:
        s = repeat(lambda: (a ^ b).volume(), max(2 * settings.repeats + 1, 9))
    return Floor("manifold_boolean", "manifold3d boolean, hand x object",
                 Sample([v * 1e3 for v in s.values], "ms"),
                 {"hand_faces": len(scene.faces), "object_faces": len(scene.mesh.faces),
                  "pinned_one_core": pinned,
                  "how": f"(hand ^ object).volume(), {len(scene.faces)} + "
                         f"{len(scene.mesh.faces)} faces, 1 core"})


# --- the scene ------------------------------------------------------------------------------
@dataclass
class Scene:
    """One SynthGRAB grasping episode in a temporary dataset folder: ``seq`` (as generated),
    ``long`` (300 frames) and ``short`` (16 windows of 120 frames), the object ``mesh``, and
    the held hand's object-frame vertices ``held_local (K, V, 3)`` with ``faces``."""

    root: Path
    library: ObjectLibrary
    seq: Sequence
    long: Sequence
    short: list[Sequence]
    mesh: object
    side: str
    held: np.ndarray  # (K,) held frame indices of ``side``
    held_local: np.ndarray
    faces: np.ndarray
    pair: object  # metrics.evaluate.SequencePair of seq with itself

    def near_points(self, n: int) -> np.ndarray:
        """Up to ``n`` object-frame hand vertices ``(n, 3)`` within 2 cm of the object."""
        sd = self.pair.track("gt", self.side).sd[self.held]
        pts = self.held_local[np.abs(sd) < 0.02]
        return pts[np.linspace(0, len(pts) - 1, min(n, len(pts))).astype(int)]

    def iv_pairs(self, k: int) -> np.ndarray:
        """``k`` held hands ``(k, V, 3)`` (object frame), each moved ``IV_PUSH`` towards the
        object's centre so that every pair needs the boolean (GT grasps barely touch)."""
        idx = np.linspace(0, len(self.held) - 1, k).astype(int)
        hands = self.held_local[idx]
        centre = 0.5 * (self.mesh.bounds[0] + self.mesh.bounds[1])
        d = centre - hands.mean(axis=1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return hands + IV_PUSH * d[:, None, :]


def ping_pong(n: int, length: int) -> np.ndarray:
    """``length`` frame indices playing ``0..n-1`` forward, then backward, ... (continuous)."""
    period = np.r_[np.arange(n), np.arange(n - 2, 0, -1)] if n > 1 else np.zeros(1, int)
    return period[np.arange(length) % len(period)]


def build_scene(root: Path) -> Scene:
    """Generate one grasping episode (a "lift" of a cup by subject 1) into ``root``."""
    from ..data.library import ObjectLibrary
    from ..data.synth.episode import make_episode
    from ..data.synth.generate import write_meshes
    from ..data.synth.objects import make_object_set
    from ..data.synth.world import make_subjects
    from ..metrics.evaluate import EvalOptions, SequencePair
    from ..metrics.intersection import FailureCounter

    with torch_threads(1):  # the generator's own setting (data.synth.generate.run_group)
        inst = make_object_set(0, 1, ["cup"])[0]
        seq = make_episode(make_subjects(2, 0)[0], inst, "lift",
                           np.random.SeedSequence([0, 0, 0])).sequence
        write_meshes(root, [inst])
        library = ObjectLibrary(root)
        library.field(seq.obj_name)  # built once per object, outside every timing
        pair = SequencePair(seq, seq, library, EvalOptions(), FailureCounter())
        side = max(("left", "right"), key=lambda s: int(pair.held(s).sum()))
        held = np.flatnonzero(pair.held(side))
        track = pair.track("gt", side)
    long = seq.take(ping_pong(seq.n_frames, LONG_FRAMES))
    starts = np.linspace(0, max(seq.n_frames - SHORT_FRAMES, 0), N_SHORT).astype(int)
    short = [long.frames(int(a), int(a) + SHORT_FRAMES) for a in starts]
    return Scene(root, library, seq, long, short, library.mesh(seq.obj_name), side, held,
                 track.local[held], np.asarray(pair.poser.faces(side)), pair)


# --- stages ---------------------------------------------------------------------------------
def paper_nets() -> dict:
    """GRIP's three networks at the paper's widths, seeded random weights, eval mode; ANet's
    residual head zeroed as in training (the denoised arms stay on the sequence)."""
    import torch

    from ..grip import ANetConfig, CNetConfig, RNetConfig

    torch.manual_seed(0)
    nets = {"anet": ANetConfig().build(), "cnet": CNetConfig().build(),
            "rnet": RNetConfig().build()}
    torch.nn.init.zeros_(nets["anet"].decoder.head.weight)
    torch.nn.init.zeros_(nets["anet"].decoder.head.bias)
    return {k: n.eval() for k, n in nets.items()}


def weight_bytes(nets: dict) -> int:
    """Bytes of every parameter of ``nets`` in fp32 (what one batch-1 frame streams)."""
    return sum(4 * p.numel() for n in nets.values() for p in n.parameters())


def _rnet_rows(pipe: object, run: Callable[[], object]) -> int:
    """Rows RNet processes in one ``run()`` (interaction frames; both hands per row)."""
    rows = [0]
    hook = pipe.nets["rnet"].register_forward_pre_hook(
        lambda _m, args: rows.__setitem__(0, rows[0] + len(args[0])))
    try:
        run()
    finally:
        hook.remove()
    return rows[0]


# GripPipeline methods timed by _grip_parts, in call order, and the network each one runs
_GRIP_PARTS = (("ANet recursion + arm FK", "arms_and_wrists_many", "anet"),
               ("stage-one inputs (sensors, body context)", "_cnet_inputs", None),
               ("CNet", "_run_cnet", "cnet"),
               ("RNet + its proximity", "refine_many", "rnet"))


def _grip_parts(pipe: object, run: Callable[[], object], frames: int, net_flops: dict,
                rate: float) -> dict[str, tuple[float, float | None]]:
    """One timed ``run()`` split over the pipeline's parts (``_GRIP_PARTS``; "other" is the
    rest): ``{part: (ms per frame, its network's FLOP floor in ms per frame or None)}``.
    ``net_flops``: FLOPs per frame of each network as the pipeline runs it."""
    spent = dict.fromkeys([name for name, _, _ in _GRIP_PARTS], 0.0)
    nested = [0]  # refine_many inside a timed part must not be counted twice

    def timed(name: str, fn: Callable) -> Callable:
        def wrapper(*a: object, **k: object) -> object:
            nested[0] += 1
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                nested[0] -= 1
                if nested[0] == 0:
                    spent[name] += time.perf_counter() - t0
        return wrapper

    for name, attr, _ in _GRIP_PARTS:
        setattr(pipe, attr, timed(name, getattr(pipe, attr)))
    try:
        t0 = time.perf_counter()
        run()
        total = time.perf_counter() - t0
    finally:
        for _, attr, _ in _GRIP_PARTS:
            delattr(pipe, attr)  # back to the class's methods
    out = {name: (spent[name] / frames * 1e3,
                  None if net is None else net_flops[net] / rate * 1e3)
           for name, _, net in _GRIP_PARTS}
    out["other (FK of the hands, array work)"] = (
        max(total - sum(spent.values()), 0.0) / frames * 1e3, None)
    return out


def _grip_offline(scene: Scene, nets: dict, floors: dict, settings: Settings,
                  progress: Progress) -> list[Row]:
    from ..core.cpu import cpu_info
    from ..grip import ANetConfig, CNetConfig, RNetConfig
    from ..grip.flops import pipeline_flops_parts, pipeline_flops_per_frame
    from ..grip.pipeline import GripPipeline, Options
    from ..grip.train import Variant

    native = cpu_info().native_bf16
    rows = []
    short = scene.short[:4] if settings.quick else scene.short
    for label, seqs in (("1seq", [scene.long]), ("16seq", short)):
        frames = sum(s.n_frames for s in seqs)
        for prec in ("fp32", "bf16"):
            pipe = GripPipeline(nets, Options(Variant(), precision=prec))
            run = lambda p=pipe, s=seqs: p.run_many(s, scene.library)  # noqa: E731
            share = _rnet_rows(pipe, run) / frames  # also the warm-up
            flops = pipeline_flops_per_frame(CNetConfig(), ANetConfig(), RNetConfig(), share)
            best = best_sgemm(floors, prec)
            rate = best.value * 1e9
            sample = repeat(run, settings.repeats)
            what = f"{len(seqs)} x {seqs[0].n_frames}" if label == "16seq" else \
                f"1 x {frames}"
            emulated = prec == "bf16" and not native
            goal = (Goal("min_ratio", 0.88, ">= 88 % of sgemm floor") if prec == "fp32" else
                    None if emulated else Goal("min_ratio", 0.5, ">= 50 % of bf16 floor"))
            net_flops = pipeline_flops_parts(CNetConfig(), ANetConfig(), RNetConfig(), share)
            rows.append(row_from(
                f"GRIP offline {prec}{' (emulated)' if emulated else ''}, {what} frames",
                sample, frames, "ms/frame", "frames/s", floor=flops / rate * 1e3,
                floor_name=f"{flops / 1e9:.3f} GFLOP/frame at {best.name}",
                goal=goal, note=f"(RNet on {share:.0%} of frames)",
                parts=_grip_parts(pipe, run, frames, net_flops, rate)))
            progress(f"{rows[-1].stage}: {rows[-1].rate:.0f} frames/s, "
                     f"{rows[-1].ratio:.0%} of floor")
    return rows


def _grip_online(scene: Scene, nets: dict, floors: dict, settings: Settings,
                 progress: Progress) -> list[Row]:
    """Latency of one new frame, batch 1: the streaming pipeline on the window (t-1, t)."""
    from ..grip.pipeline import GripPipeline, Options
    from ..grip.train import Variant

    held = scene.held
    t = int(held[len(held) // 2])
    window = scene.seq.frames(t - 1, t + 1)
    gemv = max((floors[k] for k in ("gemv_fp32", "gemv_fp32_grip") if k in floors),
               key=lambda f: f.value)
    floor_ms = weight_bytes(nets) / (gemv.value * 1e9) * 1e3
    rows = []
    for prec in ("fp32", "bf16"):
        pipe = GripPipeline(nets, Options(Variant(), online=True, precision=prec))
        n = max(settings.repeats * 4, 10)
        sample = repeat(lambda p=pipe: p.run(window, scene.library), n)
        ms = np.asarray(sample.values) * 1e3
        p95 = float(np.percentile(ms, 95))
        row = row_from(f"GRIP online {prec}, 1 frame (batch 1) p50", sample, 1, "ms",
                       "frames/s", floor=floor_ms if prec == "fp32" else floor_ms / 2,
                       floor_name=f"{weight_bytes(nets) / 2**20 / (1 if prec == 'fp32' else 2):.0f}"
                                  f" MiB weights / {gemv.name}",
                       note=f"(p95 {p95:.1f} ms)")
        rows.append(row)
        progress(f"{row.stage}: {row.time:.1f} ms (p95 {p95:.1f} ms)")
    return rows


def _grip_stream(scene: Scene, nets: dict, floors: dict, settings: Settings,
                 progress: Progress) -> list[Row]:
    """Latency of ``GripStream.step`` (only the new frame's work, state kept across calls)
    over consecutive frames of the long sequence, fp32 and int8, against the batch-1 floor:
    the weights' bytes (1/4 in int8) at the GEMV rate at GRIP's weight size."""
    from ..grip.stream import GripStream, frame_of
    from ..grip.train import Variant

    gemv = floors["gemv_fp32_grip" if "gemv_fp32_grip" in floors else "gemv_fp32"]
    seq, rows = scene.long, []
    n = min(max(settings.repeats * 12, 30), seq.n_frames - 3)
    frames = [frame_of(seq, t) for t in range(n + 3)]
    for prec, per_weight, goal in (
            ("fp32", 4, Goal("min_ratio", 1 / 1.5, "p50 <= 1.5x floor")),
            ("int8", 1, Goal("max_time", 5.0, "p50 <= 5 ms"))):
        stream = GripStream(nets, Variant(), scene.library, seq.obj_name, precision=prec,
                            height=seq.height, hand_scale=seq.hand_scale, fps=seq.fps)
        for f in frames[:3]:  # warm-up: the kernels' first calls, caches
            stream.step(f)
        secs = []
        for f in frames[3:]:
            t0 = time.perf_counter()
            stream.step(f)
            secs.append(time.perf_counter() - t0)
        floor_ms = weight_bytes(nets) * per_weight / 4 / (gemv.value * 1e9) * 1e3
        row = row_from(f"GRIP stream {prec}, GripStream.step (batch 1) p50", Sample(secs, "s"),
                       1, "ms", "frames/s", floor=floor_ms, goal=goal,
                       floor_name=f"{weight_bytes(nets) * per_weight / 4 / 2**20:.0f} MiB "
                                  f"weights / {gemv.name}",
                       note=f"(p95 {1e3 * float(np.percentile(secs, 95)):.1f} ms, {n} frames)")
        rows.append(row)
        progress(f"{row.stage}: {row.time:.1f} ms ({row.note[1:-1]})")
    return rows


def _sensors(scene: Scene, settings: Settings, progress: Progress) -> list[Row]:
    """Stage one on the 300-frame sequence: both hands' ambient (1024 points) and mean-hand
    proximity (99 vertices), as the pipeline and the feature cache run it (``stage_one``:
    hand -> world -> object per point and hand), and in the batched form the stream runs
    (``stage_one_rigid``: one composed map per hand and frame, both hands per query)."""
    from ..core.frames import NET_SIDES
    from ..sensors import hand_to_object, stage_one, stage_one_rigid, wrist_frames

    seq = scene.long
    field = scene.library.field(seq.obj_name)

    def rigid() -> object:
        wrists = [wrist_frames(seq, side) for side in NET_SIDES]
        M, c = hand_to_object(seq.object_rotations(), np.asarray(seq.object["transl"], float),
                              np.stack([w[0] for w in wrists], 1),
                              np.stack([w[1] for w in wrists], 1))
        return stage_one_rigid(field, M, c, seq.hand_scale or 1.0)

    rows = []
    for what, fn in (("", lambda: stage_one(scene.library, seq, None, "distance")),
                     (", rigid maps (the stream's form)", rigid)):
        sample = repeat(fn, settings.repeats)
        rows.append(row_from(f"sensors, both hands{what} ({seq.n_frames} frames per call)",
                             sample, seq.n_frames, "ms/frame", "frames/s",
                             goal=Goal("max_time", 0.1, "<= 0.1 ms/frame")))
        progress(f"{rows[-1].stage}: {rows[-1].time:.3f} ms/frame")
    return rows


def _iv(scene: Scene, floors: dict, settings: Settings, progress: Progress) -> list[Row]:
    """Exact IV per pair on one core: penetrating held hands (every pair a boolean), and the
    metric's own path on the GT held frames (most are cleared by the signed distances)."""
    from ..metrics.evaluate import intersection_volumes
    from ..metrics.intersection import intersection_volume_batch

    k = 8 if settings.quick else 32
    hands = scene.iv_pairs(k)
    track = scene.pair.track("gt", scene.side)
    local, sd = track.local[scene.held], track.sd[scene.held]
    goal = Goal("min_rate", 300.0, ">= 300 pairs/s/core")
    floor = None
    if "manifold_boolean" in floors:  # again, just before: the load on a shared core drifts
        again = _manifold_floor(scene, settings)
        again.key, again.name = "manifold_boolean_at_iv", f"{again.name}, just before IV"
        floors[again.key] = again
        floor = floors["manifold_boolean_at_iv"].value
    with one_core() as pinned:
        pen = repeat(lambda: intersection_volume_batch(hands, scene.faces, scene.mesh),
                     settings.repeats)
        gt = repeat(lambda: intersection_volumes(local, sd, scene.faces, scene.mesh),
                    settings.repeats)
    core = "1 core" if pinned else "not pinned"
    rows = [row_from(f"exact IV, penetrating pairs ({k} per call, {core})", pen, k, "ms/pair",
                     "pairs/s", floor=floor, goal=goal,
                     floor_name="one manifold3d boolean, re-measured just before"),
            row_from(f"exact IV, metric path on GT held frames ({len(local)}, {core})", gt,
                     len(local), "ms/pair", "pairs/s", goal=goal)]
    for r in rows:
        progress(f"{r.stage}: {r.rate:.0f} pairs/s")
    return rows


def _physics(scene: Scene, settings: Settings, progress: Progress) -> list[Row]:
    """MuJoCo stability per tested frame, as ``metrics.evaluate.simulate_frame`` runs it in
    the tables (paper: 5 steps; hold: 1 s), on one core. The content caches of hand pieces and
    compiled scenes are emptied before each repeat: the tables test distinct frames, so they
    never hit there. The object's CoACD pieces are cached per mesh (computed before timing)."""
    from ..metrics import physics
    from ..metrics.evaluate import simulate_frame

    pair = scene.pair
    physics.convex_decomposition(pair.mesh)
    k = 4 if settings.quick else PHYSICS_TESTS
    frames = scene.held[np.linspace(0, len(scene.held) - 1, k).astype(int)]

    def run(protocol: str) -> None:
        physics._HAND_CACHE.clear()
        physics._MODEL_CACHE.clear()
        pair._sims.clear()
        for t in frames:
            simulate_frame(pair, int(t), protocol)

    rows = []
    with one_core() as pinned:
        core = "1 core" if pinned else "not pinned"
        for protocol in ("paper", "hold"):
            sample = repeat(lambda p=protocol: run(p), settings.repeats)
            rows.append(row_from(
                f"physics {protocol} test ({physics.protocol_steps(protocol)} steps, {core})",
                sample, k, "ms/test", "tests/s"))
            progress(f"{rows[-1].stage}: {rows[-1].rate:.1f} tests/s")
        rows.append(_articulated_hold(pair, frames, settings, core))
        progress(f"{rows[-1].stage}: {rows[-1].rate:.1f} tests/s")
        if settings.data is not None:
            rows += _dataset_hold(settings, core, progress)
            progress(f"{rows[-1].stage}: {rows[-1].rate:.1f} tests/s")
    return rows


def _articulated_hold(pair, frames: np.ndarray, settings: Settings, core: str) -> Row:
    """The articulated hold test (``metrics.hold``, the physics table's ``hold_sim``: build the
    scene, its hand pieces bounded on the frame's pose, compile it, 0.2 s settle, 1 s hold
    under the frame's gravity) on the same ground-truth frames (:func:`_hold_row`)."""
    return _hold_row([(pair, int(t)) for t in frames], settings,
                     f"physics articulated hold test (settle + 1 s, {core})")


def _hold_row(chosen: list[tuple[object, int]], settings: Settings, stage: str,
              as_run: bool = False) -> Row:
    """One articulated hold test per (sequence pair, frame) of ``chosen`` a repeat, against
    the issue's goal of 20 tests/s a core. The sequences' hand tracks, the hand model's pieces
    and the objects' pieces are built before timing (a run shares them with every other
    metric); each repeat builds every scene anew.

    ``as_run``: each frame's scene serves the tests a run computes on it for the physics
    table (``metrics.evaluate._hold_runs``): the six gravity directions at mu = 1 after one
    settle (the world's gravity is one of them: ``hold_sim`` and ``hold_sim_axes``), the
    world's at each ``HOLD_MU_SENSITIVITY`` friction and at each ``HOLD_GRIP_SENSITIVITY``
    grip strength (a settle each, since s52), so a test's time is the scene's shared among
    them; no goal (the goal's row is one test a scene)."""
    from ..core import constants as C
    from ..metrics import hold
    from ..metrics.evaluate import object_pose, posed_hands

    for pair, t in chosen:  # warm: tracks, hand model pieces, object pieces
        posed_hands(pair, t)
        hold.object_pieces(pair.mesh)

    def run() -> None:
        for pair, t in chosen:
            hands = posed_hands(pair, t)
            scene = hold.hand_scene(hands, pair.mesh, object_pose(pair, t), pair.options.up)
            if not as_run:
                hold.hold(scene, pair.options.up)
                continue
            hold.hold(scene, pair.options.up, hold.AXES)
            for mu in C.HOLD_MU_SENSITIVITY:
                hold.hold(scene, pair.options.up, (None,), mu)
            for grip in C.HOLD_GRIP_SENSITIVITY:
                hold.hold(scene, pair.options.up, (None,), C.SIM_FRICTION, grip)

    sample = repeat(run, settings.repeats)
    if as_run:
        return row_from(stage, sample, len(chosen) * _tests_per_scene(), "ms/test", "tests/s")
    return row_from(stage, sample, len(chosen), "ms/test", "tests/s",
                    goal=Goal("min_rate", 20.0, ">= 20 tests/s/core"))


def tested_frames(data_dir: Path, split: str = "test", model_path: str | None = None,
                  pred_dir: Path | None = None, library: ObjectLibrary | None = None,
                  progress: str | None = None) -> Iterator[tuple[object, list[int]]]:
    """Per sequence of ``split``: its ``metrics.evaluate.SequencePair`` (the prediction of the
    same name in ``pred_dir`` against the ground truth; None: the ground truth itself) and its
    tested held frames, the physics table's (``physics_frames`` of every hand, sorted).
    ``library``: an ``ObjectLibrary`` of ``data_dir`` to share between calls; ``progress``:
    a label for a sequence counter on stderr (None: quiet)."""
    from ..data.grab_io import read_grab
    from ..data.library import ObjectLibrary
    from ..data.splits import sequences_in_split
    from ..metrics.evaluate import EvalOptions, SequencePair, physics_frames
    from ..metrics.intersection import FailureCounter

    lib = library if library is not None else ObjectLibrary(data_dir)
    opts = EvalOptions(model_path=model_path)
    files = sequences_in_split(data_dir, split)
    for i, path in enumerate(files):
        gt = read_grab(path)
        pred = gt if pred_dir is None else read_grab(Path(pred_dir) / path.relative_to(data_dir))
        pair = SequencePair(pred, gt, lib, opts, FailureCounter())
        yield pair, sorted({int(t) for s in opts.sides for t in physics_frames(pair, s)})
        if progress is not None:
            print(f"\r{progress}{i + 1}/{len(files)} sequences", end="", file=sys.stderr,
                  flush=True)
    if progress is not None:
        print(file=sys.stderr)


def _dataset_hold(settings: Settings, core: str, progress: Progress) -> list[Row]:
    """The articulated hold test (:func:`_hold_row`) on a dataset's ground truth:
    ``DATA_TESTS`` of the physics table's tested frames of ``settings.data_split`` (16 with
    ``--quick``), spread evenly over all of them. Issue #15 states its goal on the default data,
    where most objects fall and a test stops once they fall free, so the first row (one test
    a scene) is the goal's measure; the second times the same frames as a run computes them
    (a scene's ten tests, ``as_run``)."""
    data = Path(settings.data)
    progress(f"reading the {settings.data_split} split of {data}")
    chosen = [(pair, t) for pair, frames in tested_frames(data, settings.data_split,
                                                          settings.model_path)
              for t in frames]
    if not chosen:
        from ..core.errors import InputError

        raise InputError(f"no tested held frames in the {settings.data_split} split", data)
    n = DATA_TESTS_QUICK if settings.quick else DATA_TESTS
    chosen = [chosen[i] for i in np.unique(np.linspace(0, len(chosen) - 1, n).astype(int))]
    what = f"{data.name} {settings.data_split} split ({len(chosen)} tested frames, {core})"
    rows = [_hold_row(chosen, settings, f"physics articulated hold test, {what}")]
    progress(f"{rows[-1].stage}: {rows[-1].rate:.1f} tests/s")
    rows.append(_hold_row(chosen, settings, "physics articulated hold tests as a run computes "
                          f"them ({_tests_per_scene()} a scene), {what}", as_run=True))
    return rows


def _tests_per_scene() -> int:
    """The articulated hold tests a run computes on one tested frame's scene for the physics
    table: the six gravity directions at mu = 1 and the world's at each sensitivity friction
    and grip strength."""
    from ..core import constants as C
    from ..metrics.hold import AXES

    return len(AXES) + len(C.HOLD_MU_SENSITIVITY) + len(C.HOLD_GRIP_SENSITIVITY)


def measure_stages(settings: Settings, floors: dict[str, Floor], scene: Scene,
                   only: tuple[str, ...] = PARTS,
                   progress: Progress = lambda s: None) -> list[Row]:
    """Every stage in ``only`` (of ``PARTS``, "floors" aside) against ``floors``; a stage
    whose floor was not measured gets none."""
    rows: list[Row] = []
    with torch_threads(settings.threads):
        if "grip" in only:
            nets = paper_nets()
            if {"sgemm_fp32_square", "sgemm_bf16_square"} <= floors.keys():
                rows += _grip_offline(scene, nets, floors, settings, progress)
            else:
                raise ValueError("the GRIP rows need the sgemm floors (measure 'floors' too)")
            if "gemv_fp32" in floors:
                rows += _grip_online(scene, nets, floors, settings, progress)
                rows += _grip_stream(scene, nets, floors, settings, progress)
        if "sensors" in only:
            rows += _sensors(scene, settings, progress)
        if "iv" in only:
            rows += _iv(scene, floors, settings, progress)
        if "physics" in only:
            rows += _physics(scene, settings, progress)
    return rows


# --- the whole benchmark --------------------------------------------------------------------
def _stderr(msg: str) -> None:
    print(f"[bench] {msg}", file=sys.stderr, flush=True)


def run_bench(settings: Settings, only: tuple[str, ...] = PARTS,
              progress: Progress = _stderr) -> dict:
    """Floors then stages; returns the JSON-ready result (``floors``, ``rows``, ``settings``,
    the load average before and after, wall seconds). GRIP's rows need the floors, so they
    are measured whenever "grip" is asked for."""
    unknown = [p for p in only if p not in PARTS]
    if unknown:
        raise ValueError(f"unknown part(s) {unknown} (known: {', '.join(PARTS)})")
    load0, t0 = os.getloadavg(), time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="grip-bench-perf-") as tmp:
        progress("generating one SynthGRAB episode")
        scene = build_scene(Path(tmp))
        progress(f"scene: {scene.seq.name}, {scene.seq.n_frames} frames, "
                 f"{len(scene.held)} held frames ({scene.side})")
        want_floors = "floors" in only or "grip" in only or "iv" in only
        floors = measure_floors(settings, scene, progress) if want_floors else {}
        rows = measure_stages(settings, floors, scene, only, progress)
    return {"settings": asdict(settings), "only": list(only),
            "loadavg_before": list(load0), "loadavg_after": list(os.getloadavg()),
            "wall_s": time.perf_counter() - t0,
            "floors": {k: f.as_dict() for k, f in floors.items()},
            "rows": [r.as_dict() for r in rows],
            "tables": {"floors": format_floors(floors), "stages": format_rows(rows),
                       "parts": format_parts(rows)}}
