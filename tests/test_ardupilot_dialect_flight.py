"""A swarm in ArduCopter's dialect on our own simulator, end to end: the plain README command
``swarm up scenarios/ardupilot4.toml --dialect ardupilot --land-at-end`` (default ports, lockstep)
and what the vehicles did, from flight.tlog: they waited for their EKF, flew in GUIDED_NOGPS with
the agents' thrust read as a thrust (GUID_OPTIONS set by the agents), took off, formed, moved 20 m
with a 30 deg turn, landed in LAND and disarmed on the ground. The wire behaviour itself (modes,
pre-arm refusals, both readings of thrust, parameters, failsafes) is tests/test_sim_ardupilot_
dialect.py's; real ArduCopter SITL is tests/test_ardupilot_sitl.py's."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from gcs.report.events import read_events
from gcs.report.holds import window_errors
from gcs.report.tlog import read_tlog
from protocols.mavlink.conventions import CopterMode

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ardupilot_dialect") / "report"
    done = subprocess.run(
        [sys.executable, "-m", "gcs.cli", "up", "scenarios/ardupilot4.toml", "--dialect",
         "ardupilot", "--land-at-end", "--report", str(out)],
        cwd=ROOT, env={**os.environ, "MAVLINK20": "1"}, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return out


def test_the_vehicles_speak_ardupilot_and_fly_guided_nogps_then_land(report: Path) -> None:
    track = read_tlog(report / "flight.tlog")
    assert sorted(track.vehicles) == [1, 2, 3, 4]
    for vehicle in track.vehicles.values():
        modes = set(vehicle.custom_mode[vehicle.armed].tolist())
        assert int(CopterMode.GUIDED_NOGPS) in modes and int(CopterMode.LAND) in modes
        assert not vehicle.armed[-1]  # disarmed at the end ...
        assert -vehicle.position_ned_m[-1, 2] < 0.05  # ... on the ground
        assert vehicle.position_ned_m[:, 0].max() > 18.0  # it went 20 m north with the swarm
    kinds = [e["kind"] for e in read_events(report / "events.jsonl")]
    assert "shutdown_landed" in kinds and "collision" not in kinds


def test_the_agents_waited_for_the_ekf_and_set_thrust_as_thrust(report: Path) -> None:
    track = read_tlog(report / "flight.tlog")
    texts = [t.text for t in track.statustexts]
    assert any("using GPS" in t for t in texts)  # the simulated EKF became ready ...
    ready_s = min(t.t_s for t in track.statustexts if "using GPS" in t.text)
    for vehicle in track.vehicles.values():
        armed_s = vehicle.heartbeat_t_s[vehicle.armed]
        assert armed_s.min() >= ready_s  # ... before anyone armed
    # flown as a thrust: a climb-rate reading of the agents' ~0.5 hover thrust would hold the
    # vehicles at zero climb; they climbed to the plan's 5 m, moved and held the end
    hold = window_errors(report, range(4), 45.0, 53.0, n_drones=4)
    assert hold.centre_m < 0.05 and hold.spread < 0.02
