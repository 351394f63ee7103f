"""How fast ``swarm up`` flies with its agents in one process, in two, or one per drone:
``python -m bench.layouts [--out FILE]``; also ``python -m bench.run --only layouts``.

Each case flies a scenario's first seconds with ``swarm up SCENARIO --duration-s S
--agents-per-process K`` (lockstep, default ports) and reads the real-time factor of the whole
flight from its report (metrics.json) and the run's wall time (start-up and report included).
The default layout (gcs/cli/up.py's default_agents_per_process) rests on these figures; the
committed result is bench/results_layouts.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.provenance import write_result

ROOT = Path(__file__).resolve().parents[1]
#: (scenario, simulated seconds, agents per process)
CASES = (
    ("scenarios/paper.toml", 40.0, (1, 5, 9)),
    ("scenarios/grid16_turn.toml", 30.0, (1, 8, 16)),
    ("scenarios/large_grid25.toml", 30.0, (13, 25)),
)


def run_case(scenario: str, seconds: float, k: int, report: Path) -> dict[str, Any]:
    """One flight; its row."""
    argv = [sys.executable, "-m", "gcs.cli", "up", scenario, "--duration-s", str(seconds),
            "--agents-per-process", str(k), "--report", str(report)]  # fmt: skip
    start = time.monotonic()
    done = subprocess.run(argv, cwd=ROOT, env={**os.environ, "MAVLINK20": "1"},
                          capture_output=True, text=True, timeout=1200)  # fmt: skip
    wall = time.monotonic() - start
    row: dict[str, Any] = {"scenario": scenario, "seconds": seconds, "agents_per_process": k}
    if done.returncode != 0:
        return {**row, "error": done.stderr.strip().splitlines()[-1:]}
    metrics = json.loads((report / "metrics.json").read_text())
    return {**row, "real_time_factor": metrics.get("real_time_factor"), "wall_s": round(wall, 1)}


def layouts() -> dict[str, Any]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-layouts-") as tmp:
        for n, (scenario, seconds, ks) in enumerate(CASES):
            for k in ks:
                rows.append(run_case(scenario, seconds, k, Path(tmp) / f"r{n}-{k}"))
                print(rows[-1], flush=True)
    return {"rows": rows}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.layouts", description=__doc__)
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results_layouts.json")
    args = parser.parse_args(argv)
    result = layouts()
    write_result(args.out, result, indent=2)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
