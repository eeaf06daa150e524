"""A two-alternative forced-choice perceptual study, as GRIP's Table 1: make it, then score it.

**Making** (:func:`plan_pairs`, :func:`make_study`). The conditions are every method against
the ground truth and every two methods against each other. ``n_pairs`` regular trials are
spread over the conditions as evenly as possible (the first ``n_pairs % conditions`` get one
more); each condition cycles through the sequences in a seeded random order and puts each
side's method on the left in half of its trials (seeded). ``n_catch`` catch trials are added
on top: the ground truth beside an obviously broken copy of itself (hands displaced by
``CATCH_OFFSET`` along the world's up axis, or frozen at their first frame while the object
moves on), the ground truth's side being the expected answer; kinds and sides alternate and
are shuffled. All trials are shuffled together and numbered ``p001, p002, ...``. One seed
fixes everything, so the same inputs make the same key byte for byte.

Files: ``key.csv`` (``pair_id, sequence, left, right, is_catch, expected, video``; the
ground truth is ``ground_truth``, a broken copy ``catch:<kind>``), ``answers_template.csv``
(``participant, pair_id, choice``; one row per trial with the participant and choice blank),
``study.json`` (the settings) and, unless ``render=False``, ``videos/<pair_id>.mp4``
labelled only "A" (left) and "B" (right).

**Scoring** (:func:`aggregate`). Answers are ``left`` or ``right`` (blank = not answered,
skipped). A participant whose share of correct catch answers is below ``min_catch`` is
dropped whole (one who answered no catch trial is kept). For each condition, with the two
methods ``a`` and ``b`` (``a`` is the ``focus`` method when given, the ground truth is
always ``b``, otherwise alphabetical), the table gives the share of answers preferring each,
its 95% interval and the numbers of answers and participants. The interval is a seeded
bootstrap over participants (each resample draws participants with replacement and pools
their answers: answers of one person are not independent), or Wilson's score interval on
the pooled answers (``ci="wilson"``, which treats answers as independent).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, replace
from itertools import combinations
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..core import constants as C
from ..core.errors import InputError
from ..core.io import atomic_write_text

if TYPE_CHECKING:
    from ..data.sequence import Sequence
    from .video import RenderOptions

GT = "ground_truth"
CATCH_PREFIX = "catch:"
CATCH_KINDS = ("displaced", "frozen")
CATCH_OFFSET = 0.12  # m: hands lifted this far off the object in a "displaced" catch trial
KEY_COLUMNS = ("pair_id", "sequence", "left", "right", "is_catch", "expected", "video")
ANSWER_COLUMNS = ("participant", "pair_id", "choice")
CHOICES = ("left", "right")
CI_METHODS = ("bootstrap", "wilson")
WILSON_Z = 1.959963984540054  # two-sided 95%


@dataclass(frozen=True)
class Pair:
    """One trial: ``left`` / ``right`` are method names, ``GT`` or ``catch:<kind>``;
    ``expected`` is ``"left"``/``"right"`` for catch trials, ``""`` otherwise."""

    pair_id: str
    sequence: str
    left: str
    right: str
    is_catch: bool
    expected: str = ""
    video: str = ""


# --- making ----------------------------------------------------------------------------------
def conditions(methods: list[str]) -> list[tuple[str, str]]:
    """Every method against the ground truth, then every two methods, in the given order."""
    return [(m, GT) for m in methods] + list(combinations(methods, 2))


def _halves(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n,) bools, True in floor(n/2) or ceil(n/2) places (seeded): balanced sides."""
    return rng.permutation(np.arange(n) % 2 == 1)


