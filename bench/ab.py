"""``swarm simulate`` of two checkouts side by side, the same hour: how much a change sped the
in-process flight loop up, on a machine whose speed swings more than the change does.

``python -m bench.ab --before DIR [--after DIR] [--sizes 25,100] [--runs 5] [--seconds 20]``:
the bench's N-drone hover grid (bench/side_by_side.py's scenario) flown by ``swarm simulate
--no-plots --no-recording`` in each checkout (its own ``.venv``), the two taking turns run by run,
each on one core (``taskset -c 1`` where there is one); the flight loop's wall time
(``metrics.json``'s ``wall_time_s``) of every run, their medians and the after/before ratio per
size, of the medians and (``after_over_before_paired``) the median of each pair's ratio.
``--after`` defaults to this checkout. Each checkout's compiled code is loaded (or compiled) by
one run first, not counted. Writes ``bench/results_ab.json`` (with both commits and the
machine's speed at the start and the end: bench/provenance.py). Not in ``make bench``: a tool
for a change's author, who names the checkout before it (``git worktree add DIR REV``).

``--up`` compares the distributed flight instead: ``swarm up`` (lockstep, the default layout) of
the hover grid of bench/up_lockstep.py (``run_case``, ``--seconds`` simulated, 25 by default),
flown by each checkout in turn (the whole machine, as a user runs it): per run the real-time
factor once airborne and over the whole flight, the agents' CPU per agent-tick and the
simulator's and ground station's shares of the CPU; their medians and after/before ratios
(each checkout first flies 9 drones for 4 s, not counted: its compiled code loaded or compiled).
Writes ``bench/results_ab_up.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from bench.provenance import ROOT, commit, machine_speed, write_result
from bench.side_by_side import SPACING_M

OUT = ROOT / "bench" / "results_ab.json"
OUT_UP = ROOT / "bench" / "results_ab_up.json"
#: bench/up_lockstep.py's figures of one ``swarm up`` that --up compares (higher is better for
#: the first two)
UP_FIGURES = ("rtf", "rtf_whole", "agent_cpu_us_per_agent_tick", "sim_cpu_share",
              "gcs_cpu_share")  # fmt: skip


def _loop_s(tree: Path, scenario: Path, seconds: float, report: Path) -> float:
    """One ``swarm simulate`` of ``scenario`` in checkout ``tree``: its flight loop's wall time."""
    python = tree / ".venv" / "bin" / "python"
    pin = ["taskset", "-c", "1"] if shutil.which("taskset") else []
    argv = [*pin, str(python), "-m", "gcs.cli", "simulate", str(scenario), "--duration-s",
            f"{seconds:g}", "--report", str(report), "--no-plots", "--no-recording",
            "--progress", "off"]  # fmt: skip
    done = subprocess.run(argv, cwd=tree, capture_output=True, text=True, timeout=3600)
    if done.returncode != 0:
        raise RuntimeError(f"swarm simulate failed in {tree}: {done.stderr[-400:]}")
    wall: float = json.loads((report / "metrics.json").read_text())["wall_time_s"]
    return wall


def _up_run(tree: Path, n: int, seconds: float, check: bool = True) -> dict[str, Any]:
    """One ``swarm up`` of the N-drone hover grid by checkout ``tree`` (bench/up_lockstep.py
    ``run_case``, the default layout): its figures (``check``: RuntimeError unless every drone
    flies at the end)."""
    python = tree / ".venv" / "bin" / "python"
    code = ("import json, sys; from bench.up_lockstep import run_case; "
            f"print(json.dumps(run_case({n}, None, 'grid', {seconds!r})))")  # fmt: skip
    done = subprocess.run([str(python), "-c", code], cwd=tree, capture_output=True, text=True,
                          timeout=3600, env={**os.environ, "PYTHONPATH": str(tree)})  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(f"swarm up failed in {tree}: {done.stderr[-400:]}")
    got: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    if check and got.get("flying_at_end") != n:
        raise RuntimeError(f"swarm up in {tree}: {got.get('flying_at_end')} of {n} flying")
    return got


def compare_up(
    before: Path, after: Path, sizes: list[int], runs: int, seconds: float
) -> dict[str, Any]:
    """The ``--up`` A/B of the module doc."""
    for tree in (before, after):  # each checkout's compiled code loaded (or compiled) first
        _up_run(tree, 9, 4.0, check=False)
    speed_start = machine_speed()
    rows = []
    for n in sizes:
        runs_of: dict[str, list[dict[str, Any]]] = {"before": [], "after": []}
        for k in range(runs):
            for side, tree in (("before", before), ("after", after)):
                got = _up_run(tree, n, seconds)
                runs_of[side].append({f: got.get(f) for f in UP_FIGURES})
                print(f"N = {n} {side} run {k + 1}: " + ", ".join(
                    f"{f} {got.get(f)}" for f in UP_FIGURES), flush=True)  # fmt: skip
        row: dict[str, Any] = {"n": n, "seconds": seconds, "runs": runs_of}
        for f in UP_FIGURES:
            b = statistics.median(r[f] for r in runs_of["before"])
            a = statistics.median(r[f] for r in runs_of["after"])
            row[f] = {"median_before": b, "median_after": a, "after_over_before": round(a / b, 3)}
        rows.append(row)
    return _result("python -m bench.ab --up", before, after, runs, rows, speed_start)


