"""The packages import only downwards: protocols <- sitl_sim, drone_agent <- gcs.

``protocols`` (the wire, scenarios, conventions) is what every side speaks and imports none of
them; the simulator and the agents never reach up into the ground side. Checked on the import
statements of every module (also those inside functions)."""

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