def plan_pairs(sequences: list[str], methods: list[str], n_pairs: int, n_catch: int,
               seed: int) -> list[Pair]:
    """The trials of a study (see the module docstring); ``sequences`` are names like
    ``s1/mug_lift_1`` (sorted first, so the caller's order does not matter)."""
    if not sequences:
        raise InputError("no sequences to draw from", "--gt")
    if n_pairs < 0 or n_catch < 0:
        raise InputError(f"need --pairs >= 0 and --catch >= 0 (got {n_pairs}, {n_catch})",
                         "--pairs")
    seqs = sorted(sequences)
    conds = conditions(methods)
    rng = np.random.default_rng(seed)
    trials: list[Pair] = []
    for i, (a, b) in enumerate(conds):
        count = n_pairs // len(conds) + (i < n_pairs % len(conds))
        order = [seqs[j] for j in rng.permutation(len(seqs))]
        swap = _halves(rng, count)
        for j in range(count):
            left, right = (b, a) if swap[j] else (a, b)
            trials.append(Pair("", order[j % len(order)], left, right, False))
    gt_right = _halves(rng, n_catch)
    kinds = rng.permutation([CATCH_KINDS[j % len(CATCH_KINDS)] for j in range(n_catch)])
    for j in range(n_catch):
        broken = CATCH_PREFIX + str(kinds[j])
        seq = seqs[int(rng.integers(len(seqs)))]
        left, right = (broken, GT) if gt_right[j] else (GT, broken)
        trials.append(Pair("", seq, left, right, True, "right" if gt_right[j] else "left"))
    shuffled = [trials[k] for k in rng.permutation(len(trials))]
    width = max(3, len(str(len(shuffled))))
    return [replace(p, pair_id=f"p{i + 1:0{width}d}") for i, p in enumerate(shuffled)]


def broken_sequence(seq: Sequence, kind: str, up: np.ndarray) -> Sequence:
    """An obviously wrong copy of ``seq`` for a catch trial: ``"displaced"`` lifts both hands
    by ``CATCH_OFFSET`` m along ``up`` (3,); ``"frozen"`` holds both hands at frame 0."""
    if kind == "displaced":
        new = {s: {"transl": seq.hand_params(s)["transl"] + CATCH_OFFSET * np.asarray(up)}
               for s in ("right", "left")}
    elif kind == "frozen":
        T = seq.n_frames
        new = {s: {k: np.repeat(seq.hand_params(s)[k][:1], T, axis=0)
                   for k in ("global_orient", "hand_pose", "transl")}
               for s in ("right", "left")}
    else:
        raise InputError(f"unknown catch kind {kind!r} (known: {', '.join(CATCH_KINDS)})",
                         "catch")
    return seq.with_hands(**new)


def common_sequences(gt_dir: Path, preds: dict[str, Path]) -> list[str]:
    """Names (``s<k>/<stem>``) of the ground-truth sequences every prediction folder has."""
    from ..data.grab_io import list_sequences

    names = [f"{p.parent.name}/{p.stem}" for p in list_sequences(gt_dir)]
    for method, d in preds.items():
        have = {f"{p.parent.name}/{p.stem}" for p in list_sequences(d)}
        names = [n for n in names if n in have]
        if not names:
            raise InputError(f"no sequence of {gt_dir} is in the predictions of {method}",
                             f"--pred {method}={d}")
    return names


