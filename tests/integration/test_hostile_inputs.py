"""Hostile inputs through the real command line (issue #18; catalogue: docs/hostile_inputs.md).

Every case asserts: exit code 1, exactly one line ``error: <file>: <what>`` on stderr that
names the file and the field, no traceback, no pickled code run, and nothing already
computed lost (earlier outputs and finished cache units are byte-identical afterwards).
Mesh cases live in ``tests/integration/test_hostile_meshes.py``.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from grip_bench.cli.main import main
from grip_bench.core import io as core_io
from grip_bench.core.safe_pickle import load_npz
from tests.grab_fixtures import write_dataset
from tests.hostile_fixtures import (
    DELETE,
    OBJECT_FIELDS,
    Payload,
    edited,
    valid_members,
    write_members,
)

T = 12  # frames of the fixture sequence


# --- helpers ---------------------------------------------------------------------------------
def _cli(capsys, *argv: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _cli_proc(*argv: str, timeout: float = 300, prefix: tuple[str, ...] = ()
              ) -> subprocess.CompletedProcess:
    """The CLI in its own process (``prefix``: e.g. setpriv to drop privileges)."""
    return subprocess.run([*prefix, sys.executable, "-m", "grip_bench", *map(str, argv)],
                          capture_output=True, text=True, timeout=timeout)


def assert_one_line_error(rc: int, err: str, where: str | Path, *fragments: str) -> str:
    """Exit code 1 and one ``error: <where>...`` line, the last on stderr (progress notes may
    precede it), holding ``fragments``; no traceback."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 1, err
    assert "Traceback" not in err, err
    assert sum(ln.startswith("error:") for ln in lines) == 1 and lines[-1].startswith("error:"), err
    line = lines[-1]
    assert line.startswith(f"error: {where}"), (line, where)
    for frag in fragments:
        assert frag in line, (frag, line)
    return line


def _snapshot(folder: Path, skip: tuple[str, ...] = ("run.log",)) -> dict[str, bytes]:
    """Every file's bytes (the run log is appended to by design)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in skip}


# --- sequence files: one hostile file each, read by `grip-bench data info` ------------------
def _set(dotted, value):
    return lambda m, tmp: edited(m, dotted, value)


def _pickle(dotted):
    return lambda m, tmp: edited(m, dotted, Payload(tmp / "PWNED"))


def _raw(fn):
    """A case built from the valid file's bytes: ``fn(bytes) -> bytes``."""
    def build(m, tmp):
        good = write_members(tmp / "good.npz", m)
        return fn(good.read_bytes())
    return build


def _flip_data_byte(raw: bytes) -> bytes:
    """Flip bytes inside a member's stored data (its CRC no longer matches)."""
    b = bytearray(raw)
    with zipfile.ZipFile(__import__("io").BytesIO(raw)) as zf:
        info = zf.getinfo("framerate.npy")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    b[start + info.compress_size - 1] ^= 0xFF
    return bytes(b)


def _zip_of(members: dict[str, bytes]) -> bytes:
    import io

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def _npy_lying_header() -> bytes:
    """A ``.npy`` whose header claims 8 GB of float64 but that holds 8 bytes."""
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buf, {"descr": "<f8", "fortran_order": False, "shape": (10**9,)})
    return _zip_of({"framerate.npy": buf.getvalue() + b"\0" * 8})


def _f32(shape, fill=0.0):
    return np.full(shape, fill, np.float32)


_DEG = np.full((T, 3), 90.0, np.float32)  # degrees where radians belong

