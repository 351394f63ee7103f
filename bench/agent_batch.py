"""Cost of the agents' maths per agent-tick, batched vs one by one, and ``swarm simulate``'s speed.

``python -m bench.agent_batch [--before REV] [--repeats 3]`` (about 10 minutes with the default
before revision; ``--quick`` for a smoke run).

- ``maths``: CPU time (``time.process_time``) of the agent core alone per agent-tick, on N = 100
  drones hovering on a grid 2.5 m apart with a 6 m radio range (about 16 neighbours each; the
  in-memory radio of ``swarm simulate`` carries their messages, untimed), hosted in batches of K =
  1, 9, 25, 100 (:class:`~drone_agent.core.agent_core.BatchAgentCore`, one call per batch per tick);
  ``before`` is the code at ``--before`` (one ``AgentCore.tick`` per agent).
- ``simulate``: ``swarm simulate`` real-time factor (the flight loop's wall time as metrics.json
  reports it) of ``scenarios/paper.toml`` (N = 9, 200 s) and of the N = 100 grid hovering (30 s).
- ``--profile``: where one control tick of ``swarm simulate`` goes, per part (agent maths and its
  parts, radio, physics, the rest), at N = 9 (paper, first 40 s) and N = 100 (grid, first 6 s),
  before and after, written to ``bench/agent_batch_profile.txt``.

Every figure runs in a fresh process with ``PYTHONPATH`` at either tree; before and after take
turns within each repeat and the faster of the repeats is kept (the machine is shared and noisy).
The JSON goes to ``bench/results_agent_batch.json``.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.provenance import write_result

ROOT = Path(__file__).resolve().parents[1]
BATCH_SIZES = (1, 9, 25, 100)
MATHS_N = 100
MATHS_TICKS = 150
GRID_SIM_N = 100
GRID_SIM_S = 30.0


def _grid_scenario(n: int, duration_s: float, folder: Path) -> Path:
    from bench.end_to_end import scenario_text

    path = folder / f"grid{n}.toml"
    path.write_text(scenario_text(n, duration_s), encoding="utf-8")
    return path


# -- workers (run in a child process with PYTHONPATH at the tree under test) -------------------
def maths_worker(n: int, k: int, ticks: int) -> dict[str, Any]:
    """CPU µs per agent-tick of the core, N drones in batches of K (one by one without
    BatchAgentCore, i.e. before)."""
    from drone_agent.core import agent_core
    from drone_agent.core.config import agent_config
    from gcs.reference.network import InProcessNetwork
    from protocols.scenario.scenario_file import load_scenario

    with tempfile.TemporaryDirectory() as tmp:
        scenario = load_scenario(_grid_scenario(n, 20.0, Path(tmp)))
    config = agent_config(scenario)
    plan = scenario.trajectory()
    home = scenario.positions_ned_m() + np.array([0.0, 0.0, -3.0])
    rng = np.random.default_rng(1)
    net = InProcessNetwork(n, scenario.comms.range_m, rng)
    members = frozenset(range(n))
    batched = hasattr(agent_core, "BatchAgentCore")
    chunks = [list(range(lo, min(lo + k, n))) for lo in range(0, n, k)]
    if batched:
        cores = [agent_core.BatchAgentCore(ids, config) for ids in chunks]
    else:
        singles = [agent_core.AgentCore(i, config) for i in range(n)]
    phase = rng.uniform(0, 2 * np.pi, size=(n, 3))
    cpu = 0.0
    warm = 20
    for tick in range(ticks + warm):
        t_s = 5.0 + 0.02 * tick
        pos = home + 0.05 * np.sin(0.5 * t_s + phase)
        vel = 0.025 * np.cos(0.5 * t_s + phase)
        inboxes = net.receive(tick)
        c0 = time.process_time()
        if batched:
            outs = []
            for core, ids in zip(cores, chunks, strict=True):
                outs += core.tick(
                    range(len(ids)),
                    tick,
                    t_s,
                    pos[ids],
                    vel[ids],
                    [plan] * len(ids),
                    [inboxes[i] for i in ids],
                    [members] * len(ids),
                )
        else:
            outs = [
                a.tick(tick, t_s, pos[i], vel[i], plan, inboxes[i], members)
                for i, a in enumerate(singles)
            ]
        c1 = time.process_time()
        if tick >= warm:
            cpu += c1 - c0
        assert all(o.setpoint is not None for o in outs)
        net.send(tick, [o.message for o in outs], net.in_range(pos))
    degree = float(np.mean([len(o.active_neighbours) for o in outs]))
    return {"us_per_agent_tick": 1e6 * cpu / (ticks * n), "mean_degree": degree}


def simulate_worker(scenario: str, duration_s: float | None) -> dict[str, Any]:
    """``swarm simulate`` (:func:`gcs.reference.simulate.simulate`, no plots) of a scenario file (or
    ``grid``), in this process so that the tree under test is what runs: its real-time factor
    as metrics.json reports it (the flight loop's wall time)."""
    import dataclasses

    from gcs.reference.simulate import simulate
    from protocols.scenario.scenario_file import load_scenario

    with tempfile.TemporaryDirectory() as tmp:
        path = (
            _grid_scenario(GRID_SIM_N, GRID_SIM_S, Path(tmp))
            if scenario == "grid"
            else Path(scenario)
        )
        sc = load_scenario(path)
        if duration_s is not None:
            sc = dataclasses.replace(sc, duration_s=duration_s)
        metrics = simulate(sc, Path(tmp) / "report", plots=False).metrics
    return {
        "real_time_factor": metrics["real_time_factor"],
        "wall_time_s": metrics["wall_time_s"],
        "centroid_rms_m": metrics["tracking"]["centroid_m"]["rms"],
    }


#: (label, function) parts timed per control tick; the name is looked up in the tree under test.
_PARTS = (
    ("agents (core)", "drone_agent.core.agent_core", "BatchAgentCore", "tick"),
    ("agents (core)", "drone_agent.core.agent_core", "AgentCore", "tick"),
    ("agents (core)", "drone_agent.core.agent_core", "BatchAgentCore", "tick_columns"),
    ("  consensus step", "drone_agent.core.consensus.estimator", "BatchConsensus", "step"),
    ("  consensus step", "drone_agent.core.consensus.estimator", "BatchConsensus", "step_messages"),
    ("  consensus step", "drone_agent.core.consensus.estimator", "BatchConsensus", "step_outgoing"),
    ("  consensus step", "drone_agent.core.consensus.scalar", "ConsensusEstimator", "step"),
    ("  descriptor frame (eigh, axes)", "protocols.model.descriptors", None, "align_axes_batch"),
    ("  descriptor frame (eigh, axes)", "protocols.model.descriptors", None, "align_axes"),
    ("  cooperative field", "drone_agent.core.cooperative", None, "virtual_acceleration_batch"),
    ("  cooperative field", "drone_agent.core.cooperative", None, "virtual_acceleration"),
    ("  thrust and attitude", "drone_agent.core.thrust_attitude", None, "attitude_thrust_batch"),
    ("  thrust and attitude", "drone_agent.core.thrust_attitude", None, "attitude_thrust"),
    ("  plan evaluation", "protocols.model.trajectory", "DescriptorTrajectory", "evaluate"),
    ("  separation layer", "drone_agent.core.separation.layer", "SeparationLayer", "filter"),
    (
        "    neighbours heard (filing, query)",
        "drone_agent.core.neighbours",
        "NeighbourTable",
        "hear",
    ),
    (
        "    neighbours heard (filing, query)",
        "drone_agent.core.neighbours",
        "NeighbourTable",
        "query",
    ),
    ("    nobody-near pre-check", "drone_agent.core.separation.filter", None, "nobody_near"),
    (
        "    filter (agents not cleared)",
        "drone_agent.core.separation.filter",
        None,
        "filter_accelerations",
    ),
    ("readiness and flight phase", "drone_agent.core.flight_phase", "Readiness", "update"),
    ("readiness and flight phase", "drone_agent.core.flight_phase", "BatchReadiness", "update"),
    ("readiness and flight phase", "gcs.reference.flight", "ReferenceFlight", "_decide"),
    ("radio (in-memory, send + receive)", "gcs.reference.network", "InProcessNetwork", "send"),
    ("radio (in-memory, send + receive)", "gcs.reference.network", "InProcessNetwork", "receive"),
    ("vehicles (World.step: 10 sub-steps, autopilots)", "sitl_sim.vehicle.world", "World", "step"),
)


def profile_worker(scenario: str, duration_s: float) -> dict[str, Any]:
    """Wall µs per control tick of ``swarm simulate``'s flight loop, per part (timers around the
    parts, nested calls counted once), and the top functions of a cProfile run."""
    import dataclasses
    import importlib

    from gcs.reference.flight import ReferenceFlight
    from protocols.scenario.scenario_file import load_scenario

    with tempfile.TemporaryDirectory() as tmp:
        path = (
            _grid_scenario(GRID_SIM_N, duration_s, Path(tmp))
            if scenario == "grid"
            else Path(scenario)
        )
        sc = dataclasses.replace(load_scenario(path), duration_s=duration_s)
    parts: dict[str, float] = {}
    depth: dict[str, int] = {}
    for label, module, owner_name, name in _PARTS:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError:  # a part the tree under test does not have
            continue
        owner = mod if owner_name is None else getattr(mod, owner_name, None)
        if owner is None or not hasattr(owner, name):
            continue
        _wrap(owner, name, label, parts, depth)
    flight = ReferenceFlight(sc)
    t0 = time.perf_counter()
    flight.run()
    wall = time.perf_counter() - t0
    ticks = round(duration_s * 50) + 1
    per_tick = {k: 1e6 * v / ticks for k, v in parts.items()}
    per_tick["total (flight loop)"] = 1e6 * wall / ticks
    flight = ReferenceFlight(sc)
    prof = cProfile.Profile()
    prof.enable()
    flight.run()
    prof.disable()
    with tempfile.NamedTemporaryFile("w+", suffix=".txt") as out:
        stats = pstats.Stats(prof, stream=out)
        stats.sort_stats("tottime").print_stats(12)
        out.seek(0)
        top = out.read()
    lines = [ln for ln in top.splitlines() if ln.strip()]
    start = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith("ncalls"))
    return {"us_per_tick": per_tick, "ticks": ticks, "cprofile_top_tottime": lines[start:]}