def _working_frames(path: Path) -> int:
    """Frames at the working rate, from the file's header (cheap)."""
    from ..data.grab_io import read_grab_header

    h = read_grab_header(path)
    return -(-int(h["n_frames"]) // round(h["framerate"] / C.FPS))


def check_lengths(pairs: list[Pair], gt_dir: Path, preds: dict[str, Path]) -> None:
    """Every method's sequence in a trial has as many frames as the ground truth's."""
    for p in pairs:
        n = _working_frames(gt_dir / "grab" / f"{p.sequence}.npz")
        for m in (p.left, p.right):
            if m in preds:
                path = preds[m] / "grab" / f"{p.sequence}.npz"
                k = _working_frames(path)
                if k != n:
                    raise InputError(f"{k} frames, but the ground truth has {n}", path)


def _csv(df: pd.DataFrame) -> str:
    return df.to_csv(index=False, lineterminator="\n")


def key_frame(pairs: list[Pair]) -> pd.DataFrame:
    """The key as a table, columns ``KEY_COLUMNS`` (``is_catch`` 0/1)."""
    rows = [{**asdict(p), "is_catch": int(p.is_catch)} for p in pairs]
    return pd.DataFrame(rows, columns=list(KEY_COLUMNS))


def _load(name: str, gt_dir: Path, preds: dict[str, Path], cache: dict, seq: str,
          model_path, up: str = "auto") -> Sequence:
    from ..data.grab_io import load_mano_backend, read_grab
    from .video import up_axis

    if (name, seq) not in cache:
        backend = load_mano_backend(model_path) if model_path else None
        if name.startswith(CATCH_PREFIX):
            gt = _load(GT, gt_dir, preds, cache, seq, model_path, up)
            cache[name, seq] = broken_sequence(gt, name[len(CATCH_PREFIX):],
                                               up_axis(gt, up))
        else:
            root = gt_dir if name == GT else preds[name]
            cache[name, seq] = read_grab(root / "grab" / f"{seq}.npz", mano_backend=backend)
    return cache[name, seq]


def render_pairs(pairs: list[Pair], gt_dir: Path, preds: dict[str, Path], out: Path,
                 opts: RenderOptions, model_path=None) -> list[Pair]:
    """Render ``videos/<pair_id>.mp4`` for every trial (labels "A" and "B" only); returns
    the pairs with their ``video`` paths (relative to ``out``)."""
    from ..data.posing import load_object_mesh_of
    from .video import render_pair

    done, cache, meshes = [], {}, {}
    for p in pairs:
        gt = _load(GT, gt_dir, preds, cache, p.sequence, model_path)
        if p.sequence not in meshes:
            meshes[p.sequence] = load_object_mesh_of(gt)
        left, right = (_load(m, gt_dir, preds, cache, p.sequence, model_path, opts.up)
                       for m in (p.left, p.right))
        rel = f"videos/{p.pair_id}.mp4"
        render_pair(left, right, ("A", "B"), out / rel, None, None, opts, model_path,
                    meshes[p.sequence], ref=gt)
        done.append(replace(p, video=rel))
    return done


def make_study(gt_dir: Path, preds: dict[str, Path], out: Path, n_pairs: int, seed: int,
               n_catch: int = 0, render: bool = True, opts: RenderOptions | None = None,
               model_path: str | os.PathLike | None = None) -> list[Pair]:
    """Plan, check, render (unless ``render=False``) and write a study into ``out``."""
    from .video import RenderOptions

    for name in preds:
        if name == GT or name.startswith(CATCH_PREFIX) or not name or "," in name:
            raise InputError(f"{name!r} is reserved or not a usable method name", "--pred")
    opts = opts or RenderOptions()
    gt_dir, preds = Path(gt_dir), {k: Path(v) for k, v in preds.items()}
    pairs = plan_pairs(common_sequences(gt_dir, preds), list(preds), n_pairs, n_catch, seed)
    check_lengths(pairs, gt_dir, preds)
    out = Path(out)
    if render:
        pairs = render_pairs(pairs, gt_dir, preds, out, opts, model_path)
    atomic_write_text(out / "key.csv", _csv(key_frame(pairs)))
    template = pd.DataFrame({"participant": "", "pair_id": [p.pair_id for p in pairs],
                             "choice": ""}, columns=list(ANSWER_COLUMNS))
    atomic_write_text(out / "answers_template.csv", _csv(template))
    settings = {"gt": str(gt_dir), "methods": {k: str(v) for k, v in preds.items()},
                "pairs": n_pairs, "catch": n_catch, "seed": seed, "rendered": render,
                "size": list(opts.size), "fps": opts.fps, "azimuth": opts.azimuth,
                "elevation": opts.elevation, "up": opts.up, "catch_offset_m": CATCH_OFFSET}
    atomic_write_text(out / "study.json", json.dumps(settings, indent=2) + "\n")
    return pairs


# --- scoring ---------------------------------------------------------------------------------
def _read_csv(path: Path, columns: tuple[str, ...], where: str) -> pd.DataFrame:
    if not Path(path).is_file():
        raise InputError("no such file", path)
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"not a readable CSV ({type(e).__name__})", path) from e
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)}", f"{path} ({where})")
    return df.apply(lambda c: c.str.strip())


