"""Digests of the code a work unit runs: the transitive import closure of its entry modules.

A unit's cache key must change when, and only when, code that produces its content
changes. Hashing one folder (the old way) missed code the unit imports from elsewhere
(``sensors.py`` for GRIP, ``geometry/distance.py`` for the metrics) and re-ran units for
edits they never execute. Here the key covers the code of every module the unit's entry
modules import, directly or not, read from the source with :mod:`ast` (imports inside
functions included, ``if TYPE_CHECKING:`` blocks excluded), plus the ``__init__.py`` of
every package on the way, since importing a module runs them.

A module's code is its syntax tree without docstrings (``ast.dump``: no comments, no line
numbers), so an edit of a comment, a docstring or the layout renews nothing, while any
change to a statement, a name, a constant or an annotation does.

A *constants module* (every top-level statement a plain assignment to names, as
``core/constants.py``) counts by name instead: a closure holds only the assignments of the
names its other modules read from it (``C.NAME``, ``from ... import NAME``) and of the
names those assignments read, so a change to a physics protocol constant renews the units
that read it and not the dataset. A module that uses such a module other than by reading an
attribute (``dir(C)``, ``getattr(C, name)``, ``import *``) counts it whole.

Methods are found through the registry by name (``importlib``), so a unit that runs a
method names the method's module as an entry itself (``bench.plan``); plug-in metrics are
imported by the metric registry through entry points, so the metric units name their
modules likewise.

The index reads files under given package roots, so a test can point it at a temporary
copy of the source tree, edit a file there and see which keys move.
"""

from __future__ import annotations

import ast
import functools
import hashlib
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

ROOT_PACKAGES = ("grip_bench", "grip_baselines")


def installed_roots() -> dict[str, Path]:
    """``{top package: folder}`` of ``grip_bench``, ``grip_baselines`` and the top packages of
    installed plug-ins of every group (methods, metrics, tables: their code is part of
    their units' keys too)."""
    import importlib

    from ..core.plugins import plugin_top_packages

    names = [*ROOT_PACKAGES, *plugin_top_packages()]
    roots = {}
    for name in dict.fromkeys(names):
        module = importlib.import_module(name)
        if module.__file__ is None:  # a namespace package has no folder of its own to hash
            continue
        is_package = hasattr(module, "__path__")
        roots[name] = Path(module.__file__).parent if is_package else Path(module.__file__)
    return roots