def _wrap(
    owner: Any, name: str, label: str, parts: dict[str, float], depth: dict[str, int]
) -> None:
    original = getattr(owner, name)
    is_static = isinstance(owner, type) is False

    def timed(*args: Any, **kwargs: Any) -> Any:
        outer = depth.get(label, 0) == 0
        depth[label] = depth.get(label, 0) + 1
        t0 = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            depth[label] -= 1
            if outer:
                parts[label] = parts.get(label, 0.0) + time.perf_counter() - t0

    if is_static:
        # module-level function: patch every module that imported it by name
        for mod in list(sys.modules.values()):
            if getattr(mod, name, None) is original:
                setattr(mod, name, timed)
    else:
        setattr(owner, name, timed)


# -- the parent: before/after in turns --------------------------------------------------------
def _run(tree: Path, *args: str) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=str(tree), MAVLINK20="1", MPLBACKEND="Agg")
    # this file by path, so that everything it imports comes from the tree under test
    code = (
        "import importlib.util as u, json, sys; "
        f"spec = u.spec_from_file_location('agent_batch_bench', {str(Path(__file__))!r}); "
        "b = u.module_from_spec(spec); sys.modules[spec.name] = b; spec.loader.exec_module(b); "
        "print(json.dumps(b.worker(sys.argv[1:])))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, *args],
        env=env,
        cwd=tree,
        check=True,
        capture_output=True,
        text=True,
    )
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def worker(argv: list[str]) -> dict[str, Any]:
    """Entry of a child process: ``maths N K TICKS``, ``simulate SCENARIO [S]``,
    ``profile SCENARIO S``."""
    kind = argv[0]
    if kind == "maths":
        return maths_worker(int(argv[1]), int(argv[2]), int(argv[3]))
    if kind == "simulate":
        return simulate_worker(argv[1], float(argv[2]) if len(argv) > 2 else None)
    if kind == "profile":
        return profile_worker(argv[1], float(argv[2]))
    raise ValueError(kind)