def read_key(path: Path) -> pd.DataFrame:
    """``key.csv`` with ``is_catch`` as bool, checked."""
    key = _read_csv(path, KEY_COLUMNS[:-1], "--key")
    if key["pair_id"].duplicated().any():
        raise InputError("duplicate pair_id", path)
    if not key["is_catch"].isin(["0", "1"]).all():
        raise InputError("is_catch must be 0 or 1", path)
    key["is_catch"] = key["is_catch"] == "1"
    if not key.loc[key["is_catch"], "expected"].isin(CHOICES).all():
        raise InputError("catch trials need expected = left or right", path)
    return key


def read_answers(path: Path, key: pd.DataFrame) -> pd.DataFrame:
    """Answered rows of ``answers.csv`` (blank choices skipped), checked against ``key``."""
    ans = _read_csv(path, ANSWER_COLUMNS, "--answers")
    ans["choice"] = ans["choice"].str.lower()
    ans = ans[ans["choice"] != ""]
    bad = ans[~ans["choice"].isin(CHOICES)]
    if len(bad):
        raise InputError(f"choice must be left or right, got {bad['choice'].iloc[0]!r} "
                         f"(pair {bad['pair_id'].iloc[0]})", path)
    if (ans["participant"] == "").any():
        raise InputError("an answered row has no participant", path)
    unknown = sorted(set(ans["pair_id"]) - set(key["pair_id"]))
    if unknown:
        raise InputError(f"pair_id(s) not in the key: {', '.join(unknown[:5])}", path)
    dup = ans.duplicated(["participant", "pair_id"])
    if dup.any():
        r = ans[dup].iloc[0]
        raise InputError(f"participant {r['participant']} answered {r['pair_id']} twice", path)
    return ans.reset_index(drop=True)


def catch_accuracy(ans: pd.DataFrame, key: pd.DataFrame) -> pd.Series:
    """Share of correct catch answers per participant (NaN: answered no catch trial)."""
    merged = ans.merge(key, on="pair_id")
    catch = merged[merged["is_catch"]]
    correct = (catch["choice"] == catch["expected"]).groupby(catch["participant"]).mean()
    return correct.reindex(sorted(ans["participant"].unique()))


def _orient(a: str, b: str, focus: str | None) -> tuple[str, str]:
    """(method a, method b) of a row: the focus first, the ground truth last, else sorted."""
    if focus in (a, b):
        return (focus, b if a == focus else a)
    if GT in (a, b):
        return (b if a == GT else a, GT)
    return tuple(sorted((a, b)))