class CodeIndex:
    """Module files and their internal imports under ``roots`` (``{package: folder}``, or
    ``{module: file}`` for a top-level module)."""

    def __init__(self, roots: Mapping[str, Path]):
        self.files: dict[str, Path] = {}
        self.packages: set[str] = set()
        for top, folder in roots.items():
            if Path(folder).suffix == ".py":  # a top-level module, not a package
                self.files[top] = Path(folder)
                continue
            for path in sorted(Path(folder).rglob("*.py")):
                parts = [top, *path.relative_to(folder).with_suffix("").parts]
                if parts[-1] == "__init__":
                    parts = parts[:-1]
                    self.packages.add(".".join(parts))
                self.files[".".join(parts)] = path
        self._imports: dict[str, frozenset[str]] = {}
        self._reads: dict[tuple[str, str], frozenset[str] | None] = {}
        self._trees: dict[str, ast.Module] = {}
        self._code: dict[str, bytes] = {}
        self._digests: dict[tuple[str, ...], str] = {}

    @classmethod
    @functools.cache
    def installed(cls) -> CodeIndex:
        """The index of the installed source (built once per process)."""
        return cls(installed_roots())

    # -- the import graph ------------------------------------------------------------------
    def imports(self, module: str) -> frozenset[str]:
        """Internal modules ``module`` imports anywhere in its file (not TYPE_CHECKING)."""
        if module not in self._imports:
            tree = self._tree(module)
            pkg = module if module in self.packages else module.rpartition(".")[0]
            found: set[str] = set()
            for node in _runtime_nodes(tree):
                if isinstance(node, ast.Import):
                    found.update(self._known(a.name) for a in node.names)
                elif isinstance(node, ast.ImportFrom):
                    base = _resolve(node, pkg)
                    found.add(self._known(base))
                    found.update(self._known(f"{base}.{a.name}") for a in node.names)
            found.discard("")
            self._imports[module] = frozenset(found)
        return self._imports[module]

    def _tree(self, module: str) -> ast.Module:
        """``module``'s syntax tree, docstrings removed (a docstring holds no import, so
        :meth:`imports` reads the same tree)."""
        if module not in self._trees:
            tree = ast.parse(self.files[module].read_bytes())
            self._trees[module] = _strip_docstrings(tree)
        return self._trees[module]

    def code(self, module: str) -> bytes:
        """What of ``module`` counts as code: its syntax tree without docstrings."""
        if module not in self._code:
            self._code[module] = ast.dump(self._tree(module)).encode()
        return self._code[module]

    def _known(self, name: str) -> str:
        """``name`` or its longest prefix that is a module of the index ('' if none)."""
        while name and name not in self.files:
            name = name.rpartition(".")[0]
        return name

    def closure(self, entries: Iterable[str]) -> list[str]:
        """Sorted modules run by importing ``entries``: their imports, transitively, and the
        ``__init__`` of every enclosing package."""
        seen: set[str] = set()
        todo = [self._known(e) or _missing(e) for e in entries]
        while todo:
            mod = todo.pop()
            if mod in seen:
                continue
            seen.add(mod)
            parents = [mod.rsplit(".", i)[0] for i in range(1, mod.count(".") + 1)]
            todo.extend(p for p in parents if p in self.files)
            todo.extend(self.imports(mod) - seen)
        return sorted(seen)

    def digest(self, entries: Iterable[str]) -> str:
        """sha256 over the names and code of the :meth:`closure` of ``entries``: each module's
        :meth:`code`, a constants module's the :meth:`constants_read` of the closure."""
        key = tuple(entries)
        if key not in self._digests:
            h = hashlib.sha256()
            closure = self.closure(key)
            for mod in closure:
                code = (self.constants_code(mod, self.constants_read(mod, closure))
                        if self.is_constants(mod) else self.code(mod))
                h.update(mod.encode() + b"\0" + code + b"\0")
            self._digests[key] = h.hexdigest()
        return self._digests[key]

    # -- constants modules, counted by name -------------------------------------------------
    def is_constants(self, module: str) -> bool:
        """Whether every top-level statement of ``module`` (docstring aside) assigns to plain
        names: a module of named constants, which :meth:`digest` counts by name."""
        body = self._tree(module).body
        return bool(body) and module not in self.packages and all(
            _assigned_names(node) is not None for node in body)

    def constants_read(self, constants: str, modules: Iterable[str]) -> frozenset[str] | None:
        """The names of ``constants`` that ``modules`` read, with the names their assignments
        read in turn; None when one of them uses the module whole (then all of it counts)."""
        names: set[str] = set()
        for mod in modules:
            if mod == constants:
                continue
            read = self.reads(mod, constants)
            if read is None:
                return None
            names |= read
        values = self._assignments(constants)
        todo = list(names)
        while todo:  # a constant defined from others reads them
            for node in values.get(todo.pop(), ()):
                for n in ast.walk(node.value if node.value is not None else node):
                    if isinstance(n, ast.Name) and n.id in values and n.id not in names:
                        names.add(n.id)
                        todo.append(n.id)
        return frozenset(names)

    def constants_code(self, constants: str, names: frozenset[str] | None) -> bytes:
        """The code of ``constants`` that counts for ``names`` (None: all of it): their
        assignments in file order."""
        if names is None:
            return self.code(constants)
        kept = [node for node in self._tree(constants).body
                if set(_assigned_names(node) or ()) & names]
        return ast.dump(ast.Module(body=kept, type_ignores=[])).encode()

    def _assignments(self, constants: str) -> dict[str, list[ast.Assign | ast.AnnAssign]]:
        out: dict[str, list] = {}
        for node in self._tree(constants).body:
            for name in _assigned_names(node) or ():
                out.setdefault(name, []).append(node)
        return out

    def reads(self, module: str, constants: str) -> frozenset[str] | None:
        """The names ``module`` reads from the constants module ``constants`` (empty when it
        does not import it); None when it uses the module other than by attribute."""
        key = (module, constants)
        if key not in self._reads:
            self._reads[key] = self._find_reads(module, constants)
        return self._reads[key]

    def _find_reads(self, module: str, constants: str) -> frozenset[str] | None:
        tree = self._tree(module)
        pkg = module if module in self.packages else module.rpartition(".")[0]
        parent, _, leaf = constants.rpartition(".")
        names: set[str] = set()
        aliases: set[str] = set()
        for node in _runtime_nodes(tree):
            if isinstance(node, ast.ImportFrom):
                base = _resolve(node, pkg)
                for a in node.names:
                    if base == constants:
                        if a.name == "*":
                            return None
                        names.add(a.name)
                    elif base == parent and a.name == leaf:
                        aliases.add(a.asname or a.name)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name == constants:
                        if a.asname is None:  # read as a dotted path: count it whole
                            return None
                        aliases.add(a.asname)
        if not aliases:
            return frozenset(names)
        attribute_of: set[int] = set()
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases):
                names.add(node.attr)
                attribute_of.add(id(node.value))
        for node in ast.walk(tree):
            if (isinstance(node, ast.Name) and node.id in aliases
                    and id(node) not in attribute_of and not isinstance(node.ctx, ast.Store)):
                return None  # dir(C), getattr(C, ...), passed on: every name may be read
        return frozenset(names)


def _assigned_names(node: ast.stmt) -> list[str] | None:
    """The names a top-level ``NAME = ...`` / ``NAME: T = ...`` statement assigns (tuple
    targets of names included); None for any other statement."""
    if isinstance(node, ast.AnnAssign):
        targets = [node.target]
    elif isinstance(node, ast.Assign):
        targets = node.targets
    else:
        return None
    names: list[str] = []
    for t in targets:
        elts = t.elts if isinstance(t, ast.Tuple) else [t]
        if not all(isinstance(e, ast.Name) for e in elts):
            return None
        names += [e.id for e in elts]
    return names


def _missing(name: str) -> str:
    raise KeyError(f"no module {name!r} in the code index")


def _resolve(node: ast.ImportFrom, pkg: str) -> str:
    if not node.level:
        return node.module or ""
    base = pkg.split(".")
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _runtime_nodes(tree: ast.AST) -> Iterator[ast.AST]:
    """Every node of ``tree`` except the bodies of ``if TYPE_CHECKING:`` blocks."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                todo.extend(child.orelse)
                continue
            todo.append(child)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _strip_docstrings(tree: ast.Module) -> ast.Module:
    """``tree`` with its module, class and function docstrings removed, in place (a freshly
    parsed tree: copying it first cost more than parsing and dumping it together)."""
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
                and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return tree
