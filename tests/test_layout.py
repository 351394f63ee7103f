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
    assert {"protocols.model.frames", "sitl_sim.vehicle.setpoint"} <= graph[
        "sitl_sim.vehicle.setpoint_jit"
    ]  # it reads
    cycles = [sorted(cycle) for cycle in _cycles(graph)]
    assert not cycles, f"import cycles: {cycles}"


def _imported_names(path: Path) -> set[str]:
    """The modules ``path`` imports by absolute name, anywhere in it."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
    return found


def _imports(path: Path) -> set[str]:
    """The top-level project packages that ``path`` imports."""
    return {n.split(".")[0] for n in _imported_names(path)} & PROJECT


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


#: A concern (a sub-package, or a package's own modules: "sitl_sim", "protocols.faults") -> the
#: concerns it may import besides itself. protocols' concerns build up from the model; in each
#: role the pure core imports no run-time side (agent: core <- process; simulator: physics <-
#: vehicle <- mavlink_edge <- the event loop and ``swarm sim``).
CONCERNS: dict[str, set[str]] = {
    "protocols.runtime": set(),
    "protocols.faults": set(),
    "protocols.model": {"protocols.runtime"},
    "protocols.wire": {"protocols.model", "protocols.faults", "protocols.runtime"},
    "protocols.mavlink": {"protocols.model", "protocols.runtime"},
    "protocols.scenario": {"protocols.model", "protocols.faults", "protocols.runtime"},
    "protocols.secrets": {"protocols.wire"},
    "protocols.bus": {"protocols.secrets", "protocols.wire"},
    "drone_agent.core": {
        "protocols.runtime",
        "protocols.model",
        "protocols.wire",
        "protocols.mavlink",
        "protocols.scenario",
        "protocols.faults",
    },
    "drone_agent.process": {"drone_agent.core", "protocols.*"},
    "sitl_sim.physics": {"protocols.model", "protocols.runtime"},
    "sitl_sim.vehicle": {
        "sitl_sim.physics",
        "protocols.model",
        "protocols.runtime",
        "protocols.mavlink",
        "protocols.scenario",
    },
    "sitl_sim.mavlink_edge": {
        "sitl_sim.vehicle",
        "sitl_sim.physics",
        "protocols.model",
        "protocols.runtime",
        "protocols.mavlink",
    },
    "sitl_sim": {"sitl_sim.*", "protocols.*"},
}
#: The most modules a folder of protocols, the agent or the simulator holds side by side (a bigger
#: one is split by concern).
MAX_MODULES = 15


def _concern(module: str) -> str:
    """The concern a module belongs to: ``drone_agent.core.consensus.kernels`` ->
    ``drone_agent.core``; a package's own module ``protocols.faults`` -> itself,
    ``sitl_sim.server`` -> ``sitl_sim``."""
    parts = module.split(".")
    if parts[0] == "protocols" and len(parts) == 2:
        return module
    return ".".join(parts[:2]) if len(parts) > 2 else parts[0]


def _allowed(concern: str, other: str) -> bool:
    rules = CONCERNS[concern]
    return other == concern or other in rules or f"{other.split('.')[0]}.*" in rules


def test_every_concern_has_a_rule() -> None:
    concerns = {_concern(m) for m in _import_graph() if m.split(".")[0] in ALLOWED}
    assert concerns - {"protocols", "drone_agent"} == set(CONCERNS)


def test_concerns_import_only_what_their_rule_allows() -> None:
    """Inside protocols, the agent and the simulator, each concern imports only those below it."""
    graph = _import_graph()
    wrong = sorted(
        f"{m} -> {d}"
        for m, deps in graph.items()
        if m.split(".")[0] in ALLOWED and m.count(".")
        for d in deps
        if not _allowed(_concern(m), _concern(d))
    )
    assert not wrong, wrong


def test_no_folder_is_a_drawer() -> None:
    """No folder holds more than MAX_MODULES modules side by side; the agent's modules all live
    in a concern, as protocols' do (besides the one fault vocabulary)."""
    crowded = {
        str(folder.relative_to(ROOT)): n
        for package in sorted(ALLOWED)
        for folder in [ROOT / package, *(ROOT / package).rglob("*/")]
        if folder.is_dir()
        and "__pycache__" not in folder.parts
        and (n := len([p for p in folder.glob("*.py") if p.name != "__init__.py"])) > MAX_MODULES
    }
    assert not crowded
    flat = {
        package: sorted(p.stem for p in (ROOT / package).glob("*.py") if p.name != "__init__.py")
        for package in ("protocols", "drone_agent")
    }
    assert flat == {"protocols": ["faults"], "drone_agent": []}


def test_numba_is_reached_through_one_helper() -> None:
    """Only protocols/runtime/compiled.py imports numba: every compiled function follows its
    rules (lazy, cached, the plain function's own code)."""
    importers = sorted(
        str(p.relative_to(ROOT))
        for package in sorted(PROJECT)
        for p in (ROOT / package).rglob("*.py")
        if "numba" in {n.split(".")[0] for n in _imported_names(p)}
    )
    assert importers == ["protocols/runtime/compiled.py"]