def wilson(k: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """Wilson score interval (lo, hi) of the proportion ``k / n``."""
    if n == 0:
        return (np.nan, np.nan)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def _interval(per: pd.DataFrame, ci: str, seed: int, n_boot: int) -> tuple[float, float, float]:
    """Share choosing a (pooled), interval; ``per``: columns k, n per participant."""
    from ..results.stats import weighted_bootstrap_ci

    k, n = int(per["k"].sum()), int(per["n"].sum())
    if n == 0:
        return (np.nan, np.nan, np.nan)
    if ci == "wilson":
        return (k / n, *wilson(k, n))
    r = weighted_bootstrap_ci(per["k"] / per["n"], per["n"], n_boot=n_boot, seed=seed)
    return (r.mean, r.lo, r.hi)


@dataclass
class StudyResult:
    """The table (one row per condition) and who was kept / dropped."""

    table: pd.DataFrame
    kept: list[str]
    dropped: list[str]
    min_catch: float
    ci: str
    seed: int
    n_boot: int


TABLE_COLUMNS = ("method_a", "method_b", "prefer_a_pct", "prefer_a_lo", "prefer_a_hi",
                 "prefer_b_pct", "prefer_b_lo", "prefer_b_hi", "n_answers", "n_participants")


def aggregate(key: pd.DataFrame, ans: pd.DataFrame, min_catch: float = 1.0,
              ci: str = "bootstrap", seed: int = C.BOOTSTRAP_SEED, n_boot: int = C.BOOTSTRAP_N,
              focus: str | None = None) -> StudyResult:
    """Score a study (see the module docstring); percentages in the table are 0..100."""
    if ci not in CI_METHODS:
        raise InputError(f"unknown interval {ci!r} (known: {', '.join(CI_METHODS)})", "--ci")
    if not 0.0 <= min_catch <= 1.0:
        raise InputError(f"must be in [0, 1], got {min_catch}", "--min-catch")
    acc = catch_accuracy(ans, key)
    dropped = sorted(acc.index[acc < min_catch - 1e-12])
    kept = sorted(set(acc.index) - set(dropped))
    m = ans[ans["participant"].isin(kept)].merge(key, on="pair_id")
    m = m[~m["is_catch"]]
    m = m.assign(chosen=np.where(m["choice"] == "left", m["left"], m["right"]),
                 cond=[_orient(a, b, focus) for a, b in zip(m["left"], m["right"], strict=True)])
    regular = key[~key["is_catch"]]
    conds = sorted({_orient(a, b, focus) for a, b in zip(regular["left"], regular["right"],
                                                         strict=True)},
                   key=lambda c: (focus not in c, GT not in c, c))
    rows = []
    for a, b in conds:
        sub = m[m["cond"] == (a, b)]
        per = (sub.assign(k=(sub["chosen"] == a).astype(int), n=1)
               .groupby("participant")[["k", "n"]].sum())
        pct, lo, hi = _interval(per, ci, seed, n_boot)
        rows.append({"method_a": a, "method_b": b, "prefer_a_pct": 100 * pct,
                     "prefer_a_lo": 100 * lo, "prefer_a_hi": 100 * hi,
                     "prefer_b_pct": 100 * (1 - pct), "prefer_b_lo": 100 * (1 - hi),
                     "prefer_b_hi": 100 * (1 - lo), "n_answers": int(per["n"].sum()),
                     "n_participants": len(per)})
    table = pd.DataFrame(rows, columns=list(TABLE_COLUMNS))
    return StudyResult(table, kept, dropped, min_catch, ci, seed, n_boot)


def _pct(x: float, lo: float, hi: float) -> str:
    if not np.isfinite(x):
        return "–"
    return f"{x:.1f} [{lo:.1f}, {hi:.1f}]"


def to_markdown(res: StudyResult) -> str:
    """Table 1-style markdown: one row per method pair, notes on participants and intervals."""
    how = ("seeded bootstrap over participants "
           f"({res.n_boot} resamples, seed {res.seed})" if res.ci == "bootstrap"
           else "Wilson score interval on the pooled answers")
    lines = ["### Perceptual study: which is more realistic?", "",
             "| A vs B | prefer A (%) [95% CI] | prefer B (%) [95% CI] | answers | participants |",
             "|---|---|---|---|---|"]
    for r in res.table.itertuples():
        lines.append(f"| {r.method_a} vs {r.method_b} | "
                     f"{_pct(r.prefer_a_pct, r.prefer_a_lo, r.prefer_a_hi)} | "
                     f"{_pct(r.prefer_b_pct, r.prefer_b_lo, r.prefer_b_hi)} | "
                     f"{r.n_answers} | {r.n_participants} |")
    dropped = ", ".join(res.dropped) if res.dropped else "none"
    lines += ["", f"Participants kept: {len(res.kept)}; dropped for failing catch trials "
              f"(fewer than {100 * res.min_catch:.0f}% correct): {len(res.dropped)} "
              f"({dropped}).", f"Intervals: 95%, {how}. Catch trials are not counted."]
    return "\n".join(lines) + "\n"


def write_result(res: StudyResult, out_md: Path) -> tuple[Path, Path]:
    """Write ``out_md`` (markdown) and the same table as CSV beside it (``.csv``)."""
    out_md = Path(out_md)
    out_csv = out_md.with_suffix(".csv")
    atomic_write_text(out_md, to_markdown(res))
    atomic_write_text(out_csv, _csv(res.table.round(4)))
    return out_md, out_csv
