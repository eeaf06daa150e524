"""Code digests of work units (``bench.codehash``): a constants module counts by name.

Each test writes a small package to a temporary folder, digests a unit's entry modules,
edits one file and checks which digests move. The naive reference is the rule itself: a
unit's key must move when a constant it reads (directly or through another constant)
changes, and only then, unless the unit uses the module whole."""

from __future__ import annotations

from pathlib import Path

import pytest

from grip_bench.bench.codehash import CodeIndex

CONSTS = "A = 1.0\nB = A * 2  # read by uses_b, reads A\nC = 3\nD, E = 4, 5\n"
MODULES = {
    "__init__.py": "",
    "consts.py": '"""Named constants."""\n' + CONSTS,
    "uses_b.py": "from . import consts as K\n\n\ndef f():\n    return K.B\n",
    "uses_c.py": "from .consts import C\n",
    "uses_e.py": "from pkg.consts import E\n",
    "uses_none.py": "X = 1\n",
    "dyn.py": "from . import consts\n\nNAMES = dir(consts)\n",
    "getattr_.py": "from . import consts as K\n\n\ndef g(n):\n    return getattr(K, n)\n",
    "star.py": "from .consts import *  # noqa\n",
    "dotted.py": "import pkg.consts\n\nY = pkg.consts.C\n",
    "inside.py": "def h():\n    from .consts import A\n    return A\n",
}


def _tree(root: Path, edits: dict[str, str] | None = None) -> CodeIndex:
    pkg = root / "pkg"
    pkg.mkdir(parents=True, exist_ok=True)
    for name, text in {**MODULES, **(edits or {})}.items():
        (pkg / name).write_text(text)
    return CodeIndex({"pkg": pkg})


def _digests(root: Path, edits: dict[str, str] | None = None) -> dict[str, str]:
    index = _tree(root, edits)
    return {m: index.digest([f"pkg.{m}"]) for m in
            ("uses_b", "uses_c", "uses_e", "uses_none", "dyn", "getattr_", "star", "dotted",
             "inside")}


def _moved(tmp_path: Path, old: str, new: str) -> set[str]:
    before = _digests(tmp_path / "a")
    after = _digests(tmp_path / "b", {"consts.py": MODULES["consts.py"].replace(old, new)})
    return {m for m in before if before[m] != after[m]}


def test_only_a_pure_assignment_module_counts_by_name(tmp_path):
    index = _tree(tmp_path, {"funcs.py": "A = 1\n\n\ndef f():\n    return A\n"})
    assert index.is_constants("pkg.consts")
    assert not index.is_constants("pkg.funcs")  # a function: counted whole
    assert not index.is_constants("pkg")  # a package's __init__ runs on import: whole
    assert not index.is_constants("pkg.uses_b")


def test_a_constant_renews_only_the_units_that_read_it(tmp_path):
    # whole-module users move on every edit; name readers only on theirs
    whole = {"dyn", "getattr_", "star", "dotted"}
    assert _moved(tmp_path, "C = 3", "C = 4") == whole | {"uses_c"}
    assert _moved(tmp_path, "D, E = 4, 5", "D, E = 4, 6") == whole | {"uses_e"}


def test_a_constant_read_through_another_renews_its_readers(tmp_path):
    # uses_b reads B, and B = A * 2 reads A; inside reads A in a function body
    assert _moved(tmp_path, "A = 1.0", "A = 1.5") == {
        "uses_b", "inside", "dyn", "getattr_", "star", "dotted"}


def test_a_new_constant_or_a_comment_renews_no_name_reader(tmp_path):
    assert _moved(tmp_path, "C = 3\n", "C = 3\nF = 7\n") == {"dyn", "getattr_", "star",
                                                             "dotted"}
    assert _moved(tmp_path, "# read by uses_b, reads A", "# another comment") == set()


def test_reads_lists_the_names_and_none_for_whole_use(tmp_path):
    index = _tree(tmp_path)
    assert index.reads("pkg.uses_b", "pkg.consts") == {"B"}
    assert index.reads("pkg.uses_c", "pkg.consts") == {"C"}
    assert index.reads("pkg.uses_none", "pkg.consts") == frozenset()
    for whole in ("pkg.dyn", "pkg.getattr_", "pkg.star", "pkg.dotted"):
        assert index.reads(whole, "pkg.consts") is None, whole
    closure = index.closure(["pkg.uses_b"])
    assert index.constants_read("pkg.consts", closure) == {"A", "B"}


@pytest.mark.parametrize("name, data_reads", [("HOLD_FINGER_KP", False),
                                              ("HOLD_TOUCH", True)])
def test_installed_dataset_units_do_not_read_the_hold_tests_servos(name, data_reads):
    """The installed tree: the generator reads the force check's contact band, not the
    articulated test's servo gains, so a change to those renews no dataset unit; the
    metric units count the constants whole (``metrics.physics`` lists ``SIM_*`` by
    ``dir``)."""
    index = CodeIndex.installed()
    consts = "grip_bench.core.constants"
    data = index.closure(["grip_bench.bench.stages.data"])
    assert (name in index.constants_read(consts, data)) is data_reads
    assert index.constants_read(consts, index.closure(["grip_bench.bench.stages.evaluate"])) \
        is None


def test_installed_reads_cover_a_naive_textual_scan():
    """The naive reference on the installed tree: every ``C.NAME`` / ``constants.NAME``
    attribute and every name in a ``from ...constants import (...)`` list of a module is among
    the names :meth:`reads` finds for it (or the module counts the constants whole); the
    scan reads the code without docstrings, as the digest does."""
    import ast
    import re

    index = CodeIndex.installed()
    consts = "grip_bench.core.constants"
    defined = set(index._assignments(consts))
    checked = 0
    for module, path in index.files.items():
        if module == consts or "constants" not in path.read_text():
            continue
        text = ast.unparse(index._tree(module))
        if "constants" not in text:
            continue
        read = index.reads(module, consts)
        if read is None:
            continue
        used = set(re.findall(r"\b(?:C|constants)\.([A-Z][A-Z0-9_]*)", text))
        for group in re.findall(r"constants import \(?([A-Z0-9_,\s]+)\)?", text):
            used |= set(re.findall(r"[A-Z][A-Z0-9_]*", group))
        assert used & defined <= read, (module, sorted((used & defined) - read))
        checked += 1
    assert checked > 30
