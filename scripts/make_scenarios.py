"""Write the scenario library in scenarios/ with the generator of ``swarm scenario new``.

Usage: ``python scripts/make_scenarios.py`` (writes every file; ``make scenarios`` runs it) or
``python scripts/make_scenarios.py --check`` (exit 1 if a file differs from what the generator
makes now). Each file's header records the equivalent ``swarm scenario new`` command.
scenarios/paper.toml has its own script (scripts/make_paper_scenario.py).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from gcs.report.scenario_summary import envelope_problem
from protocols.scenario.generator import FaultRequest, GeneratorOptions, generate

ROOT = Path(__file__).resolve().parents[1]
#: Issue 10's large-swarm flight: take-off, a 20 m move with a 30 deg turn and a 15 % stretch, an
#: agent drop-out, a vehicle crash and 20 % loss on every link, 2.5 m apart with a 6 m range.
LARGE_FAULTS = FaultRequest(dropouts=1, crashes=1, loss=0.2)

LIBRARY: dict[str, GeneratorOptions] = {
    "grid16_turn.toml": GeneratorOptions(16, "grid", name="grid16-turn"),
    "survey25.toml": GeneratorOptions(25, "grid", template="survey", name="survey25"),
    "ring12.toml": GeneratorOptions(12, "circle", template="paper", name="ring12"),
    "large_grid25.toml": GeneratorOptions(25, "grid", faults=LARGE_FAULTS, name="large-grid25"),
    "large_grid100.toml": GeneratorOptions(100, "grid", faults=LARGE_FAULTS, name="large-grid100"),
    "large_grid250.toml": GeneratorOptions(250, "grid", faults=LARGE_FAULTS, name="large-grid250"),
}


def render_all() -> dict[Path, str]:
    """Every library file's path and text; ValueError if one leaves the envelope."""
    out: dict[Path, str] = {}
    for name, options in LIBRARY.items():
        generated = generate(options, f"scenarios/{name}")
        problem = envelope_problem(generated.scenario)
        if problem is not None:
            raise ValueError(f"scenarios/{name}: the plan leaves the envelope {problem}")
        out[ROOT / "scenarios" / name] = generated.text
    return out


def main(argv: Sequence[str]) -> int:
    """Write the library, or with ``--check`` report the files that are out of date."""
    files = render_all()
    if "--check" in argv:
        stale = [p for p, text in files.items() if not p.exists() or p.read_text() != text]
        for p in stale:
            print(f"{p.relative_to(ROOT)} is out of date: run make scenarios", file=sys.stderr)
        return 1 if stale else 0
    for path, text in files.items():
        path.write_text(text, encoding="utf-8")
        print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