def _result(
    command: str, before: Path, after: Path, runs: int, rows: list[Any], speed_start: Any
) -> dict[str, Any]:
    """An A/B's result file: its rows with both commits and the machine's speed."""
    return {
        "command": command,
        "before": commit(before) or str(before),
        "after": commit(after) or str(after),
        "runs": runs,
        "rows": rows,
        "machine_speed_start": speed_start,
        "machine_speed_end": machine_speed(),
    }


def compare(
    before: Path, after: Path, sizes: list[int], runs: int, seconds: float
) -> dict[str, Any]:
    """The A/B of the module doc."""
    from protocols.scenario.generator import GeneratorOptions, generate

    speed_start = machine_speed()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-ab-") as tmp:
        folder = Path(tmp)
        for n in sizes:
            scenario = folder / f"hover{n}.toml"
            options = GeneratorOptions(n, "grid", spacing_m=SPACING_M, template="hover")
            scenario.write_text(generate(options, str(scenario)).text)
            times: dict[str, list[float]] = {"before": [], "after": []}
            for k in range(runs + 1):
                for side, tree in (("before", before), ("after", after)):
                    s = _loop_s(tree, scenario, seconds, folder / f"r{n}-{side}-{k}")
                    if k:  # the first: compiled code loaded or compiled
                        times[side].append(round(s, 3))
                        print(f"N = {n} {side} run {k}: loop {s:.3f} s", flush=True)
            b, a = statistics.median(times["before"]), statistics.median(times["after"])
            # each after-run over the before-run just ahead of it: the two of a pair met the
            # same minute of the machine (its speed drifts over minutes)
            paired = statistics.median(
                x / y for x, y in zip(times["after"], times["before"], strict=True)
            )
            rows.append({
                "n": n,
                "seconds": seconds,
                "before_loop_s": times["before"],
                "after_loop_s": times["after"],
                "median_before_s": round(b, 3),
                "median_after_s": round(a, 3),
                "after_over_before": round(a / b, 3),
                "after_over_before_paired": round(paired, 3),
                "rtf_loop_before": round(seconds / b, 2),
                "rtf_loop_after": round(seconds / a, 2),
            })  # fmt: skip
    return _result("python -m bench.ab", before, after, runs, rows, speed_start)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.ab", description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path, required=True, help="the checkout before the change")
    ap.add_argument("--after", type=Path, default=ROOT, help="the checkout after (this one)")
    ap.add_argument("--sizes", default="25,100", help="drone counts, comma separated")
    ap.add_argument("--runs", type=int, default=5, help="runs per checkout and size")
    ap.add_argument("--seconds", type=float, default=None,
                    help="simulated seconds per run (20; with --up 25)")  # fmt: skip
    ap.add_argument(
        "--up",
        action="store_true",
        help="compare swarm up (lockstep, default layout) instead of swarm simulate",
    )
    args = ap.parse_args(argv)
    for tree in (args.before, args.after):
        if not (tree / ".venv" / "bin" / "python").exists():
            print(f"bench.ab: {tree} has no .venv (run make venv there)", file=sys.stderr)
            return 2
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError:
        sizes = []
    if not sizes or min(sizes) < 2:
        print(f"bench.ab: --sizes takes drone counts like 25,100, got {args.sizes!r}",
              file=sys.stderr)  # fmt: skip
        return 2
    if args.up:
        seconds = 25.0 if args.seconds is None else args.seconds
        try:
            result = compare_up(
                args.before.resolve(), args.after.resolve(), sizes, args.runs, seconds
            )
        except RuntimeError as exc:
            print(f"bench.ab: {exc}", file=sys.stderr)
            return 1
        write_result(OUT_UP, result)
        for row in result["rows"]:
            print(f"N = {row['n']}: " + "; ".join(
                f"{f} {row[f]['median_before']} -> {row[f]['median_after']}"
                for f in UP_FIGURES))  # fmt: skip
        print(f"written: {OUT_UP.relative_to(ROOT)}")
        return 0
    seconds = 20.0 if args.seconds is None else args.seconds
    result = compare(args.before.resolve(), args.after.resolve(), sizes, args.runs, seconds)
    write_result(OUT, result)
    for row in result["rows"]:
        print(f"N = {row['n']}: loop {row['median_before_s']} s -> {row['median_after_s']} s "
              f"({row['after_over_before']} of before; pair by pair "
              f"{row['after_over_before_paired']})")  # fmt: skip
    print(f"written: {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