def _tree(rev: str, folder: Path, name: str) -> Path:
    """The files of revision ``rev`` in ``folder / name``."""
    tree = folder / name
    tree.mkdir()
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def agent_batch(
    before: str = "20394f3",
    repeats: int = 3,
    quick: bool = False,
    profile: bool = True,
    after: str | None = None,
    timings: bool = True,
) -> dict[str, Any]:
    """All the figures, before and after (see the module docstring); ``after`` a revision, or
    None for the working tree."""
    paper = str(ROOT / "scenarios" / "paper.toml")
    ticks = 30 if quick else MATHS_TICKS
    rows: list[dict[str, Any]] = []
    result: dict[str, Any] = {
        "before": before,
        "after": after or "working tree",
        "repeats": repeats,
        "rows": rows,
    }
    with tempfile.TemporaryDirectory() as tmp:
        trees = {
            "before": _tree(before, Path(tmp), "before"),
            "after": ROOT if after is None else _tree(after, Path(tmp), "after"),
        }
        jobs: list[tuple[str, tuple[str, ...]]] = [
            (f"maths N={MATHS_N} K={k}", ("maths", str(MATHS_N), str(k), str(ticks)))
            for k in BATCH_SIZES
        ]
        jobs.append(("simulate paper N=9", ("simulate", paper) + (("20",) if quick else ())))
        jobs.append(
            (f"simulate grid N={GRID_SIM_N}", ("simulate", "grid") + (("4",) if quick else ()))
        )
        best: dict[tuple[str, str], dict[str, Any]] = {}
        for _ in range(repeats if timings else 0):
            for label, args in jobs:
                for which, tree in trees.items():
                    if which == "before" and args[0] == "maths" and args[2] != "1":
                        continue  # before: one by one whatever K
                    r = _run(tree, *args)
                    key = (label, which)
                    metric = "us_per_agent_tick" if args[0] == "maths" else "wall_time_s"
                    if key not in best or r[metric] < best[key][metric]:
                        best[key] = r
                    print(label, which, r, flush=True)
        for (label, which), r in best.items():
            rows.append({"case": label, "code": which, **r})
        if profile:
            prof: dict[str, Any] = {}
            for _ in range(max(1, repeats - 1)):  # the faster of the repeats, in turns
                for label, args in (
                    ("N=9 paper, first 40 s", ("profile", paper, "4" if quick else "40")),
                    ("N=100 grid, first 6 s", ("profile", "grid", "1" if quick else "6")),
                ):
                    for which, tree in trees.items():
                        r = _run(tree, *args)
                        name = f"{label}, {which}"
                        total = "total (flight loop)"
                        if (
                            name not in prof
                            or r["us_per_tick"][total] < prof[name]["us_per_tick"][total]
                        ):
                            prof[name] = r
            result["profile"] = prof
    return result


