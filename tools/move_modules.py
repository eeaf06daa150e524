"""Move modules and rewrite every import of them (a refactoring aid, not part of the suite).

    python tools/move_modules.py OLD=NEW [OLD=NEW ...]

``OLD`` and ``NEW`` are dotted module names
(``grip_bench.bench.results=grip_bench.results.schema``); a package moves with everything
under it. Files are moved with ``git mv``; every ``import``
and ``from ... import`` in ``grip_bench``, ``baselines``, ``tests`` and ``tools`` that names a
moved module is rewritten, relative imports staying relative (recomputed from the importing
file's new place). Dotted names in strings are left to the caller (``git grep`` them).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = {
    "grip_bench": ROOT / "grip_bench",
    "grip_baselines": ROOT / "baselines" / "grip_baselines",
}
SCAN = [ROOT / "grip_bench", ROOT / "baselines", ROOT / "tests", ROOT / "tools"]


def module_path(name: str) -> Path:
    """File (``x.py``) or package folder of a dotted module name."""
    top, *rest = name.split(".")
    base = SOURCES[top].joinpath(*rest)
    return base if base.is_dir() else base.with_suffix(".py")


def module_of(path: Path) -> tuple[str, bool] | None:
    """``(dotted name, is_package)`` of a source file, or None outside the packages."""
    for top, base in SOURCES.items():
        try:
            rel = path.relative_to(base)
        except ValueError:
            continue
        parts = [top, *rel.with_suffix("").parts]
        if parts[-1] == "__init__":
            return ".".join(parts[:-1]), True
        return ".".join(parts), False
    return None


def remap(name: str, moves: dict[str, str]) -> str:
    for old, new in moves.items():
        if name == old or name.startswith(old + "."):
            return new + name[len(old):]
    return name


def package_of(mod: str, is_pkg: bool) -> str:
    return mod if is_pkg else mod.rpartition(".")[0]


def resolve(node: ast.ImportFrom, pkg: str) -> str:
    if not node.level:
        return node.module or ""
    base = pkg.split(".")
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def relative(target: str, pkg: str) -> str:
    """``target`` written relative to package ``pkg`` (both in one top package)."""
    t, p = target.split("."), pkg.split(".")
    common = 0
    while common < min(len(t), len(p)) and t[common] == p[common]:
        common += 1
    dots = "." * (len(p) - common + 1)
    return dots + ".".join(t[common:])


def rewrite(path: Path, old_mod, new_mod, moves: dict[str, str]) -> bool:
    src = path.read_text(encoding="utf-8")
    tree = ast.parse(src)
    lines = src.splitlines(keepends=True)
    old_pkg = package_of(*old_mod) if old_mod else None
    new_pkg = package_of(*new_mod) if new_mod else None
    edits = []  # (lineno, col, end_lineno, end_col, text)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level and old_pkg is None:
                continue
            target = resolve(node, old_pkg or "")
            new_target = remap(target, moves)
            names = [a.name for a in node.names]
            # ``from pkg import module``: the module itself may have moved elsewhere
            moved_parents = {remap(f"{target}.{n}", moves).rpartition(".")[0] for n in names
                             if remap(f"{target}.{n}", moves) != f"{new_target}.{n}"}
            if moved_parents:
                if len(moved_parents) > 1 or len(moved_parents) != 1 or any(
                        remap(f"{target}.{n}", moves) == f"{new_target}.{n}" for n in names):
                    raise SystemExit(f"{path}:{node.lineno}: mixed module import, fix by hand")
                new_target = moved_parents.pop()
            if new_target == target and new_pkg == old_pkg:
                continue
            top = new_target.split(".")[0]
            if node.level and new_pkg and new_pkg.split(".")[0] == top:
                text_mod = relative(new_target, new_pkg)
            else:
                text_mod = new_target
            seg = ast.get_source_segment(src, node)
            head = "from " + ("." * node.level + (node.module or ""))
            i = seg.index(" import ") + 1
            new_seg = f"from {text_mod} " + seg[i:]
            if new_seg != seg:
                edits.append((node.lineno, node.col_offset, node.end_lineno, node.end_col_offset,
                              new_seg))
            del head
        elif isinstance(node, ast.Import):
            parts = []
            changed = False
            for a in node.names:
                n = remap(a.name, moves)
                changed |= n != a.name
                parts.append(n + (f" as {a.asname}" if a.asname else ""))
            if changed:
                edits.append((node.lineno, node.col_offset, node.end_lineno, node.end_col_offset,
                              "import " + ", ".join(parts)))
    if not edits:
        return False
    offsets = [0]
    for line in lines:
        offsets.append(offsets[-1] + len(line))
    out = src
    for l0, c0, l1, c1, text in sorted(edits, reverse=True):
        a = offsets[l0 - 1] + len(lines[l0 - 1].encode()[:c0].decode())
        b = offsets[l1 - 1] + len(lines[l1 - 1].encode()[:c1].decode())
        out = out[:a] + text + out[b:]
    path.write_text(out, encoding="utf-8")
    return True


def main(argv: list[str]) -> None:
    moves = dict(arg.split("=", 1) for arg in argv)
    files = sorted(p for d in SCAN for p in d.rglob("*.py") if ".venv" not in p.parts)
    old_mods = {p: module_of(p) for p in files}
    # move files
    for old, new in moves.items():
        src, dst = module_path(old), module_path(new)
        if src.is_dir():
            dst = dst.with_suffix("")
        dst.parent.mkdir(parents=True, exist_ok=True)
        init = dst.parent / "__init__.py"
        if not init.exists() and dst.parent != ROOT / "baselines":
            init.write_text(f'"""{dst.parent.name}."""\n', encoding="utf-8")
            subprocess.run(["git", "add", str(init)], cwd=ROOT, check=True)
        subprocess.run(["git", "mv", str(src), str(dst)], cwd=ROOT, check=True)
    files_new = {}
    for p, mod in old_mods.items():
        if mod is None:
            files_new[p] = (p, None, None)
            continue
        new_name = remap(mod[0], moves)
        new_path = module_path(new_name)
        if mod[1]:
            new_path = new_path / "__init__.py"
        files_new[p] = (new_path, mod, (new_name, mod[1]))
    n = 0
    for _, (path, old_mod, new_mod) in files_new.items():
        if not path.exists():
            print("missing after move:", path, file=sys.stderr)
            continue
        n += rewrite(path, old_mod, new_mod, moves)
    print(f"moved {len(moves)}; rewrote imports in {n} files")


if __name__ == "__main__":
    main(sys.argv[1:])
