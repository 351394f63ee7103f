"""The paper's flight read back from a report's flight.tlog, shared by the tests of
``swarm simulate`` (in-process) and ``swarm demo`` (distributed): positions on a 25 Hz grid, who
is in the swarm (drone 1 is lost when the scenario crashes it) and the commanded descriptors."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from sitl_client import free_port_block, free_udp_port

from gcs.report.tlog import TlogTrack, read_tlog
from gcs.report.trajectory_file import read_trajectory
from protocols.scenario.scenario_file import Crash, load_scenario

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "paper.toml"
SWARM = [sys.executable, "-m", "gcs.cli"]
ENV = {**os.environ, "MAVLINK20": "1", "MPLBACKEND": "Agg"}
TLOG_GRID_HZ = 25.0


def simulate_paper(out: Path) -> Path:
    """Run ``swarm simulate scenarios/paper.toml --report out``; returns ``out``."""
    proc = subprocess.run(
        [*SWARM, "simulate", str(PAPER), "--report", str(out), "--progress", "off"],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr
    assert "centroid tracking" in proc.stdout
    return out


def run_demo(out: Path) -> tuple[Path, str]:
    """Run ``swarm demo`` in ``out`` (free ports and its own swarm id, so it does not clash with
    a swarm already running); returns its report folder and printed output."""
    report = out / "report"
    base, gcs_port = free_port_block(9), free_udp_port()
    proc = subprocess.run(
        [*SWARM, "demo", "--report", str(report), "--base-port", str(base),
         "--gcs-port", str(gcs_port), "--swarm-id", "demotest"],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=out,  # not the project folder: the demo finds the paper's scenario by itself
        timeout=900,
    )  # fmt: skip
    logs = "\n".join(f"{p.name}: {p.read_text()[-2000:]}" for p in (report / "logs").glob("*.log"))
    assert proc.returncode == 0, proc.stderr[-3000:] + logs
    return report, proc.stdout


def paper_flight(report: Path) -> dict[str, np.ndarray]:
    """``t`` (T,), ``positions`` (T, N, 3), ``member`` (T, N), ``desired`` (T, 9) of the paper's
    flight from ``report/flight.tlog``; the commanded descriptors are the plan as flown (the
    report's trajectory.json: the paper's plan starts on the ground, so it waits for the swarm's
    take-off, protocols/model/plan_timing.py)."""
    return flight_of(read_tlog(report / "flight.tlog"), report)


def flight_of(track: TlogTrack, report: Path) -> dict[str, np.ndarray]:
    """As :func:`paper_flight`, from an already read tlog of the report in ``report``."""
    scenario = load_scenario(PAPER)
    t = np.arange(0.0, scenario.duration_s + 1e-9, 1.0 / TLOG_GRID_HZ)
    positions = track.resample(t, scenario.n_drones)
    member = np.ones((t.size, scenario.n_drones), dtype=bool)
    for fault in scenario.faults:
        if isinstance(fault, Crash):
            member[t >= fault.t_s, fault.drone] = False
    desired = read_trajectory(report / "trajectory.json").evaluate_many(t)[0]
    return {"t": t, "positions": positions, "member": member, "desired": desired}


def min_airborne_separation(positions: np.ndarray) -> float:
    """Smallest distance (m) between two airborne (> 0.1 m up) drones over the flight."""
    airborne = np.isfinite(positions[..., 2]) & (-positions[..., 2] > 0.1)
    d = np.linalg.norm(positions[:, :, None, :] - positions[:, None, :, :], axis=-1)
    both = airborne[:, :, None] & airborne[:, None, :]
    both &= ~np.eye(positions.shape[1], dtype=bool)[None]
    assert both.any()
    return float(np.nanmin(np.where(both, d, np.inf)))