def profile_text(result: dict[str, Any]) -> str:
    """The per-part tables of the profile runs, before and after side by side."""
    out = [
        "Where one control tick of `swarm simulate` goes (wall µs per tick, timers around the",
        "parts; indented parts are inside 'agents'; 'rest' is the loop, faults and recording).",
        "Written by `python -m bench.agent_batch` (bench/agent_batch.py), the machine shared.",
        "",
    ]
    profiles = result.get("profile", {})
    cases = sorted({name.rsplit(", ", 1)[0] for name in profiles})
    for case in cases:
        before = profiles.get(f"{case}, before", {}).get("us_per_tick", {})
        after = profiles.get(f"{case}, after", {}).get("us_per_tick", {})
        out.append(f"== {case}")
        out.append(f"  {'part':<40s} {'before':>9s} {'after':>9s}")
        for table in (before, after):
            top = [k for k in table if not k.startswith(" ") and not k.startswith("total")]
            table["rest"] = table.get("total (flight loop)", 0.0) - sum(table[k] for k in top)
        labels = list(dict.fromkeys([p[0] for p in _PARTS] + ["rest", "total (flight loop)"]))
        labels = [k for k in labels if k in before or k in after]
        for label in labels:
            b, a = before.get(label), after.get(label)
            cell_b = f"{b:9.0f}" if b is not None else f"{'-':>9s}"
            cell_a = f"{a:9.0f}" if a is not None else f"{'-':>9s}"
            out.append(f"  {label:<40s} {cell_b} {cell_a}")
        out.append("")
    for name, r in profiles.items():
        out.append(f"-- {name}: cProfile, top functions by own time (cProfile overhead included)")
        out += ["    " + ln for ln in r["cprofile_top_tottime"]]
        out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default="20394f3", help="git revision of the 'before' code")
    parser.add_argument("--after", help="git revision of the 'after' code (default: this tree)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results_agent_batch.json")
    parser.add_argument(
        "--profile-out", type=Path, default=ROOT / "bench" / "agent_batch_profile.txt"
    )
    parser.add_argument(
        "--profile-only",
        action="store_true",
        help="only the profile; keep the timing rows already in --out",
    )
    args = parser.parse_args(argv)
    if args.profile_only:
        result = json.loads(args.out.read_text(encoding="utf-8"))
        result["profile"] = agent_batch(
            args.before, args.repeats, args.quick, after=args.after, timings=False
        )["profile"]
    else:
        result = agent_batch(args.before, args.repeats, args.quick, after=args.after)
    write_result(args.out, result, indent=2)
    args.profile_out.write_text(profile_text(result), encoding="utf-8")
    for row in result["rows"]:
        print(row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
