"""End-to-end speed of ``swarm up``: simulator, ground station and agents as real processes.

- Realtime clock, N = 9, 25, 50, 100 drones hovering, with one agent process per drone and with
  25 agents hosted per process. The simulator is paced to the wall clock, so the question is
  whether the agents keep up: the end-to-end real-time factor is the simulator's own rate times
  the fraction of control ticks the agents answered (setpoints received / (N x control rate)).
- Lockstep clock, N = 9 (the paper's swarm): how much faster than real time it runs (target 5x),
  with one agent process per drone and with the nine hosted in one process.

Writes a PNG of real-time factor against N beside the JSON (``bench/rtf_vs_n.png``).

The hover scenario uses the degree-normalised consensus gain at its documented maximum (rho c = 8).
``flying_at_end`` says whether the swarm flew: a real-time factor of a crashing swarm means little.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.sitl import _free_block, _status_lines

ROOT = Path(__file__).resolve().parents[1]
CONTROL_HZ = 50
SIZES = (9, 25, 50, 100)
HOSTED_PER_PROCESS = 25
REALTIME_S = 25.0
LOCKSTEP_S = 40.0
SETTLED_FROM_S = 10.0


def scenario_text(n: int, duration_s: float) -> str:
    """N drones on a square grid 2.5 m apart, hovering at 3 m in their grid's shape."""
    side = math.ceil(math.sqrt(n))
    pos = [(2.5 * (k // side), 2.5 * (k % side), 0.0) for k in range(n)]
    xs, ys = np.array([p[0] for p in pos]), np.array([p[1] for p in pos])
    spread = (max(float(xs.std()), 0.5), max(float(ys.std()) * 0.9, 0.4), 0.0)
    centre = (float(xs.mean()), float(ys.mean()), -3.0)
    drones = "\n".join(f"[[drones]]\nposition_ned_m = {list(p)}\n" for p in pos)
    wp = f"centre_ned_m = {list(centre)}\nspread_m = {list(spread)}\n"
    return (
        f'version = 1\nname = "hover{n}"\nduration_s = {duration_s}\nsettle_s = 5.0\n\n'
        f"[comms]\nrange_m = 6.0\n\n[consensus]\ndegree_normalised = true\nrho = 8.0\n\n"
        f"{drones}\n[[trajectory.waypoints]]\nt_s = 0.0\n{wp}\n"
        f"[[trajectory.waypoints]]\nt_s = 10.0\n{wp}"
    )


def run_up(n: int, per_process: int, clock: str, duration_s: float) -> dict[str, Any]:
    """One ``swarm up`` run; the figures read from the simulator's status lines."""
    with tempfile.TemporaryDirectory() as tmp:
        scenario = Path(tmp) / f"hover{n}.toml"
        scenario.write_text(scenario_text(n, duration_s))
        report = Path(tmp) / "report"
        base, gcs = _free_block(n), _free_block(1)
        wall0 = time.monotonic()
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "gcs.cli",
                "up",
                str(scenario),
                "--report",
                str(report),
                "--clock",
                clock,
                "--agents-per-process",
                str(per_process),
                "--base-port",
                str(base),
                "--gcs-port",
                str(gcs),
            ],
            capture_output=True,
            text=True,
            cwd=ROOT,
            env={**os.environ, "MAVLINK20": "1"},
            timeout=1200,
        )
        wall = time.monotonic() - wall0
        log = report / "logs" / "sim.log"
        text = log.read_text(errors="replace").replace("\r", "\n") if log.exists() else ""
    lines = _status_lines(text)
    rx = _rx_counts(text)
    settled = [(s, r) for s, r in zip(lines, rx, strict=False) if s["sim"] >= SETTLED_FROM_S]
    sim_rtf = answered = float("nan")
    if len(settled) >= 3:
        w = np.array([s["wall"] for s, _ in settled])
        sim = np.array([s["sim"] for s, _ in settled])
        got = np.array([r for _, r in settled], dtype=float)
        sim_rtf = float(np.polyfit(w, sim, 1)[0])
        answered = float(np.polyfit(sim, got, 1)[0]) / (n * CONTROL_HZ)
    flying = lines[-1]["flying"] if lines else 0.0
    rtf = sim_rtf * min(answered, 1.0) if clock == "realtime" else sim_rtf
    return {
        "n": n,
        "agents_per_process": per_process,
        "clock": clock,
        "processes": 2 + math.ceil(n / per_process),
        "rtf": round(rtf, 3) if math.isfinite(rtf) else None,
        "sim_rtf": round(sim_rtf, 3) if math.isfinite(sim_rtf) else None,
        "ticks_answered": round(answered, 3) if math.isfinite(answered) else None,
        "flying_at_end": int(flying),
        "wall_s": round(wall, 1),
        "exit": proc.returncode,
    }


def _rx_counts(text: str) -> list[float]:
    out = []
    for line in text.splitlines():
        if line.startswith("sim "):
            words = line.replace("|", " ").split()
            out.append(float(words[words.index("rx") + 1]))
    return out


def end_to_end() -> dict[str, Any]:
    """The registered benchmark."""
    rows = []
    for n in SIZES:
        for per in (1, HOSTED_PER_PROCESS):
            rows.append(run_up(n, per, "realtime", REALTIME_S))
    lockstep = run_up(9, 1, "lockstep", LOCKSTEP_S)
    rows.append(lockstep)
    lockstep_hosted = run_up(9, 9, "lockstep", LOCKSTEP_S)  # the 9 agents in one process
    rows.append(lockstep_hosted)
    hosted_100 = next(r for r in rows if r["n"] == 100 and r["agents_per_process"] > 1)
    per_process = [r for r in rows if r["agents_per_process"] == 1 and r["clock"] == "realtime"]
    keeps_up = [r["n"] for r in per_process if (r["rtf"] or 0) >= 0.95]
    _plot(rows, ROOT / "bench" / "rtf_vs_n.png")
    return {
        "rows": rows,
        "targets": {"hosted_n100_rtf": 1.0, "lockstep_n9_speed": 5.0},
        "hosted_n100_rtf_met": (hosted_100["rtf"] or 0) >= 1.0 * 0.95,
        "lockstep_n9_speed_met": max(lockstep["rtf"] or 0, lockstep_hosted["rtf"] or 0) >= 5.0,
        "one_process_per_drone_keeps_up_to_n": max(keeps_up) if keeps_up else None,
        "plot": "bench/rtf_vs_n.png",
    }


def _plot(rows: list[dict[str, Any]], path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for per, label in ((1, "one process per drone"), (HOSTED_PER_PROCESS, "25 agents per process")):
        pts = [
            (r["n"], r["rtf"])
            for r in rows
            if r["agents_per_process"] == per and r["clock"] == "realtime" and r["rtf"]
        ]
        if pts:
            ax.plot(*zip(*pts, strict=True), marker="o", label=label)
    ax.axhline(1.0, color="grey", linestyle="--", linewidth=1)
    ax.set_xlabel("drones N")
    ax.set_ylabel("end-to-end real-time factor")
    ax.set_title("swarm up --clock realtime (2-core machine)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.savefig(path, dpi=110, bbox_inches="tight")


if __name__ == "__main__":
    import json

    print(
        json.dumps(
            run_up(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], float(sys.argv[4])), indent=1
        )
    )
