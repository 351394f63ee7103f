"""The packages import only downwards: protocols <- sitl_sim, drone_agent <- gcs, and no module
imports itself through others (no import cycle).

``protocols`` (the wire, scenarios, conventions) is what every side speaks and imports none of
them; the simulator and the agents never reach up into the ground side. Checked on the import
statements of every module (also those inside functions: a cycle closed by a function-level import
is still two modules that need each other)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: package -> the project packages it may import
ALLOWED = {
    "protocols": {"protocols"},
    "sitl_sim": {"protocols", "sitl_sim"},
    "drone_agent": {"protocols", "drone_agent"},
}
PROJECT = {"protocols", "sitl_sim", "drone_agent", "gcs"}
#: The packages whose modules must not import each other in a cycle.
CYCLE_FREE = ("protocols", "sitl_sim", "drone_agent", "gcs", "bench")


def _module_of(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _import_graph() -> dict[str, set[str]]:
    """Each project module (dotted name) -> the project modules it imports, anywhere in it.
    ``from a.b import c`` is an import of the module ``a.b.c`` when there is one, else of
    ``a.b``; relative imports are resolved."""
    paths = [p for package in CYCLE_FREE for p in sorted((ROOT / package).rglob("*.py"))]
    modules = {_module_of(p): p for p in paths}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                found |= {f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                          for a in node.names}  # fmt: skip
        graph[name] = {m for m in found if m in modules and m != name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[frozenset[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(frozenset(component))
    return found


def test_the_cycle_finder_finds_cycles() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e2"}, "e2": {"e"}}
    assert sorted(map(sorted, _cycles(graph))) == [["a", "b", "c"], ["e", "e2"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles() -> None:
    """No module imports itself through others."""
    graph = _import_graph()
    assert {"protocols.frames", "sitl_sim.setpoint"} <= graph["sitl_sim.setpoint_jit"]  # it reads
    cycles = [sorted(cycle) for cycle in _cycles(graph)]
    assert not cycles, f"import cycles: {cycles}"


def _imports(path: Path) -> set[str]:
    """The top-level project packages that ``path`` imports."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found |= {n.split(".")[0] for n in names} & PROJECT
    return found


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_downwards(package: str) -> None:
    wrong = {
        str(p.relative_to(ROOT)): sorted(_imports(p) - ALLOWED[package])
        for p in sorted((ROOT / package).rglob("*.py"))
    }
    assert not {k: v for k, v in wrong.items() if v}


def test_gcs_modules_live_in_their_concern() -> None:
    """gcs/ holds sub-packages by concern and no flat modules besides its package file."""
    flat = sorted(p.name for p in (ROOT / "gcs").glob("*.py") if p.name != "__init__.py")
    assert not flat
    assert {p.name for p in (ROOT / "gcs").iterdir() if (p / "__init__.py").exists()} == {
        "api",  # the public Python API (docs/api.md)
        "cli",
        "station",
        "reference",
        "report",
        "view",
    }
