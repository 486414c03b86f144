"""The package layout's rules (docs/layout.md), read from the source: no two sgdr packages import
each other, nothing in sgdr but the entry-point helpers imports the orchestration, and no private
name is imported across packages."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SGDR = ROOT / "sgdr"


def _room(module: str) -> str:
    """The package a module belongs to: `sgdr.<package>` for a module inside a sub-package,
    the module itself for a top-level module (`sgdr.cli`, `sgdr.run_folder`, ...)."""
    parts = module.split(".")
    if len(parts) >= 2 and (SGDR / parts[1]).is_dir():
        return ".".join(parts[:2])
    return ".".join(parts[:2]) if len(parts) >= 2 else module


def _imports(folder: Path):
    """(file, line, importing room, imported module, imported names) of every sgdr import,
    function-level ones included."""
    for path in sorted(folder.rglob("*.py")):
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("sgdr"):
                yield path, node.lineno, _room(module), node.module, [a.name for a in node.names]
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("sgdr."):
                        yield path, node.lineno, _room(module), a.name, []


def test_no_two_packages_import_each_other():
    edges = defaultdict(set)
    for path, line, room, target, names in _imports(SGDR):
        full = [f"{target}.{n}" for n in names] or [target]
        for t in full:
            other = _room(t if (ROOT / Path(*t.split("."))).with_suffix(".py").exists() else target)
            if other != room and other != "sgdr.__init__":
                edges[room].add((other, f"{path.relative_to(ROOT)}:{line}"))
    cycles = []
    for a, outs in edges.items():
        for b, where in outs:
            back = [w for c, w in edges.get(b, ()) if c == a]
            if back and a < b:
                cycles.append(f"{a} <-> {b}: {where}, {back[0]}")
    assert not cycles, "packages that import each other:\n" + "\n".join(cycles)


def test_only_entry_points_import_the_orchestration():
    users = {
        f"{path.relative_to(ROOT)}:{line}"
        for path, line, room, target, _ in _imports(SGDR)
        if target.startswith("sgdr.pipeline") and room not in ("sgdr.pipeline", "sgdr.cli")
    }
    assert not users, f"sgdr modules that import sgdr.pipeline (only sgdr/cli.py may): {sorted(users)}"


def test_no_private_name_crosses_packages():
    crossing = [
        f"{path.relative_to(ROOT)}:{line} {target}.{n}"
        for folder in (SGDR, ROOT / "evaluation", ROOT / "experiments")
        for path, line, room, target, names in _imports(folder)
        for n in names
        if n.startswith("_") and _room(target) != room
    ]
    assert not crossing, "private names imported across packages:\n" + "\n".join(crossing)


def test_the_product_imports_no_research():
    research = [
        f"{path.relative_to(ROOT)}:{node.lineno}"
        for path in sorted(SGDR.rglob("*.py"))
        for node in ast.walk(ast.parse(path.read_text()))
        if (isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "evaluation")
        or (isinstance(node, ast.Import) and any(a.name.split(".")[0] == "evaluation" for a in node.names))
    ]
    assert not research, f"sgdr modules that import evaluation/: {research}"
