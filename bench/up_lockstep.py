"""``swarm up --clock lockstep``: how much faster than real time the real processes fly, and the
CPU each hosted agent costs per tick.

``python -m bench.up_lockstep [--only NAME]`` (about 10 minutes on the 2-core machine; run once,
not in ``make bench``'s default set: ``python -m bench.run --only up_lockstep``).

Cases: the paper's 9 drones (``scenarios/paper.toml``, first 40 s: take-off, the formation, the
crash at 30 s), hosted in one agent process (``--agents-per-process 9``) and one process per
drone; and 100 drones hovering on a 2.5 m grid (bench/end_to_end.py's scenario, 25 s) hosted 25
per process, and 50 per process (``swarm up``'s default on two cores); and the README's
``scenarios/large_grid100.toml`` as typed (50 per process; 20 % loss on every link, a drop-out
and a crash: the fault path's cost on top of the hover's). Each is one real ``swarm
up`` (simulator, ground station, agents, Zenoh), on free ports. Measured:

- ``rtf``: simulated over wall time, the least-squares slope of the simulator's status lines
  after ``FROM_S`` simulated seconds (the warm-up and take-off excluded);
- ``agent_cpu_us_per_agent_tick``: the agent processes' CPU time (user + system, psutil, read
  twice a second) over the same window, per drone per 50 Hz tick: the maths and the messaging
  (Zenoh, MAVLink) of a hosted agent, not the simulator's; ``sim_cpu_share`` and
  ``gcs_cpu_share``: the simulator's and the ground station's CPU per wall second;
- ``flying_at_end`` (the paper's crash leaves 8, large_grid100's 99) and the 1-minute load
  average at the start.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.end_to_end import scenario_text
from bench.provenance import write_result
from bench.sitl import _free_block, _status_lines

ROOT = Path(__file__).resolve().parents[1]
CONTROL_HZ = 50
FROM_S = 8.0
OUT_JSON = ROOT / "bench" / "results_up_lockstep.json"
OUT_PNG = ROOT / "bench" / "up_lockstep.png"
#: name -> (drones, agents per process, scenario ("paper" or "grid"), simulated seconds)
CASES: dict[str, tuple[int, int, str, float]] = {
    "n9_hosted": (9, 9, "paper", 40.0),
    "n9_per_drone": (9, 1, "paper", 40.0),
    "n100_k25": (100, 25, "grid", 25.0),
    # what swarm up does by default on two cores (one agent process per core: gcs/cli/up.py)
    "n100_k50": (100, 50, "grid", 25.0),
    # the README's 100-drone scenario as typed (its defaults: two processes of 50): 20 % loss
    # on every link, a drone dropping out and one crashing, on top of the hover's work
    "large_grid100": (100, 50, "large_grid100.toml", 25.0),
}
#: the issue's targets: name -> real-time factor
TARGETS = {"n9_hosted": 5.0, "n9_per_drone": 3.0, "n100_k25": 1.0, "n100_k50": 1.0}
TARGET_AGENT_US = 100.0  # CPU per hosted agent-tick at K = 25


def _role(cmdline: list[str]) -> str | None:
    if "gcs.cli" not in cmdline and not any(c.endswith("swarm") for c in cmdline):
        return None
    for role in ("agent", "sim", "gcs"):
        if role in cmdline:
            return role
    return None


def run_case(
    n: int, per_process: int | None, kind: str, seconds: float, clock: str = "lockstep"
) -> dict[str, Any]:
    """One ``swarm up`` run (module docstring); ``per_process`` None: ``swarm up``'s default
    layout. Besides the settled figures, the whole flight's: ``rtf_whole`` (the flown simulated
    time over the wall time from the command's start to the simulator's last status line, start-up
    and take-off included), ``agent_cpu_us_whole`` (the agents' CPU per agent-tick over the same
    span), the layout ``swarm up`` chose (its start line) and, on the realtime clock, the share
    of ticks answered in time (the report's ``agent_timing``)."""
    import psutil

    with tempfile.TemporaryDirectory() as tmp:
        if kind == "paper":
            scenario = ROOT / "scenarios" / "paper.toml"
        elif kind.endswith(".toml"):
            scenario = ROOT / "scenarios" / kind
        else:
            scenario = Path(tmp) / f"hover{n}.toml"
            scenario.write_text(scenario_text(n, seconds), encoding="utf-8")
        report = Path(tmp) / "report"
        base, gcs = _free_block(n), _free_block(1)
        swarm_id = f"bench{os.getpid()}x{n}x{per_process}"
        cmd = [sys.executable, "-m", "gcs.cli", "up", str(scenario), "--report", str(report),
               "--clock", clock, "--duration-s", str(seconds), "--base-port", str(base),
               "--gcs-port", str(gcs), "--swarm-id", swarm_id]  # fmt: skip
        if per_process is not None:
            cmd += ["--agents-per-process", str(per_process)]
        load = os.getloadavg()[0]
        wall0 = time.monotonic()
        out_path = Path(tmp) / "swarm-up.out"
        with out_path.open("wb") as sink:
            proc = subprocess.Popen(
                cmd,
                cwd=ROOT,
                env={**os.environ, "MAVLINK20": "1", "PYTHONPATH": str(ROOT)},
                stdout=sink,
                stderr=subprocess.STDOUT,
            )
        parent = psutil.Process(proc.pid)
        cpu: dict[int, tuple[str, float]] = {}
        samples: list[tuple[float, float, float, float, float]] = []  # wall, sim, agent, sim, gcs
        log = report / "logs" / "sim.log"
        while proc.poll() is None and time.monotonic() - wall0 < 1500:
            time.sleep(0.5)
            try:
                children = parent.children(recursive=True)
            except psutil.Error:
                break
            for child in children:
                try:
                    role = _role(child.cmdline())
                    if role is not None:
                        t = child.cpu_times()
                        cpu[child.pid] = (role, t.user + t.system)
                except psutil.Error:
                    continue
            text = log.read_text(errors="replace").replace("\r", "\n") if log.exists() else ""
            lines = _status_lines(text)
            if lines:
                by_role = {
                    r: sum(c for rr, c in cpu.values() if rr == r) for r in ("agent", "sim", "gcs")
                }
                samples.append((time.monotonic(), lines[-1]["sim"], by_role["agent"],
                                by_role["sim"], by_role["gcs"]))  # fmt: skip
        if proc.poll() is None:
            proc.terminate()
        proc.wait(60)
        wall = time.monotonic() - wall0
        text = log.read_text(errors="replace").replace("\r", "\n") if log.exists() else ""
        said = out_path.read_text(errors="replace")
        metrics_path = report / "metrics.json"
        metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    layout = next((line.strip() for line in said.splitlines() if " drones, " in line), None)
    timing = metrics.get("agent_timing") or {}
    whole = _whole_flight(samples, wall0, n)
    settled = [s for s in lines if s["sim"] >= FROM_S]
    rtf = None
    if len(settled) >= 3:
        rtf = float(np.polyfit([s["wall"] for s in settled], [s["sim"] for s in settled], 1)[0])
    window = [s for s in samples if s[1] >= FROM_S]
    # up to the first sample at the flight's last simulated time: after it the ground station
    # writes the report (seconds of CPU that are not the flight's)
    last = next((k for k, s in enumerate(window) if window and s[1] >= window[-1][1]), None)
    window = window if last is None else window[: last + 1]
    agent_us = sim_share = gcs_share = None
    if len(window) >= 2 and window[-1][1] > window[0][1]:
        (w0, s0, a0, m0, g0), (w1, s1, a1, m1, g1) = window[0], window[-1]
        agent_us = 1e6 * (a1 - a0) / (n * (s1 - s0) * CONTROL_HZ)
        sim_share, gcs_share = (m1 - m0) / (w1 - w0), (g1 - g0) / (w1 - w0)
    return {
        "n": n,
        "agents_per_process": per_process,
        "scenario": {"paper": "paper.toml", "grid": f"hover grid {n}"}.get(kind, kind),
        "seconds": seconds,
        "rtf": None if rtf is None else round(rtf, 2),
        "agent_cpu_us_per_agent_tick": None if agent_us is None else round(agent_us),
        "sim_cpu_share": None if sim_share is None else round(sim_share, 2),
        "gcs_cpu_share": None if gcs_share is None else round(gcs_share, 2),
        "flying_at_end": int(lines[-1]["flying"]) if lines else 0,
        "wall_s": round(wall, 1),
        "exit": proc.returncode,
        "load_1min": round(load, 1),
        "clock": clock,
        "layout": layout,
        **whole,
        "in_time_mean": timing.get("in_time_mean"),
        "in_time_min": timing.get("in_time_min"),
        "worst_lag_ms": timing.get("worst_lag_ms"),
    }


def _whole_flight(
    samples: list[tuple[float, float, float, float, float]], wall0: float, n: int
) -> dict[str, float | None]:
    """The whole flight's figures from the run's samples (wall, sim, agent, sim, gcs CPU):
    simulated time flown over the wall time from the start to the first sample at it, and the
    agents' CPU per agent-tick over that span (the agents' start-up included)."""
    if not samples or samples[-1][1] <= 0:
        return {"rtf_whole": None, "agent_cpu_us_whole": None, "flown_s": None}
    flown = samples[-1][1]
    end = next(s for s in samples if s[1] >= flown)
    agent_us = 1e6 * end[2] / (n * flown * CONTROL_HZ)
    return {
        "rtf_whole": round(flown / (end[0] - wall0), 2),
        "agent_cpu_us_whole": round(agent_us),
        "flown_s": round(flown, 2),
    }


def up_lockstep(only: list[str] | None = None) -> dict[str, Any]:
    """The registered benchmark: every case once."""
    rows = []
    for name in only or CASES:
        row = {"case": name, **run_case(*CASES[name])}
        print(json.dumps(row), flush=True)
        rows.append(row)
    by = {r["case"]: r for r in rows}
    met = {name: (by[name]["rtf"] or 0) >= target for name, target in TARGETS.items() if name in by}
    if "n100_k25" in by:
        met["agent_cpu_us_k25"] = (by["n100_k25"]["agent_cpu_us_per_agent_tick"] or 1e9) <= (
            TARGET_AGENT_US
        )
    result = {
        "command": "python -m bench.up_lockstep",
        "rows": rows,
        "targets": {**TARGETS, "agent_cpu_us_k25": TARGET_AGENT_US},
        "targets_met": met,
        "cpu_count": os.cpu_count(),
        "plot": str(OUT_PNG.relative_to(ROOT)),
    }
    write_result(OUT_JSON, result, indent=2)
    plot(rows, OUT_PNG)
    return result


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    """The cases side by side: real-time factor (the targets as red stars, real time as a
    dashed line) and agent CPU per agent-tick (the 100 µs target dashed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, 3.8))
    FigureCanvasAgg(fig)
    speed, cpu = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    names = [r["case"] for r in rows]
    at = np.arange(len(rows))
    speed.bar(at, [r["rtf"] or 0.0 for r in rows], color="tab:blue")
    for k, name in enumerate(names):
        if name in TARGETS:
            speed.plot([k], [TARGETS[name]], marker="*", markersize=12, color="red")
    speed.plot([], [], marker="*", color="red", linestyle="none", label="target")
    speed.axhline(1.0, color="grey", linestyle="--", linewidth=1, label="real time")
    speed.set_ylabel("real-time factor (simulated / wall s)")
    speed.legend(fontsize=8)
    cpu.bar(at, [r["agent_cpu_us_per_agent_tick"] or 0.0 for r in rows], color="tab:orange")
    cpu.axhline(
        TARGET_AGENT_US, color="red", linestyle="--", linewidth=1, label="target 100 µs (K = 25)"
    )
    cpu.set_yscale("log")
    cpu.set_ylabel("agent CPU per agent-tick (µs)")
    cpu.legend(fontsize=8)
    for ax in (speed, cpu):
        ax.set_xticks(at, names, rotation=30, ha="right", fontsize=8)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.suptitle("swarm up --clock lockstep, real processes (2-core machine)")
    fig.savefig(path, dpi=110, bbox_inches="tight")


if __name__ == "__main__":
    names = sys.argv[sys.argv.index("--only") + 1].split(",") if "--only" in sys.argv else None
    up_lockstep(names)
    print(f"wrote {OUT_JSON.relative_to(ROOT)} and {OUT_PNG.relative_to(ROOT)}")
