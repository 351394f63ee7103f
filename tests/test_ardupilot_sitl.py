"""The agents fly ArduPilot's own ArduCopter SITL: ``swarm up SCENARIO`` with ``ARDUPILOT_SITL``
naming an ``arducopter`` binary built for the sitl board (docs/autopilots.md says how). CI has
none, so these tests are skipped there, with that reason; they are run by hand on a machine with
the binary, and their figures are in docs/autopilots.md.

Each test types the plain command (default ports, real time, one ArduCopter instance per drone)
and judges what the vehicles did from flight.tlog: 4 vehicles wait for their EKF and GPS, take
off, move 20 m north with a 30 deg turn and a 15 % stretch, hold, and land at the end; and the
same flight with one agent killed mid-move (its vehicle's heartbeat failsafe lands it, the others
re-converge).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from gcs.report.events import read_events
from gcs.report.holds import window_errors
from gcs.report.tlog import read_tlog

ROOT = Path(__file__).resolve().parents[1]
BINARY = os.environ.get("ARDUPILOT_SITL", "")
pytestmark = pytest.mark.skipif(
    not BINARY or not Path(BINARY).is_file(),
    reason="ARDUPILOT_SITL does not name an arducopter binary built for the sitl board (none in "
    "CI; docs/autopilots.md says how to build one)",
)
#: The scenario's holds (s): hovering at 5 m before the move, and at the end of it.
HOLDS = ((20.0, 23.0), (45.0, 53.0))


def _fly(tmp_path: Path, scenario: Path) -> Path:
    report = tmp_path / "report"
    env = {**os.environ, "MAVLINK20": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "gcs.cli", "up", str(scenario), "--report", str(report)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert "all 4 vehicles ready" in done.stderr
    return report


def _errors(report: Path, drones: list[int], window: tuple[float, float]) -> tuple[float, float]:
    """Worst centre error (m) and worst relative spread error of ``drones`` in ``window``."""
    found = window_errors(report, drones, *window, n_drones=4)
    return found.centre_m, found.spread


def _landed_disarmed(report: Path, drone: int) -> bool:
    vehicle = read_tlog(report / "flight.tlog").vehicles[drone + 1]
    return bool(not vehicle.armed[-1] and -vehicle.position_ned_m[-1, 2] < 0.3)


def test_four_arducopters_take_off_move_turn_hold_and_land(tmp_path: Path) -> None:
    report = _fly(tmp_path, ROOT / "scenarios" / "ardupilot4.toml")
    for window in HOLDS:
        centre, spread = _errors(report, [0, 1, 2, 3], window)
        assert centre < 0.3, (window, centre)
        assert spread < 0.10, (window, spread)
    events = read_events(report / "events.jsonl")
    kinds = [e["kind"] for e in events]
    assert "crash" not in kinds and "vehicle_lost" not in kinds
    assert "shutdown_landed" in kinds
    for drone in range(4):
        assert _landed_disarmed(report, drone)


def test_an_agent_killed_mid_flight_lands_and_the_others_reconverge(tmp_path: Path) -> None:
    text = (ROOT / "scenarios" / "ardupilot4.toml").read_text()
    text += '\n[[faults]]\nkind = "dropout"\ndrone = 3\nt_s = 29.0\n'
    scenario = tmp_path / "ardupilot4_dropout.toml"
    scenario.write_text(text)
    report = _fly(tmp_path, scenario)
    events = read_events(report / "events.jsonl")
    texts = [e.get("text", "") for e in events if e.get("drone") == 3]
    assert any("GCS" in t and "ailsafe" in t for t in texts), texts  # ArduCopter's own words
    assert _landed_disarmed(report, 3)
    centre, spread = _errors(report, [0, 1, 2], HOLDS[1])
    assert centre < 0.3 and spread < 0.10, (centre, spread)
    for drone in range(3):
        assert _landed_disarmed(report, drone)