# (id, field named in the error (None: the file only), builder, fragments of the message)
SEQUENCE_CASES = [
    *((f"pickle-{f}", f, _pickle(f), ("refused to unpickle",)) for f in OBJECT_FIELDS),
    ("pickle-nested-body.params.transl", "body", _pickle("body.params.transl"),
     ("refused to unpickle",)),
    ("pickle-header-gender", "gender", _pickle("gender"), ("refused to unpickle",)),
    ("truncated", None, _raw(lambda b: b[: len(b) // 2]), ("not a readable .npz archive",)),
    ("truncated-tail", None, _raw(lambda b: b[:-7]), ("not a readable .npz archive",)),
    ("bad-crc", None, _raw(_flip_data_byte), ("Bad CRC-32",)),
    ("garbage-bytes", None, lambda m, tmp: np.random.default_rng(0).bytes(4096),
     ("not a readable .npz archive",)),
    ("text-named-npz", None, lambda m, tmp: b"just some text\n",
     ("not a readable .npz archive",)),
    ("empty-file", None, lambda m, tmp: b"", ("not a readable .npz archive",)),
    ("zip-without-arrays", "gender", lambda m, tmp: _zip_of({"readme.txt": b"hello"}),
     ("missing key",)),
    ("npy-header-lies", "framerate", lambda m, tmp: _npy_lying_header(),
     ("header declares shape",)),
    ("nan-hand-pose", "rhand.params.hand_pose", _set("rhand.params.hand_pose",
                                                      _f32((T, 45), np.nan)), ("non-finite",)),
    ("inf-global-orient", "lhand.params.global_orient",
     _set("lhand.params.global_orient", _f32((T, 3), np.inf)), ("non-finite",)),
    ("nan-body-transl", "body.params.transl", _set("body.params.transl", _f32((T, 3), np.nan)),
     ("non-finite",)),
    ("inf-object-transl", "object.params.transl",
     _set("object.params.transl", _f32((T, 3), -np.inf)), ("non-finite",)),
    ("shape-width", "rhand.params.transl", _set("rhand.params.transl", _f32((T, 4))),
     ("shape (12, 4)",)),
    ("shape-3d", "rhand.params.transl", _set("rhand.params.transl", _f32((T, 3, 1))),
     ("shape (12, 3, 1)",)),
    ("shape-1d", "object.params.global_orient", _set("object.params.global_orient", _f32((T,))),
     ("shape (12,)",)),
    ("frames-disagree", "table.params.transl", _set("table.params.transl", _f32((T - 1, 3))),
     ("n_frames=12",)),
    ("dtype-string", "rhand.params.transl", _set("rhand.params.transl", np.full((T, 3), "a")),
     ("numeric array",)),
    ("dtype-object", "rhand.params.transl", _set("rhand.params.transl",
                                                  np.zeros((T, 3), object)), ("numeric array",)),
    ("dtype-complex", "rhand.params.transl", _set("rhand.params.transl",
                                                   np.zeros((T, 3), complex)), ("numeric array",)),
    ("dtype-bool", "body.params.body_pose", _set("body.params.body_pose",
                                                  np.zeros((T, 63), bool)), ("numeric array",)),
    ("params-not-dict", "rhand.params", _set("rhand.params", [1, 2]), ("should be a dict",)),
    ("part-not-dict", "object", _set("object", np.zeros(3)), ("should hold a dict",)),
    ("zero-frames", "n_frames", _set("n_frames", np.asarray(0)), ("should be >= 1",)),
    ("zero-rows", "body.params.global_orient",
     _set("body.params.global_orient", _f32((0, 3))), ("shape (0, 3)",)),
    ("n-frames-fraction", "n_frames", _set("n_frames", np.asarray(12.5)),
     ("should be an integer",)),
    ("n-comps-zero", "n_comps", _set("n_comps", np.asarray(0)), ("should be in 1..45",)),
    ("missing-top-key", "lhand", _set("lhand", DELETE), ("missing key",)),
    ("missing-header-key", "framerate", _set("framerate", DELETE), ("missing key",)),
    ("missing-param", "lhand.params.transl", _set("lhand.params.transl", DELETE),
     ("missing key",)),
    ("missing-object-contact", "contact.object", _set("contact.object", DELETE), ("missing",)),
    ("framerate-zero", "framerate", _set("framerate", np.asarray(0.0)),
     ("not a whole multiple",)),
    ("framerate-negative", "framerate", _set("framerate", np.asarray(-30.0)),
     ("not a whole multiple",)),
    ("framerate-nan", "framerate", _set("framerate", np.asarray(np.nan)),
     ("should be a finite number",)),
    ("framerate-inf", "framerate", _set("framerate", np.asarray(np.inf)),
     ("should be a finite number",)),
    ("framerate-not-divisor", "framerate", _set("framerate", np.asarray(45.0)),
     ("45 fps is not a whole multiple",)),
    pytest.param("framerate", _set("framerate", np.asarray(1e12)), ("implausible",),
                 id="framerate-absurd"),
    ("framerate-string", "framerate", _set("framerate", np.asarray("fast")),
     ("should be a finite number",)),
    ("contact-negative", "contact.object", _set("contact.object", -np.ones((T, 8), np.int32)),
     (">= 0",)),
    ("contact-fractional", "contact.object", _set("contact.object", _f32((T, 8), 0.5)),
     ("whole numbers",)),
    ("transl-millimetres", "rhand.params.transl",
     _set("rhand.params.transl", _f32((T, 3), 500.0)), ("millimetres",)),
    ("rotation-degrees", "object.params.global_orient",
     _set("object.params.global_orient", _DEG), ("degrees",)),
    ("gender-number", "gender", _set("gender", np.asarray(3.0)), ("should be a string",)),
    ("gender-unknown", "gender", _set("gender", np.asarray("robot")), ("should be one of",)),
    ("subject-empty", "sbj_id", _set("sbj_id", np.asarray("")), ("non-empty string",)),
    ("object-name-path", "obj_name", _set("obj_name", np.asarray("../../etc")),
     ("path separators",)),
    ("height-nan", "body.height", _set("body.height", float("nan")), ("finite number",)),
    ("flat-hand-mean-string", "body.flat_hand_mean", _set("body.flat_hand_mean", "yes"),
     ("True or False",)),
]


def _params(cases):
    """pytest params from ``(id, *args)`` tuples (a ready ``pytest.param`` passes through)."""
    return [c if hasattr(c, "marks") else pytest.param(*c[1:], id=c[0]) for c in cases]


@pytest.mark.parametrize(("field", "build", "fragments"), _params(SEQUENCE_CASES))
def test_hostile_sequence_file(field, build, fragments, tmp_path, capsys):
    built = build(valid_members(T), tmp_path)
    path = tmp_path / "hostile.npz"
    if isinstance(built, bytes):
        path.write_bytes(built)
    else:
        write_members(path, built)
    rc, out, err = _cli(capsys, "data", "info", path)
    where = f"{path}: {field}" if field else f"{path}:"
    assert_one_line_error(rc, err, where, *fragments)
    assert not out
    assert not (tmp_path / "PWNED").exists()  # the payload never ran


def test_pickle_in_every_object_field_is_covered():
    """The payload cases above cover each object-array member of a real sequence file."""
    members = valid_members(T)
    object_members = {k for k, v in members.items() if isinstance(v, dict)}
    assert object_members == set(OBJECT_FIELDS)
    covered = {c[1] for c in SEQUENCE_CASES
               if not hasattr(c, "marks") and c[0].startswith("pickle-")}
    assert set(OBJECT_FIELDS) <= covered


def test_one_frame_is_a_valid_sequence(tmp_path, capsys):
    path = write_members(tmp_path / "one.npz", valid_members(1))
    rc, out, err = _cli(capsys, "data", "info", path, "--json")
    assert rc == 0, err
    assert json.loads(out)["frames"] == 1


@pytest.mark.parametrize("dotted", ["banana", "rhand.params.banana", "body.banana"])
def test_unknown_extra_keys_are_ignored(dotted, tmp_path, capsys):
    """Decision (today's reader): members and entries the format does not name are ignored,
    as GRAB's own files carry keys the suite does not use; they are not written back."""
    path = write_members(tmp_path / "extra.npz", edited(valid_members(T), dotted, np.zeros(3)))
    rc, out, err = _cli(capsys, "data", "info", path, "--json")
    assert rc == 0 and not err
    assert json.loads(out)["frames"] == T


def test_export_refuses_a_pickle_payload_and_writes_nothing(tmp_path, capsys):
    path = write_members(tmp_path / "seq.npz",
                         edited(valid_members(T), "rhand", Payload(tmp_path / "PWNED")))
    out_dir = tmp_path / "meshes"
    rc, _, err = _cli(capsys, "export", path, "--out", out_dir)
    assert_one_line_error(rc, err, f"{path}: rhand", "refused to unpickle")
    assert not (tmp_path / "PWNED").exists()
    assert not out_dir.exists() or not any(out_dir.rglob("*"))


# --- prediction vs ground truth (`grip-bench evaluate`) --------------------------------------
SEQ = "grab/s1/mug_lift_1.npz"


@pytest.fixture(scope="module")
def gt_data(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("gt") / "gt"
    write_dataset(root, [("s1", "mug", "lift"), ("s2", "box", "pass"), ("s3", "ball", "lift")],
                  splits={"train": ["ball"], "val": [], "test": ["mug", "box"]})
    return root


def _pred_with(gt: Path, tmp: Path, change) -> Path:
    pred = tmp / "pred"
    shutil.copytree(gt, pred)
    change(pred)
    return pred


def _member(key, value):
    def change(pred):
        members = load_npz(pred / SEQ)
        members[key] = value
        write_members(pred / SEQ, members)
    return change


def _shorter(pred):
    from grip_bench.data.grab_io import read_grab, write_grab

    write_grab(read_grab(pred / SEQ).frames(0, 8), pred / SEQ)


def _only_train_split(pred):
    for p in (pred / "grab").glob("s[12]/*.npz"):
        p.unlink()


EVAL_CASES = [
    ("length", _shorter, SEQ, ("8 frames, but the ground truth",)),
    ("object", _member("obj_name", np.asarray("box")), SEQ, ("object 'box'", "'mug'")),
    ("framerate", _member("framerate", np.asarray(120.0)), SEQ, ("frames, but the ground truth",)),
    ("split", _only_train_split, "", ("of split 'test' have no prediction",)),
    ("missing", lambda p: (p / SEQ).unlink(), "", ("have no prediction", SEQ)),
    ("extra", lambda p: shutil.copy(p / SEQ, p / "grab/s1/cup_lift_9.npz"), "",
     ("have no ground-truth sequence",)),
    ("hostile-prediction", _member("rhand", Payload("/nonexistent/PWNED")), SEQ,
     ("rhand: refused to unpickle",)),
]


def _evaluate(capsys, pred: Path, gt: Path, out: Path):
    return _cli(capsys, "evaluate", "--pred", pred, "--gt", gt, "--out", out, "--metrics",
                "mpjpe")


@pytest.mark.parametrize(("change", "rel", "fragments"),
                         [pytest.param(*c[1:], id=c[0]) for c in EVAL_CASES])
def test_prediction_and_ground_truth_disagree(change, rel, fragments, gt_data, tmp_path, capsys):
    pred = _pred_with(gt_data, tmp_path, change)
    out = tmp_path / "eval"
    out.mkdir()
    (out / "results.csv").write_text("an earlier evaluation\n")
    rc, _, err = _evaluate(capsys, pred, gt_data, out)
    where = pred / rel if rel else pred
    assert_one_line_error(rc, err, f"{where}:", *fragments)
    assert (out / "results.csv").read_text() == "an earlier evaluation\n"  # nothing lost


@pytest.mark.parametrize(("key", "value"), [("sbj_id", "s9"), ("motion_intent", "pass")],
                         ids=["subject", "intent"])
def test_prediction_of_another_subject_or_intent(key, value, gt_data, tmp_path, capsys):
    pred = _pred_with(gt_data, tmp_path, _member(key, np.asarray(value)))
    rc, _, err = _evaluate(capsys, pred, gt_data, tmp_path / "eval")
    assert_one_line_error(rc, err, f"{pred / SEQ}:", value)


# --- data folders ----------------------------------------------------------------------------
def _with_symlink_loops(data: Path) -> None:
    (data / "grab" / "s1" / "loop.npz").symlink_to("loop.npz")  # ELOOP
    (data / "grab" / "s9").symlink_to(".")  # grab/s9 -> grab
    (data / "grab" / "s1" / "up").symlink_to("..")  # a directory cycle
    (data / "tools" / "again").symlink_to("..")


def test_symlink_loops_in_a_data_folder_are_not_followed(gt_data, tmp_path):
    """Loops are skipped (never followed), the real sequences are listed and evaluated."""
    data = tmp_path / "data"
    shutil.copytree(gt_data, data)
    _with_symlink_loops(data)
    info = _cli_proc("data", "info", data, "--json", timeout=120)
    assert info.returncode == 0, info.stderr
    assert json.loads(info.stdout)["sequences"] == 3
    ev = _cli_proc("evaluate", "--pred", data, "--gt", data, "--out", tmp_path / "ev",
                   "--metrics", "mpjpe", timeout=120)
    assert ev.returncode == 0 and "Traceback" not in ev.stderr, ev.stderr
    assert "evaluated 2 sequence(s)" in ev.stdout


def test_data_folder_without_grab(tmp_path, capsys):
    rc, _, err = _cli(capsys, "data", "info", tmp_path)
    assert_one_line_error(rc, err, f"{tmp_path}:", "no grab/ folder")


# --- a run's output folder -------------------------------------------------------------------
# The tiny run: the default profile's [run] section (so keys added later are present) with
# the smallest settings; optional reports that would slow it down are switched off.
RUN_SETTINGS = {
    "data": "synth", "synth_profile": "tiny", "data_seed": 0, "dataset": "",
    "tables": ["table4_grasp"], "methods": ["gt", "mean-pose"], "extra_methods": [],
    "perturbations": [], "perturb_seed": 0, "seed": 0, "metrics": ["mpjpe", "mpvpe"],
    "per_frame": True, "device": "cpu", "bootstrap_seed": 0, "bootstrap_n": 50,
    "runtime_sequences": 1, "runtime_repeats": 1, "physics_frames": 4, "iv_frames": 0,
    "figure_methods": [], "validity_sequences": 0, "viewer_sequences": 0,
    "seeds": [], "capture_noise": "none",
}


def _toml_value(v) -> str:
    return json.dumps(v) if not isinstance(v, bool) else str(v).lower()


def _tiny_profile() -> str:
    import tomllib

    from grip_bench.profiles import PROFILE_DIR

    run = tomllib.loads((PROFILE_DIR / "default.toml").read_text(encoding="utf-8"))["run"]
    run.update({k: v for k, v in RUN_SETTINGS.items() if k in run})
    return "[run]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in run.items())


PROFILE = _tiny_profile()


@pytest.fixture(scope="module")
def base_run(tmp_path_factory) -> tuple[Path, Path]:
    """(profile, OUT) of one finished tiny run (2 fixed methods, 7 units, ~10 s)."""
    root = tmp_path_factory.mktemp("hostile_run")
    profile = root / "tiny.toml"
    profile.write_text(PROFILE, encoding="utf-8")
    out = root / "out"
    assert main(["run", "--profile", str(profile), "--out", str(out), "--workers", "1",
                 "--quiet"]) == 0
    return profile, out


@pytest.fixture
def run_copy(base_run, tmp_path) -> tuple[Path, Path]:
    """A private copy of the finished run (tests damage it)."""
    profile, out = base_run
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    return profile, copy


def _run_args(profile: Path, out: Path, *extra) -> list[str]:
    return ["run", "--profile", str(profile), "--out", str(out), "--workers", "1", "--quiet",
            *map(str, extra)]


def _units(out: Path, kind: str) -> list[Path]:
    return sorted(p.parent for p in (out / "cache" / kind).glob("*/*/unit.json"))


def test_hostile_file_in_run_data_keeps_the_finished_run(run_copy, tmp_path, capsys):
    profile, out = run_copy
    data = tmp_path / "data"
    files = write_dataset(data, [("s1", "mug", "lift"), ("s2", "box", "pass")],
                          splits={"train": [], "val": [], "test": ["mug", "box"]})
    write_members(files[1], edited(load_npz(files[1]), "object.params.transl",
                                   _f32((20, 3), np.nan)))
    before = _snapshot(out)
    rc, _, err = _cli(capsys, *_run_args(profile, out, "--data", data))
    assert_one_line_error(rc, err, f"{files[1]}: object.params.transl", "non-finite")
    assert _snapshot(out) == before  # earlier outputs and units untouched
    assert not any((out / "cache" / ".tmp").iterdir())


def _drop_privileges() -> tuple[str, ...]:
    """A command prefix under which root cannot write into read-only folders."""
    if os.geteuid() != 0:
        return ()
    setpriv = shutil.which("setpriv")
    if not setpriv:
        pytest.skip("running as root without setpriv: read-only folders are writable")
    return (setpriv, "--bounding-set=-dac_override,-dac_read_search,-fowner")


def _read_only(folder: Path) -> None:
    for d in [folder, *(p for p in folder.rglob("*") if p.is_dir())]:
        d.chmod(0o555)


def test_read_only_output_folder(run_copy, tmp_path):
    profile, out = run_copy
    prefix = _drop_privileges()
    fresh = tmp_path / "ro"
    fresh.mkdir()
    before = _snapshot(out)
    _read_only(out)
    _read_only(fresh)
    try:
        run_new = _cli_proc(*_run_args(profile, fresh / "out"), prefix=prefix)
        assert_one_line_error(run_new.returncode, run_new.stderr, f"{fresh / 'out'}:",
                              "cannot write in the output folder", "Permission denied")
        report = _cli_proc("report", out, prefix=prefix)
        assert_one_line_error(report.returncode, report.stderr, f"{out}/",
                              "cannot write (Permission denied)")
        assert _snapshot(out) == before
    finally:
        for d in (out, fresh):
            for p in [d, *(q for q in d.rglob("*") if q.is_dir())]:
                p.chmod(0o755)
    assert not list(out.rglob(".*.tmp"))


class _FillingFile:
    """A file on a disk that fills up after ``room`` bytes: the write raises ENOSPC."""

    def __init__(self, f, room: int):
        self.f, self.room = f, room

    def write(self, data):
        if len(data) > self.room:
            self.f.write(data[: self.room])
            self.f.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.room -= len(data)
        return self.f.write(data)

    def __getattr__(self, name):
        return getattr(self.f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


def _fill_disk_on(monkeypatch, marker: str, room: int = 64) -> list[str]:
    """Make writes through ``core.io.atomic_file`` to temp files whose path holds ``marker``
    fail after ``room`` bytes; returns the temp paths that failed."""
    real, hit = core_io._fdopen, []

    def fdopen(fd, mode, **kw):
        f = real(fd, mode, **kw)
        name = os.readlink(f"/proc/self/fd/{fd}")
        if marker in name:
            hit.append(name)
            return _FillingFile(f, room)
        return f

    monkeypatch.setattr(core_io, "_fdopen", fdopen)
    return hit


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc/self/fd")
def test_disk_full_while_writing_the_report(run_copy, monkeypatch, capsys):
    _, out = run_copy
    before = _snapshot(out)
    hit = _fill_disk_on(monkeypatch, ".leaderboard.md.")
    rc, _, err = _cli(capsys, "report", out)
    assert_one_line_error(rc, err, f"{out / 'leaderboard.md'}:",
                          "cannot write (No space left on device)")
    assert hit and not Path(hit[0]).exists()  # the partial temp file is gone
    assert (out / "leaderboard.md").read_bytes() == before["leaderboard.md"]
    assert not list(out.rglob(".*.tmp"))


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc/self/fd")
def test_disk_full_inside_a_cache_unit(run_copy, monkeypatch, capsys):
    """A prediction unit fails half-written: one line naming the file, no temp unit left,
    every other unit intact; the next run builds the unit."""
    profile, out = run_copy
    label = lambda u: json.loads((u / "unit.json").read_text())["label"]  # noqa: E731
    victim = next(u for u in _units(out, "prediction") if label(u).endswith("mean-pose @ none"))
    shutil.rmtree(victim)
    before = _snapshot(out)
    hit = _fill_disk_on(monkeypatch, "/.tmp/")
    rc, _, err = _cli(capsys, *_run_args(profile, out))
    line = assert_one_line_error(rc, err, f"{victim}/grab/", "No space left on device")
    assert ".tmp" not in line and hit
    assert not any((out / "cache" / ".tmp").iterdir())
    after = _snapshot(out)
    assert {k: v for k, v in after.items() if k in before} == before
    monkeypatch.undo()
    assert main(_run_args(profile, out)) == 0
    assert victim.is_dir()


def test_damaged_cache_units_are_rebuilt(base_run, run_copy, capsys):
    """Flipped bytes, a missing file, an unreadable integrity record: each unit is rebuilt,
    with a note in run.log, and the results are the same bytes."""
    _, original = base_run
    profile, out = run_copy
    metrics, preds = _units(out, "metrics"), _units(out, "prediction")
    flipped = metrics[0] / "results.csv"
    data = bytearray(flipped.read_bytes())
    data[len(data) // 2] ^= 0x01
    flipped.write_bytes(bytes(data))
    missing = next(preds[0].rglob("*.npz"))
    missing.unlink()
    (metrics[1] / ".integrity.json").write_text("{not json")
    rc, out_text, err = _cli(capsys, *_run_args(profile, out))
    assert rc == 0, err
    assert "reused 4 of 7 units" in out_text
    log = (out / "run.log").read_text()
    assert "results.csv does not match its recorded sha256" in log
    assert f"{missing.relative_to(preds[0]).as_posix()} is missing" in log
    assert "unreadable integrity record" in log
    for name in ("results.csv", "frames.csv", "leaderboard.md"):
        assert (out / name).read_bytes() == (original / name).read_bytes(), name
    assert missing.is_file() and flipped.read_bytes() == (
        original / flipped.relative_to(out)).read_bytes()
    rc, out_text, _ = _cli(capsys, *_run_args(profile, out))
    assert rc == 0 and "reused 7 of 7 units" in out_text


def test_dry_run_reports_damage_without_touching_it(run_copy, capsys):
    profile, out = run_copy
    unit = _units(out, "metrics")[0]
    (unit / "results.csv").write_text("tampered\n")
    rc, text, _ = _cli(capsys, *_run_args(profile, out, "--dry-run"))
    assert rc == 0
    assert sum(line.startswith("[todo]") for line in text.splitlines()) == 1
    assert (unit / "results.csv").read_text() == "tampered\n"


# --- two runs on one output folder -----------------------------------------------------------
_HOLD = ("import sys, time\nfrom grip_bench.bench.lock import run_lock\n"
         "with run_lock(sys.argv[1]):\n    print('locked', flush=True)\n"
         "    time.sleep(float(sys.argv[2]))\n")


def _holder(out: Path, seconds: float) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", _HOLD, str(out), str(seconds)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_second_run_on_the_same_output_folder_is_refused(run_copy):
    profile, out = run_copy
    before = _snapshot(out)
    holder = _holder(out, 600)
    try:
        second = _cli_proc(*_run_args(profile, out))
        assert_one_line_error(second.returncode, second.stderr, f"{out / '.lock'}:",
                              f"another grip-bench run (PID {holder.pid})", "--wait")
        assert _snapshot(out, skip=("run.log", ".lock")) == \
            {k: v for k, v in before.items() if k != ".lock"}
    finally:
        holder.kill()  # SIGKILL: no cleanup, the kernel drops the lock
        holder.wait()
    again = _cli_proc(*_run_args(profile, out))  # a dead holder never blocks
    assert again.returncode == 0, again.stderr
    assert f"done: {out}" in again.stdout


def test_wait_blocks_until_the_other_run_ends(run_copy):
    profile, out = run_copy
    holder = _holder(out, 3)
    try:
        waiting = _cli_proc(*_run_args(profile, out, "--wait"))
        assert holder.poll() is not None  # it could only start once the holder was gone
    finally:
        holder.kill()
        holder.wait()
    assert waiting.returncode == 0, waiting.stderr
    assert f"done: {out}" in waiting.stdout
    assert (out / ".lock").read_text().split()[0] != str(holder.pid)


def test_lock_is_released_after_sigterm(run_copy):
    profile, out = run_copy
    holder = _holder(out, 600)
    holder.send_signal(signal.SIGTERM)
    holder.wait(timeout=30)
    from grip_bench.bench.lock import run_lock

    with run_lock(out) as path:  # free again, without waiting
        assert path == out / ".lock"


# --- profiles --------------------------------------------------------------------------------
PROFILE_CASES = [
    ("unknown-key", PROFILE + "banana = 1\n", "run.banana", ("unknown key 'banana'",)),
    ("mistyped-key", PROFILE.replace("validity_sequences", "validty_sequences"),
     "run.validty_sequences", ("did you mean 'validity_sequences'?",)),
    ("unknown-section", PROFILE.replace("[run]", "[rnu]"), "[rnu]",
     ("unknown section", "did you mean 'run'?")),
    ("wrong-type", PROFILE.replace("\nseed = 0\n", '\nseed = "zero"\n'), "run.seed",
     ("should be an integer, not a string",)),
    ("wrong-type-list", PROFILE.replace('methods = ["gt", "mean-pose"]', 'methods = "gt"'),
     "run.methods", ("should be an array",)),
    ("invalid-toml", PROFILE.replace("[run]", "[run"), None, ("not a readable TOML profile",)),
    ("not-utf8", None, None, ("not a readable TOML profile",)),
]


@pytest.mark.parametrize(("text", "field", "fragments"),
                         [pytest.param(*c[1:], id=c[0]) for c in PROFILE_CASES])
def test_hostile_profile(text, field, fragments, tmp_path, capsys):
    path = tmp_path / "p.toml"
    if text is None:
        path.write_bytes(b"\xff\xfe[run]\n")
    else:
        path.write_text(text, encoding="utf-8")
    out = tmp_path / "out"
    rc, _, err = _cli(capsys, *_run_args(path, out))
    assert_one_line_error(rc, err, f"{path}: {field}" if field else f"{path}:", *fragments)
    assert not out.exists()  # nothing started


def test_evaluate_into_a_read_only_folder(gt_data, tmp_path):
    prefix = _drop_privileges()
    ro = tmp_path / "ro"
    ro.mkdir()
    _read_only(ro)
    try:
        ev = _cli_proc("evaluate", "--pred", gt_data, "--gt", gt_data, "--out", ro / "ev",
                       "--metrics", "mpjpe", prefix=prefix)
    finally:
        ro.chmod(0o755)
    assert_one_line_error(ev.returncode, ev.stderr, f"{ro / 'ev'}", "Permission denied")


# --- the other commands reading data folders or run folders ---------------------------------
@pytest.mark.parametrize("argv", [("train", "nearest-neighbour", "--out", "{out}/model.pt"),
                                  ("validity", "--out", "{out}")], ids=["train", "validity"])
def test_hostile_file_in_a_data_folder(argv, tmp_path, capsys):
    data, out = tmp_path / "data", tmp_path / "out"
    files = write_dataset(data, [("s1", "mug", "lift"), ("s2", "box", "pass")],
                          splits={"train": ["mug"], "val": [], "test": ["box"]})
    for f in files:
        write_members(f, edited(load_npz(f), "rhand.params.hand_pose", _f32((20, 45), np.nan)))
    rc, _, err = _cli(capsys, *(a.format(out=out) for a in argv), "--data", data)
    assert_one_line_error(rc, err, f"{data}/grab/", "rhand.params.hand_pose", "non-finite")
    assert not out.exists() or not any(out.rglob("*"))


def test_report_on_an_unreadable_results_file(run_copy, capsys):
    _, out = run_copy
    (out / "results.csv").write_text('method,metric\n"unclosed\n')
    before = _snapshot(out)
    rc, _, err = _cli(capsys, "report", out)
    assert_one_line_error(rc, err, f"{out / 'results.csv'}:", "not a readable CSV")
    assert _snapshot(out) == before  # the earlier tables and leaderboards are kept
