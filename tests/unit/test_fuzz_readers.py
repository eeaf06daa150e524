"""Property-based fuzzing of the sequence reader (issue #18; docs/hostile_inputs.md).

Whatever bytes or structures a ``.npz`` holds, ``read_grab`` returns a valid ``Sequence``
or raises ``InputError`` (``UnsafeFileError`` for pickled code; ``MissingModelError`` for
PCA / mean-relative hand poses without a MANO model, its documented third outcome), never
another exception, and never runs pickled code. Three strategies: random member structures,
one entry of a valid file replaced by a random array, byte-level corruption of a valid file.

The budget is fixed (``derandomize=True``: the same examples on every run, so CI is
deterministic) and small enough for the default suite: ``EXAMPLES`` per strategy.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from grip_bench.core.errors import InputError, MissingModelError
from grip_bench.data.grab_io import read_grab
from grip_bench.data.sequence import Sequence
from tests.hostile_fixtures import Payload, edited, valid_members, write_members

EXAMPLES = 200  # per strategy: 600 reads in all
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

_DIR = Path(tempfile.mkdtemp(prefix="grip-bench-fuzz-"))
MARKER = _DIR / "PWNED"  # created only if a pickled payload ran
T = 6
VALID = valid_members(T)
VALID_BYTES = write_members(_DIR / "valid.npz", VALID).read_bytes()


@pytest.fixture(scope="module", autouse=True)
def _cleanup():
    yield
    shutil.rmtree(_DIR, ignore_errors=True)


def _read(path: Path) -> None:
    """The property: a valid Sequence or one of the reader's documented errors."""
    try:
        seq = read_grab(path)
    except (InputError, MissingModelError) as e:
        assert "\n" not in e.message, e.message  # one line for the CLI
        event(type(e).__name__)  # --hypothesis-show-statistics shows the mix of outcomes
    else:
        assert isinstance(seq, Sequence)
        seq.validate()
        event("valid Sequence")
    assert not MARKER.exists(), "a pickled payload ran"


# --- strategies --------------------------------------------------------------------------------
DTYPES = st.sampled_from(["<f4", "<f8", ">f8", "<i4", "<i8", "u1", "?", "<c16", "<U3", "O",
                          "<f2", "V4"])
SHAPES = st.one_of(st.just(()), st.tuples(st.integers(0, 8)),
                   st.tuples(st.sampled_from([0, 1, T - 1, T, T + 1]),
                             st.sampled_from([0, 1, 3, 4, 10, 45, 48, 63, 165])),
                   st.tuples(st.integers(0, 3), st.integers(0, 3), st.integers(0, 3)))
FLOATS = st.sampled_from([0.0, 1.0, -1.0, 0.5, np.nan, np.inf, -np.inf, 1e30, -1e-30, 30.0,
                          120.0, 3.14])


@st.composite
def arrays(draw) -> np.ndarray:
    dtype, shape = np.dtype(draw(DTYPES)), draw(SHAPES)
    n = int(np.prod(shape))
    if dtype.kind == "O":
        leaves = st.one_of(st.none(), st.integers(), st.text(max_size=3), FLOATS,
                           st.just(Payload(MARKER)))
        a = np.empty(n, dtype=object)
        a[:] = [draw(leaves) for _ in range(n)] if n <= 16 else None
        return a.reshape(shape)
    if dtype.kind in "fc":
        values = draw(st.lists(FLOATS, min_size=1, max_size=4))
        with np.errstate(over="ignore"):  # 1e30 in float16 is inf: a value worth trying
            return np.resize(np.asarray(values, dtype=dtype), shape)
    if dtype.kind in "iub":
        return np.resize(np.asarray(draw(st.lists(st.integers(0, 100), min_size=1, max_size=4)),
                                    dtype=dtype), shape)
    if dtype.kind == "U":
        return np.resize(np.asarray(draw(st.lists(st.text(max_size=3), min_size=1, max_size=3)),
                                    dtype=dtype), shape)
    return np.zeros(shape, dtype=dtype)


LEAVES = st.one_of(arrays(), st.none(), st.booleans(), st.integers(-2, 200), FLOATS,
                   st.text(max_size=6), st.just(Payload(MARKER)))
VALUES = st.recursive(LEAVES, lambda kids: st.one_of(
    st.lists(kids, max_size=3), st.dictionaries(st.sampled_from(
        ["params", "transl", "global_orient", "hand_pose", "object", "vtemp", "fullpose"]),
        kids, max_size=4)), max_leaves=8)
KEYS = st.sampled_from(sorted(VALID))


def _leaf_paths(members: dict, prefix: str = "") -> list[str]:
    out = []
    for k, v in members.items():
        dotted = f"{prefix}{k}"
        out += _leaf_paths(v, dotted + ".") if isinstance(v, dict) else [dotted]
    return out


LEAF_PATHS = sorted(_leaf_paths(VALID))


# --- properties --------------------------------------------------------------------------------
@FUZZ
@given(st.dictionaries(KEYS, VALUES, max_size=6), st.sets(KEYS, max_size=3))
def test_random_structures(overrides, removed):
    members = {k: v for k, v in {**VALID, **overrides}.items() if k not in removed}
    _read(write_members(_DIR / "structure.npz", members))


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(LEAF_PATHS), st.one_of(arrays(), LEAVES)),
                min_size=1, max_size=3))
def test_random_entries_of_a_valid_file(changes):
    members = VALID
    for dotted, value in changes:
        members = edited(members, dotted, value)
    _read(write_members(_DIR / "entry.npz", members))


@FUZZ
@given(st.lists(st.tuples(st.integers(0, len(VALID_BYTES) - 1), st.integers(1, 255)),
                min_size=1, max_size=6),
       st.one_of(st.none(), st.integers(0, len(VALID_BYTES))),
       st.binary(max_size=16))
def test_byte_corruption_of_a_valid_file(flips, cut, junk):
    data = bytearray(VALID_BYTES)
    for pos, mask in flips:
        data[pos] ^= mask
    if cut is not None:
        data = data[:cut] + junk + data[cut:]
    path = _DIR / "bytes.npz"
    path.write_bytes(bytes(data))
    _read(path)


def test_the_unchanged_file_reads():
    """The fuzzed files start from a valid one (else every property would hold trivially)."""
    assert read_grab(_DIR / "valid.npz").n_frames == T
