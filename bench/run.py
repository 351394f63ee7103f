"""Run the registered benchmarks and write one JSON object: ``python -m bench.run --out FILE``.

To add a benchmark, put a callable returning a JSON-able dict into ``BENCHMARKS``. A result with a
``"rows"`` list of flat dicts is also printed as a table. Those in ``ON_REQUEST`` run only when
named with ``--only`` (measured once, their JSON kept in bench/).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.agent_batch import agent_batch
from bench.autopilots import autopilots
from bench.end_to_end import end_to_end
from bench.layouts import layouts
from bench.messaging_floor import messaging_floor
from bench.physics import physics_step
from bench.physics_tick import physics_tick
from bench.provenance import commit, load_average, machine_speed
from bench.runners_gap import runners_gap
from bench.session import session
from bench.settling import settling
from bench.simulate_rtf import simulate_rtf
from bench.sitl import sitl_rtf
from bench.tables import format_rows
from bench.up_lockstep import up_lockstep
from bench.zenoh_latency import zenoh_latency
from bench.zenoh_router import zenoh_router

Benchmark = Callable[[], dict[str, Any]]

BENCHMARKS: dict[str, Benchmark] = {
    "physics_step": physics_step,
    "physics_tick": physics_tick,
    "agent_batch": agent_batch,
    "simulate_rtf": simulate_rtf,
    "settling": settling,
    "zenoh_latency": zenoh_latency,
    "zenoh_router": zenoh_router,
    "sitl": sitl_rtf,
    "end_to_end": end_to_end,
    "up_lockstep": up_lockstep,
    "messaging_floor": messaging_floor,
    "runners_gap": runners_gap,
    "autopilots": autopilots,
    "layouts": layouts,
    "session": session,
}
#: Run only with ``--only NAME``: ``swarm up --clock lockstep`` at N = 9 and 100 (about 10 min);
#: the 100-drone flight distributed and in process, compared (about 5 min on a quiet machine).
#: the same flight on our simulator in both dialects and on ArduCopter SITL (about 4 min).
#: swarm up with its agents in one process, two, or one per drone (about 4 min).
#: the README's 16-drone operator session, three times (about 1 min; default ports).
ON_REQUEST = {"up_lockstep", "runners_gap", "messaging_floor", "autopilots", "layouts", "session"}


def machine_info() -> dict[str, Any]:
    """Where the numbers were measured."""
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "processor": platform.processor(),
        "cpu_count": os.cpu_count(),
        "usable_cpus": len(affinity) if affinity is not None else None,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "commit": commit(),
        "load_average": load_average(),
        "machine_speed": machine_speed(),
    }


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point: run the benchmarks, print tables, write the JSON file."""
    parser = argparse.ArgumentParser(prog="python -m bench.run", description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("bench/results.json"))
    parser.add_argument("--only", action="append", choices=sorted(BENCHMARKS), default=None)
    args = parser.parse_args(argv)
    results: dict[str, Any] = {}
    for name in args.only or [b for b in BENCHMARKS if b not in ON_REQUEST]:
        result = BENCHMARKS[name]()
        results[name] = result
        if result.get("rows"):
            print(format_rows(name, result["rows"]))
        if "target_met" in result:
            print(f"{name}: target {result.get('target')} met: {result['target_met']}")
    results["machine"] = machine_info()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
