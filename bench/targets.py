"""The speed targets, each measured as a user meets it, with its figure beside it.

``python -m bench.targets [--only NAME,...] [--repeats 3]`` (about 25 minutes on the 2-core
machine when it is quiet; in ``make bench``). Every figure is a whole flight as the plain command
flies it (start-up and take-off included) unless its row says otherwise, the median of
``--repeats`` runs, and each run is a fresh process tree on free ports (the operator session on
the default ones, as the README types it):

- ``session16``: ``swarm up --drones 16`` with its defaults, ``swarm takeoff``, ``swarm shutdown``
  at 60 s (bench/session.py): simulated over wall time from the command to the shutdown;
- ``paper_up``: ``swarm up scenarios/paper.toml`` with its defaults, the whole 200 s;
- ``realtime100``: ``swarm up --clock realtime`` of a 100-drone hover grid (bench/end_to_end.py's
  scenario, 30 s) with the default layout: the share of control ticks answered in time over the
  run (the report's ``agent_timing``) and the drones flying at the end;
- ``lockstep100``, ``lockstep250``: ``swarm up`` (lockstep, default layout) of a 100-drone hover
  grid for 25 s and a 250-drone one for 20 s; ``lockstep100`` also gives the hosted agent's CPU per
  agent-tick (maths and messaging, the simulator excluded) once airborne, at the default layout's
  K = 50 on two cores;
- ``simulate9``, ``simulate25``, ``simulate100``: ``swarm simulate --no-plots --no-recording`` of
  an N-drone hover grid, 20 simulated seconds, on one core (bench/side_by_side.py's ``ours``): the
  flight loop's real-time factor, and at N = 9 the whole process's wall time. (The issue's N =
  1000 is not flown: a scenario holds at most 250 drones, MAVLink's vehicle numbers.)

Writes ``bench/results_targets.json`` (each target: its bound, the median figure, met or missed
and by what factor, the runs, and the commit and load average it was measured at),
``bench/targets.md`` (the table) and ``bench/targets.png`` (each figure over its bound). With
``--only``, the other targets' entries are kept from the file as they were measured.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.provenance import commit, load_average, machine_speed, write_result

ROOT = Path(__file__).resolve().parents[1]
OUT_JSON = ROOT / "bench" / "results_targets.json"
OUT_MD = ROOT / "bench" / "targets.md"
OUT_PNG = ROOT / "bench" / "targets.png"


@dataclass(frozen=True)
class Figure:
    """One figure a target is judged by: ``key`` of its run's row, at least (``at_least``) or
    at most ``bound``."""

    key: str
    bound: float
    at_least: bool
    unit: str
    what: str

    def met(self, value: float | None) -> bool:
        if value is None:
            return False
        return value >= self.bound if self.at_least else value <= self.bound

    def margin(self, value: float | None) -> float | None:
        """How far from the bound: figure over bound where more is better, else bound over
        figure (>= 1: met)."""
        if value is None or value == 0:
            return None
        return value / self.bound if self.at_least else self.bound / value


@dataclass(frozen=True)
class Target:
    name: str
    command: str
    run: Callable[[], dict[str, Any]]
    figures: tuple[Figure, ...]


def _session() -> dict[str, Any]:
    from bench.session import one_session

    with tempfile.TemporaryDirectory(prefix="bench-targets-") as tmp:
        return one_session(Path(tmp))


def _up(n: int, kind: str, seconds: float, clock: str = "lockstep") -> Callable[[], dict[str, Any]]:
    def run() -> dict[str, Any]:
        from bench.up_lockstep import run_case

        return run_case(n, None, kind, seconds, clock)

    return run


def _simulate(n: int, seconds: float = 20.0) -> Callable[[], dict[str, Any]]:
    def run() -> dict[str, Any]:
        from bench.side_by_side import ours

        with tempfile.TemporaryDirectory(prefix="bench-targets-") as tmp:
            row = ours(n, seconds, Path(tmp))
        return {**row, "rtf_loop": round(seconds / row["loop_s"], 2)}

    return run


def _loop(bound: float) -> Figure:
    return Figure("rtf_loop", bound, True, "x", "flight loop, simulated over wall time")


TARGETS: tuple[Target, ...] = (
    Target(
        "session16",
        "swarm up --drones 16; swarm takeoff; swarm shutdown at 60 s",
        _session,
        (
            Figure("real_time_factor_whole", 1.0, True, "x", "from the command to the shutdown"),
            Figure("shutdown_to_exit_s", 10.0, False, "s", "report written after swarm shutdown"),
        ),
    ),
    Target(
        "paper_up",
        "swarm up scenarios/paper.toml",
        _up(9, "paper", 200.0),
        (Figure("rtf_whole", 3.0, True, "x", "the whole 200 s"),),
    ),
    Target(
        "realtime100",
        "swarm up --clock realtime (100-drone hover grid, 30 s)",
        _up(100, "grid", 30.0, "realtime"),
        (
            Figure("in_time_mean", 0.99, True, "", "share of control ticks answered in time"),
            Figure("flying_at_end", 100, True, "", "drones flying at the end"),
        ),
    ),
    Target(
        "lockstep100",
        "swarm up (100-drone hover grid, 25 s)",
        _up(100, "grid", 25.0),
        (
            Figure("rtf_whole", 2.0, True, "x", "the whole flight"),
            Figure("agent_cpu_us_per_agent_tick", 100.0, False, "us", "hosted agent-tick, K = 50"),
        ),
    ),
    Target(
        "lockstep250",
        "swarm up (250-drone hover grid, 20 s)",
        _up(250, "grid", 20.0),
        (Figure("rtf_whole", 1.0, True, "x", "the whole flight"),),
    ),
    Target(
        "simulate9",
        "swarm simulate (9-drone hover grid, 20 s)",
        _simulate(9),
        (_loop(30.0), Figure("whole_s", 2.0, False, "s", "the whole process")),
    ),
    Target("simulate25", "swarm simulate (25-drone grid, 20 s)", _simulate(25), (_loop(25.0),)),
    Target("simulate100", "swarm simulate (100-drone grid, 20 s)", _simulate(100), (_loop(15.0),)),
)


def _median(runs: list[dict[str, Any]], key: str) -> float | None:
    values = [r[key] for r in runs if isinstance(r.get(key), (int, float))]
    return round(statistics.median(values), 4) if values else None


def judge(target: Target, runs: list[dict[str, Any]]) -> dict[str, Any]:
    """A target's entry: each figure's median over ``runs``, met or not, and by what factor."""
    figures = []
    for f in target.figures:
        value = _median(runs, f.key)
        margin = f.margin(value)
        figures.append({
            "figure": f.key, "what": f.what, "bound": f.bound,
            "sense": ">=" if f.at_least else "<=", "unit": f.unit, "median": value,
            "met": f.met(value), "margin": None if margin is None else round(margin, 3),
        })  # fmt: skip
    return {"name": target.name, "command": target.command, "figures": figures, "runs": runs}


def targets(only: Sequence[str] | None = None, repeats: int = 3) -> dict[str, Any]:
    """Measure the targets (``only`` these names), ``repeats`` runs each, taking turns. Each
    target's entry carries the commit, the load average and the machine's speed
    (:func:`~bench.provenance.machine_speed`) when its runs began, and their count."""
    chosen = [t for t in TARGETS if not only or t.name in only]
    runs: dict[str, list[dict[str, Any]]] = {t.name: [] for t in chosen}
    start = {
        "commit": commit(),
        "load_average": load_average(),
        "machine_speed": machine_speed(),
        "repeats": repeats,
    }
    for k in range(repeats):
        for t in chosen:
            print(f"[{k + 1}/{repeats}] {t.name}: {t.command}", flush=True)
            try:
                row = t.run()
            except Exception as exc:  # a failed run is a row saying so, not the end of the bench
                row = {"error": f"{type(exc).__name__}: {exc}"}
            print(f"    {json.dumps(row)}", flush=True)
            runs[t.name].append(row)
    return {
        "command": "python -m bench.targets",
        "repeats": repeats,
        "targets": [{**judge(t, runs[t.name]), **start} for t in chosen],
        "commit": commit(),
        "load_average_end": load_average(),
    }


def merged(result: dict[str, Any], path: Path) -> dict[str, Any]:
    """``result`` with the targets it did not measure kept from the file at ``path`` (each
    entry says where it was measured), in the order of :data:`TARGETS`."""
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return result
    entries = {t["name"]: t for t in old.get("targets", [])}
    for t in old.get("targets", []):  # an entry from before entries carried their own
        t.setdefault("commit", old.get("commit"))
        t.setdefault("load_average", old.get("load_average"))
        t.setdefault("repeats", old.get("repeats"))
    entries.update({t["name"]: t for t in result["targets"]})
    order = [t.name for t in TARGETS if t.name in entries]
    return {**result, "targets": [entries[name] for name in order]}


def table(result: dict[str, Any]) -> str:
    """The targets as a Markdown table."""
    lines = [
        "Targets (`python -m bench.targets`): each the median of its runs, at the commit and "
        "with the load average at the start its row gives, and the machine's speed then: a "
        "fixed pure-Python loop's time (bench/provenance.py's machine_speed; the same code "
        "runs slower in proportion on a slower day).",
        "",
        "| target | command | figure | bound | measured | met | at (runs, load, Python loop) |",
        "|---|---|---|---|---|---|---|",
    ]
    for t in result["targets"]:
        for f in t["figures"]:
            value = "not measured" if f["median"] is None else f"{f['median']:g}{f['unit']}"
            verdict = "yes" if f["met"] else (
                "no" if f["margin"] is None else f"no ({f['margin']:.2f} of the bound)"
            )  # fmt: skip
            at = t.get("commit", result.get("commit"))
            runs = t.get("repeats", result.get("repeats"))
            load = t.get("load_average", result.get("load_average"))
            speed = (t.get("machine_speed") or {}).get("python_ms")
            loop = "not measured" if speed is None else f"{speed:g} ms"
            lines.append(
                f"| {t['name']} | `{t['command']}` | {f['what']} | {f['sense']} "
                f"{f['bound']:g}{f['unit']} | {value} | {verdict} | {at} ({runs}, {load}, "
                f"{loop}) |"
            )
    return "\n".join(lines) + "\n"


def plot(result: dict[str, Any], path: Path) -> None:
    """Each figure over its bound (1 = the target; right of it is met), one bar per figure."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure as MplFigure

    rows = [(f"{t['name']}: {f['figure']}", f["margin"] or 0.0, f["met"])
            for t in result["targets"] for f in t["figures"]]  # fmt: skip
    fig = MplFigure(figsize=(8.0, 0.4 * len(rows) + 1.2))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    at = list(range(len(rows)))
    ax.barh(at, [r[1] for r in rows], color=["tab:green" if r[2] else "tab:red" for r in rows])
    ax.axvline(1.0, color="k", linestyle="--", linewidth=1)
    ax.set_yticks(at, [r[0] for r in rows], fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("figure over its target (>= 1: met; log scale)")
    ax.set_title(f"speed targets at {result.get('commit')}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.targets",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--only", help="comma-separated target names (default: all)")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each (median kept)")
    parser.add_argument("--out", type=Path, default=OUT_JSON)
    args = parser.parse_args(argv)
    names = [n for n in (args.only or "").split(",") if n]
    unknown = sorted(set(names) - {t.name for t in TARGETS})
    if unknown:
        parser.error(f"unknown target(s) {', '.join(unknown)}; "
                     f"known: {', '.join(t.name for t in TARGETS)}")  # fmt: skip
    start_load = load_average()
    result = {**targets(names, args.repeats), "load_average": start_load}
    if names:  # the other targets' entries are kept from the file, as they were measured
        result = merged(result, args.out)
    write_result(args.out, result, indent=2)
    if args.out == OUT_JSON:
        OUT_MD.write_text(table(result), encoding="utf-8")
        plot(result, OUT_PNG)
    print(table(result))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
