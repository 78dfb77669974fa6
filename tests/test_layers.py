"""The package's layers (docs/architecture.md), checked from the import statements of src/.

Every ``import`` counts, at module level or inside a function, and so do imports
under ``if TYPE_CHECKING:`` (a type-only import runs nothing, but it still ties
one module to another's names: two modules that name each other's types are
one module in two files).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def _modules() -> dict[str, Path]:
    out = {}
    for path in (SRC / "pyethercat").rglob("*.py"):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(module: str) -> list[tuple[str, bool]]:
    """(imported module, type-only) for every import statement of ``module``."""
    path = MODULES[module]
    tree = ast.parse(path.read_text("utf-8"))
    found: list[tuple[str, bool]] = []

    def target(name: str) -> str | None:
        while name and name not in MODULES:
            name = name.rpartition(".")[0]
        return name or None

    def visit(node: ast.AST, typing_only: bool) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.body:
                visit(child, True)
            for child in node.orelse:
                visit(child, typing_only)
            return
        if isinstance(node, ast.Import):
            for alias in node.names:
                if (t := target(alias.name)) is not None:
                    found.append((t, typing_only))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
                package = package[:len(package) - (node.level - 1)]
                base = ".".join(package + ([base] if base else []))
            for alias in node.names:
                name = f"{base}.{alias.name}"
                if (t := target(name if name in MODULES else base)) is not None:
                    found.append((t, typing_only))
        for child in ast.iter_child_nodes(node):
            visit(child, typing_only)

    visit(tree, False)
    return [(t, typing_only) for t, typing_only in found if t != module]


GRAPH = {m: _imports(m) for m in MODULES}


def _cycles(include_typing: bool) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan)."""
    edges = {m: sorted({t for t, typing_only in deps if include_typing or not typing_only})
             for m, deps in GRAPH.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []
    counter = 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(edges[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, it = work[-1]
            nxt = next(it, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(edges[nxt])))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    m = stack.pop()
                    on_stack.discard(m)
                    group.append(m)
                    if m == node:
                        break
                if len(group) > 1:
                    groups.append(sorted(group))
    return groups


def test_the_checker_sees_imports_inside_functions_and_type_checking_blocks() -> None:
    deps = GRAPH["pyethercat.master.master"]
    assert ("pyethercat.master.scheduler", False) in deps
    assert ("pyethercat.link.registry", False) in deps  # imported inside Master.open
    assert ("pyethercat.esi.eni", True) in GRAPH["pyethercat.master.slave_info"]


def test_no_import_cycles() -> None:
    assert _cycles(include_typing=False) == []


def test_no_import_cycles_through_type_only_imports_either() -> None:
    assert _cycles(include_typing=True) == []


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


# Which top-level parts of the package each part may import (besides itself and errors).
ALLOWED = {
    "wire": {"errors"},
    "esi": {"errors", "wire"},
    "clock": set(),
    # The package's version string.
    "version": set(),
    # Real-time settings of a process (SCHED_FIFO, affinity, mlockall).
    "realtime": set(),
    # The topology file format (text in, typed entries out), read by both sides.
    "topology": {"errors"},
    # Motion profiles (numpy only), sampled for the master's drive helper and for users.
    "trajectory": {"errors"},
    "link": {"errors", "wire"},
    "master": {"errors", "wire", "esi", "link", "clock", "topology", "trajectory", "realtime",
               "version"},
    "sim": {"errors", "wire", "esi", "link", "clock", "topology", "realtime"},
    # The dashboard: a client of the master (never of the simulator or the command line).
    "web": {"errors", "wire", "esi", "link", "clock", "master"},
}


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_layers_import_only_what_is_below_them(layer: str) -> None:
    wrong = []
    for module, deps in GRAPH.items():
        if _layer(module) != layer:
            continue
        for target, _typing_only in deps:
            other = _layer(target)
            if other and other != layer and other not in ALLOWED[layer]:
                wrong.append(f"{module} imports {target}")
    assert wrong == []
