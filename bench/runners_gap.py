"""How far the distributed flight is from the in-process one (issue 10's bar: every drone within
5 cm): ``python -m bench.runners_gap [--scenario FILE] [--per-process K] [--duration-s S]``.

Flies one scenario twice, as a user would: ``swarm simulate FILE`` and ``swarm up FILE --clock
lockstep --agents-per-process K`` (real processes, Zenoh, MAVLink; free ports and a swarm id of
its own, so it runs beside anything), then compares the two flight.tlogs alone: for every vehicle
and every ``time_boot_ms`` both logged, the distance between the two LOCAL_POSITION_NED
positions. Drones a scenario fault takes out (drop-out, crash) are reported apart (their
vehicles are one model in both runners, sitl_sim/vehicle/world.py: a dropped agent's vehicle lands
on its own failsafe in both the same way).

Writes ``bench/results_runners_gap.json`` (per drone: the largest gap and when it first exceeded
1 mm; the median and largest over drones; how many drones are beyond the 5 cm bar) and prints a
summary. About 5 minutes for the 100-drone grid on the 2-core machine (the lockstep flight runs
at a quarter of real time there).
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

import numpy as np

from bench.provenance import write_result
from bench.sitl import _free_block
from gcs.report.tlog import vehicle_samples
from protocols.faults import Crash, Dropout
from protocols.scenario.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parents[1]
OUT_JSON = ROOT / "bench" / "results_runners_gap.json"
BAR_M = 0.05
_ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _swarm(*args: str, cwd: Path) -> float:
    """Run ``swarm ARGS`` (wall seconds); RuntimeError with its output's tail if it fails."""
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "gcs.cli", *args], capture_output=True, text=True, env=_ENV, cwd=cwd
    )
    if done.returncode != 0:
        raise RuntimeError(f"swarm {args[0]} failed: {done.stdout[-1500:]}{done.stderr[-1500:]}")
    return time.monotonic() - t0


def gaps(sim_tlog: Path, up_tlog: Path) -> dict[int, tuple[float, float | None, int]]:
    """Per system id: (largest position gap m, first time s above 1 mm or None, samples)."""
    sim, up = vehicle_samples(sim_tlog), vehicle_samples(up_tlog)
    out: dict[int, tuple[float, float | None, int]] = {}
    for key in sorted(sim.keys() & up.keys(), key=lambda k: (k[1], k[2])):
        name, sysid, t_ms = key
        if name != "LOCAL_POSITION_NED":
            continue
        gap = float(np.linalg.norm(np.subtract(sim[key][:3], up[key][:3])))
        worst, first, count = out.get(sysid, (0.0, None, 0))
        if first is None and gap > 1e-3:
            first = t_ms / 1000.0
        out[sysid] = (max(worst, gap), first, count + 1)
    return out


def runners_gap(
    scenario: Path = ROOT / "scenarios" / "large_grid100.toml",
    per_process: int = 25,
    duration_s: float | None = None,
    keep: Path | None = None,
) -> dict[str, Any]:
    """Fly ``scenario`` both ways and compare (module docstring)."""
    spec = load_scenario(scenario)
    lost = {f.drone + 1 for f in spec.faults if isinstance(f, Dropout | Crash)}
    n = spec.n_drones
    extra = ["--duration-s", str(duration_s)] if duration_s else []
    with tempfile.TemporaryDirectory() as tmp:
        work = keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        load = os.getloadavg()[0]
        sim_s = _swarm("simulate", str(scenario), "--report", "sim", "--no-plots", *extra, cwd=work)
        base, gcs_port = _free_block(n), _free_block(1)
        up_s = _swarm(
            *("up", str(scenario), "--clock", "lockstep", "--agents-per-process", str(per_process)),
            *("--report", "up", "--base-port", str(base)),
            *("--gcs-port", str(gcs_port), "--swarm-id", f"gap{os.getpid()}", *extra),
            cwd=work,
        )
        per = gaps(work / "sim" / "flight.tlog", work / "up" / "flight.tlog")
    flying = {s: g for s, g in per.items() if s not in lost}
    worst = np.array([g[0] for g in flying.values()]) if flying else np.zeros(1)
    firsts = [g[1] for g in flying.values() if g[1] is not None]
    return {
        "scenario": str(scenario.relative_to(ROOT) if scenario.is_relative_to(ROOT) else scenario),
        "drones": n,
        "agents_per_process": per_process,
        "load_1min_at_start": round(load, 2),
        "simulate_wall_s": round(sim_s, 1),
        "up_wall_s": round(up_s, 1),
        "compared_drones": len(flying),
        "median_max_gap_m": round(float(np.median(worst)), 5),
        "max_gap_m": round(float(worst.max()), 5),
        "drones_beyond_bar": int((worst > BAR_M).sum()),
        "bar_m": BAR_M,
        "first_departure_s": min(firsts) if firsts else None,
        "lost_by_faults": {str(s): round(per[s][0], 4) for s in sorted(lost) if s in per},
        "per_drone": {str(s): [round(g[0], 5), g[1], g[2]] for s, g in sorted(flying.items())},
    }


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point (module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", type=Path, default=ROOT / "scenarios" / "large_grid100.toml")
    parser.add_argument("--per-process", type=int, default=25)
    parser.add_argument("--duration-s", type=float, default=None)
    parser.add_argument("--out", type=Path, default=OUT_JSON)
    parser.add_argument("--keep", type=Path, help="fly in this folder and keep both reports")
    args = parser.parse_args(argv)
    keep = args.keep.resolve() if args.keep else None
    result = runners_gap(args.scenario.resolve(), args.per_process, args.duration_s, keep)
    brief = {k: v for k, v in result.items() if k != "per_drone"}
    print(json.dumps(brief, indent=1))
    write_result(args.out, result, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
