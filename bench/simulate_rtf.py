"""``swarm simulate``'s real-time factor against the number of drones.

``python -m bench.simulate_rtf [--sizes 9,25,50,100,250] [--repeats 3] [--profile] [--max-s S]``
(in ``make bench``; about 10 minutes on the 2-core machine when it is quiet).

The flights, whole, with their faults: N = 9 ``scenarios/paper.toml`` (200 s, a vehicle crash at
30 s, 5 % loss); N = 25, 100, 250 ``scenarios/large_grid{N}.toml`` (take-off, a 20 m move with a
30° turn and a 15 % stretch, an agent drop-out, a vehicle crash, 20 % loss on every link);
N = 50 the same generator options at 50 drones (made in a temporary folder). Each run is a
fresh child process running :func:`gcs.reference.simulate.simulate` (what ``swarm simulate
--no-plots`` does, without the Rerun recording):

- ``rtf_wall``: simulated seconds over the flight loop's wall time, as ``metrics.json`` reports;
- ``rtf_cpu``: over the flight loop's process CPU time (``time.process_time``): what the code
  costs, less sensitive to the other jobs on a shared machine;
- ``us_per_tick``: CPU µs per 50 Hz control tick (agents, radio, 10 physics sub-steps and the
  in-loop recording); ``report_s``: CPU s of writing the report after the flight (tlog, events,
  metrics);
- ``airborne_at_end`` of N, ``lost`` (the scenario's crash and drop-out), ``failsafes`` and the
  minimum separation, so that a fast flight is seen to be a good one.

The sizes take turns within each repeat and the median of the repeats is kept; the 1-minute load
average is recorded before each run. Writes (also when run by ``bench.run``)
``bench/results_simulate_rtf.json``, the plot ``bench/simulate_rtf.png`` and the table
``bench/simulate_rtf.md``; with ``--profile`` also
``bench/simulate_rtf_profile.txt`` (where one tick goes, per part, and cProfile's top functions,
at N = 9 and N = 100).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.provenance import write_result

ROOT = Path(__file__).resolve().parents[1]
SIZES = (9, 25, 50, 100, 250)
OUT_JSON = ROOT / "bench" / "results_simulate_rtf.json"
OUT_PNG = ROOT / "bench" / "simulate_rtf.png"
OUT_TABLE = ROOT / "bench" / "simulate_rtf.md"
OUT_PROFILE = ROOT / "bench" / "simulate_rtf_profile.txt"
#: The issue's targets (2-core machine): N -> real-time factor.
TARGETS = {9: 20.0, 100: 5.0}


def scenario_path(n: int, folder: Path) -> Path:
    """The scenario flown at ``n`` drones (module docstring)."""
    if n == 9:
        return ROOT / "scenarios" / "paper.toml"
    library = ROOT / "scenarios" / f"large_grid{n}.toml"
    if library.exists():
        return library
    sys.path.insert(0, str(ROOT))
    from protocols.scenario.generator import GeneratorOptions, generate
    from scripts.make_scenarios import LARGE_FAULTS

    path = folder / f"large_grid{n}.toml"
    options = GeneratorOptions(n, "grid", faults=LARGE_FAULTS, name=f"large-grid{n}")
    path.write_text(generate(options, str(path)).text, encoding="utf-8")
    return path


# -- the child ---------------------------------------------------------------------------------
def run_one(scenario: Path, max_s: float | None = None) -> dict[str, Any]:
    """Fly ``scenario`` (its first ``max_s`` seconds, if given) with
    :func:`gcs.reference.simulate.simulate` in this process; the figures."""
    from gcs.reference import flight as reference_flight
    from gcs.reference.simulate import simulate
    from protocols.scenario.scenario_file import load_scenario

    cpu: dict[str, float] = {}
    original = reference_flight.ReferenceFlight.run

    def timed(self: Any, *args: Any, **kwargs: Any) -> Any:
        c0 = time.process_time()
        try:
            return original(self, *args, **kwargs)
        finally:
            cpu["flight"] = time.process_time() - c0

    reference_flight.ReferenceFlight.run = timed  # type: ignore[method-assign]
    sc = load_scenario(scenario)
    if max_s is not None and max_s < sc.duration_s:
        sc = dataclasses.replace(sc, duration_s=max_s)
    with tempfile.TemporaryDirectory() as tmp:
        c0 = time.process_time()
        result = simulate(sc, Path(tmp) / "report", plots=False, recording=False)
        total = time.process_time() - c0
    m = result.metrics
    rec = result.record
    ticks = rec.t_s.shape[0]
    return {
        "n": sc.n_drones,
        "scenario": scenario.name,
        "duration_s": sc.duration_s,
        "rtf_wall": m["real_time_factor"],
        "rtf_cpu": round(sc.duration_s / cpu["flight"], 3),
        "us_per_tick": round(1e6 * cpu["flight"] / ticks, 1),
        "report_s": round(total - cpu["flight"], 2),
        "airborne_at_end": int(rec.airborne[-1].sum()),
        "lost": len(rec.lost_at_s),
        "failsafes": sum(e.kind == "failsafe" for e in result.events),
        "min_separation_m": _min_separation(m),
    }


def _min_separation(metrics: dict[str, Any]) -> float | None:
    value = metrics.get("separation", {}).get("min_m")
    return None if value is None else round(float(value), 2)


# -- the parent --------------------------------------------------------------------------------
def _child(args: Sequence[str]) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), MAVLINK20="1", MPLBACKEND="Agg")
    out = subprocess.run(
        [sys.executable, "-m", "bench.simulate_rtf", *args],
        env=env,
        cwd=ROOT,
        check=True,
        capture_output=True,
        text=True,
    )
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def simulate_rtf(
    sizes: Sequence[int] = SIZES,
    repeats: int = 3,
    profile: bool = False,
    max_s: float | None = None,
) -> dict[str, Any]:
    """Every size ``repeats`` times in turns; medians (module docstring). The JSON, plot and
    table are written after each repeat (a long run interrupted keeps what it measured)."""
    runs: dict[int, list[dict[str, Any]]] = {n: [] for n in sizes}
    result: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = {n: scenario_path(n, Path(tmp)) for n in sizes}
        for _ in range(repeats):
            for n in sizes:
                load = os.getloadavg()[0]
                args = ["child", str(paths[n])] + ([] if max_s is None else [str(max_s)])
                r = _child(args)
                r["load_1min"] = round(load, 1)
                runs[n].append(r)
                print(json.dumps(r), flush=True)
            result = _summary(runs, max_s)
    if profile:
        OUT_PROFILE.write_text(profile_text(), encoding="utf-8")
        result["profile"] = str(OUT_PROFILE.relative_to(ROOT))
        write_result(OUT_JSON, result, indent=2)
    return result


def _summary(runs: dict[int, list[dict[str, Any]]], max_s: float | None) -> dict[str, Any]:
    """Medians per size; writes the JSON, the plot and the table."""
    rows = []
    for rs in runs.values():
        if not rs:
            continue
        row = dict(rs[0])
        for key in ("rtf_wall", "rtf_cpu", "us_per_tick", "report_s"):
            row[key] = round(statistics.median(r[key] for r in rs), 3)
        row["rtf_cpu_runs"] = [r["rtf_cpu"] for r in rs]
        row["load_1min"] = [r["load_1min"] for r in rs]
        rows.append(row)
    command = "python -m bench.simulate_rtf" + ("" if max_s is None else f" --max-s {max_s:g}")
    result: dict[str, Any] = {
        "command": command,
        "max_s": max_s,
        "repeats": [len(rs) for rs in runs.values()],
        "rows": rows,
        "targets": {str(n): rtf for n, rtf in TARGETS.items()},
        "targets_met": {
            str(n): next((r["rtf_cpu"] >= rtf for r in rows if r["n"] == n), None)
            for n, rtf in TARGETS.items()
        },
        "plot": str(OUT_PNG.relative_to(ROOT)),
        "table": str(OUT_TABLE.relative_to(ROOT)),
        "cpu_count": os.cpu_count(),
    }
    _plot(rows, OUT_PNG)
    OUT_TABLE.write_text(table(rows) + "\n", encoding="utf-8")
    write_result(OUT_JSON, result, indent=2)
    return result


def table(rows: Sequence[dict[str, Any]]) -> str:
    """The Markdown table of the README."""
    lines = [
        "| N | scenario | RTF (CPU) | RTF (wall) | CPU µs per tick | airborne at end | lost |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['n']} | {r['scenario']} | {r['rtf_cpu']:.1f}× | {r['rtf_wall']:.1f}× | "
            f"{r['us_per_tick']:.0f} | {r['airborne_at_end']} | {r['lost']} |"
        )
    return "\n".join(lines)


def _plot(rows: Sequence[dict[str, Any]], path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    n = [r["n"] for r in rows]
    ax.plot(n, [r["rtf_cpu"] for r in rows], marker="o", label="per CPU second (median)")
    ax.plot(n, [r["rtf_wall"] for r in rows], marker="s", linestyle=":", label="per wall second")
    for size, target in TARGETS.items():
        ax.plot([size], [target], marker="*", markersize=12, color="red", linestyle="none")
    ax.plot([], [], marker="*", color="red", linestyle="none", label="target")
    ax.axhline(1.0, color="grey", linestyle="--", linewidth=1)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xticks(n, [str(x) for x in n])
    ax.set_xlabel("drones N")
    ax.set_ylabel("real-time factor")
    ax.set_title("swarm simulate, whole scenarios (2-core machine)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.savefig(path, dpi=110, bbox_inches="tight")


def profile_worker(scenario: str, duration_s: float) -> dict[str, Any]:
    """CPU µs per control tick of ``swarm simulate``'s flight loop, per part (the parts of
    ``bench.agent_batch._PARTS``, timers of the thread's CPU time around them, nested calls
    counted once), the flight loop's CPU µs per tick without the timers, and the top functions
    of a cProfile run (without the timers)."""
    import cProfile
    import importlib
    import pstats

    from bench.agent_batch import _PARTS
    from gcs.reference.flight import ReferenceFlight
    from protocols.scenario.scenario_file import load_scenario

    sc = dataclasses.replace(load_scenario(Path(scenario)), duration_s=duration_s)
    ticks = round(duration_s / sc.rates.dt_control_s) + 1
    flight = ReferenceFlight(sc)
    c0 = time.thread_time()
    flight.run()
    plain = time.thread_time() - c0
    flight = ReferenceFlight(sc)
    prof = cProfile.Profile()
    prof.enable()
    flight.run()
    prof.disable()
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
        _wrap_cpu(owner, name, label, parts, depth)
    flight = ReferenceFlight(sc)
    c0 = time.thread_time()
    flight.run()
    timed = time.thread_time() - c0
    per_tick = {k: 1e6 * v / ticks for k, v in parts.items()}
    per_tick["total (flight loop)"] = 1e6 * timed / ticks
    with tempfile.NamedTemporaryFile("w+", suffix=".txt") as out:
        stats = pstats.Stats(prof, stream=out)
        stats.sort_stats("tottime").print_stats(15)
        out.seek(0)
        top = out.read()
    lines = [ln for ln in top.splitlines() if ln.strip()]
    start = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith("ncalls"))
    return {
        "us_per_tick": per_tick,
        "plain_us_per_tick": 1e6 * plain / ticks,
        "ticks": ticks,
        "cprofile_top_tottime": lines[start:],
    }


def _wrap_cpu(
    owner: Any, name: str, label: str, parts: dict[str, float], depth: dict[str, int]
) -> None:
    """Time ``owner.name`` (a method, or a module function wherever it was imported by name)
    into ``parts[label]``: the thread's CPU seconds, the outermost call of the label only."""
    original = getattr(owner, name)
    clock = time.thread_time

    def timed(*args: Any, **kwargs: Any) -> Any:
        outer = depth.get(label, 0) == 0
        depth[label] = depth.get(label, 0) + 1
        t0 = clock()
        try:
            return original(*args, **kwargs)
        finally:
            depth[label] -= 1
            if outer:
                parts[label] = parts.get(label, 0.0) + clock() - t0

    if isinstance(owner, type):
        setattr(owner, name, timed)
    else:  # module-level function: patch every module that imported it by name
        for mod in list(sys.modules.values()):
            if getattr(mod, name, None) is original:
                setattr(mod, name, timed)


def profile_text() -> str:
    """Where one control tick goes, per part, and cProfile's top functions, at N = 9 (the paper,
    first 40 s) and N = 100 (large_grid100, first 20 s), each in a fresh process."""
    out = [
        "Where one 50 Hz control tick of `swarm simulate` goes (CPU µs per tick: the thread's",
        "CPU time, timers around the parts, nested parts indented; 'rest' is the loop, the fault",
        "timeline and the in-loop recording; 'total' includes the timers' own cost, 'untimed'",
        "is the same flight without them), and cProfile's top functions by own time (its",
        "overhead included: it inflates numpy-heavy code such as the physics sub-step).",
        "Written by `python -m bench.simulate_rtf --profile` (bench/simulate_rtf.py). The",
        "machine is shared by several jobs: CPU time is less sensitive to them than wall time",
        "but still grows with the load (hyperthreads and caches shared), so compare shares.",
        "",
    ]
    for label, n, seconds in (("N=9 paper, first 40 s", 9, 40.0), ("N=100 grid, 20 s", 100, 20.0)):
        with tempfile.TemporaryDirectory() as tmp:
            path = scenario_path(n, Path(tmp))
            load = os.getloadavg()[0]
            r = _child(["profile", str(path), str(seconds)])
        out.append(f"== {label} (1-min load average {load:.1f} at the start)")
        from bench.agent_batch import _PARTS

        parts = dict(r["us_per_tick"])
        total = parts.pop("total (flight loop)")
        parts["rest"] = total - sum(us for part, us in parts.items() if not part.startswith(" "))
        parts["total (flight loop)"] = total
        parts["untimed flight loop"] = r["plain_us_per_tick"]
        labels = [p[0] for p in _PARTS] + ["rest", "total (flight loop)", "untimed flight loop"]
        for part in dict.fromkeys(labels):
            if part in parts:
                share = f"{100.0 * parts[part] / total:5.1f} %"
                out.append(f"  {part:44s} {parts[part]:9.0f}  {share}")
        out.append("")
        out += ["  " + line for line in r["cprofile_top_tottime"]]
        out.append("")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    """CLI (see the module docstring); ``child SCENARIO`` and ``profile SCENARIO S`` are the
    child processes' entries."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "child":
        print(json.dumps(run_one(Path(argv[1]), float(argv[2]) if len(argv) > 2 else None)))
        return 0
    if argv and argv[0] == "profile":
        print(json.dumps(profile_worker(argv[1], float(argv[2]))))
        return 0
    parser = argparse.ArgumentParser(prog="python -m bench.simulate_rtf", description=__doc__)
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--max-s", type=float, help="fly only each scenario's first S seconds")
    args = parser.parse_args(argv)
    sizes = [int(x) for x in args.sizes.split(",")]
    result = simulate_rtf(sizes, args.repeats, args.profile, args.max_s)
    print(table(result["rows"]))
    print(f"wrote {OUT_JSON.relative_to(ROOT)}, {OUT_TABLE.relative_to(ROOT)}, "
          f"{OUT_PNG.relative_to(ROOT)}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
