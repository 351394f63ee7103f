"""make test's two parts (tests/conftest.py): the serial lists name real modules, and the guard
that keeps a realtime flight out of the parallel part recognises one."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import DEFAULT_PORT_MODULES, REALTIME_MODULES
from sitl_client import needs_the_machine_alone, swarm_command

HERE = Path(__file__).parent


def test_the_serial_lists_name_existing_test_modules() -> None:
    missing = sorted(
        m for m in REALTIME_MODULES | DEFAULT_PORT_MODULES if not (HERE / f"{m}.py").exists()
    )
    assert not missing, missing


@pytest.mark.parametrize(
    ("args", "alone"),
    [
        (("sim", "--scenario", "s.toml"), True),  # swarm sim's default clock is realtime
        (("sim", "--scenario", "s.toml", "--clock", "realtime"), True),
        (("sim", "--scenario", "s.toml", "--clock", "lockstep"), False),
        (("sim", "--help"), False),
        (("up", "s.toml", "--clock", "realtime"), True),
        (("up", "s.toml"), False),  # lockstep by default
        (("simulate", "s.toml"), False),
    ],
)
def test_a_realtime_flight_needs_the_machine_alone(args: tuple[str, ...], alone: bool) -> None:
    assert (needs_the_machine_alone(args) is not None) == alone


def test_on_a_worker_a_realtime_simulator_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw0")
    with pytest.raises(AssertionError, match="REALTIME_MODULES"):
        swarm_command("sim", "--drones", "2")
    assert swarm_command("sim", "--drones", "2", "--clock", "lockstep")[-1] == "lockstep"
    monkeypatch.delenv("PYTEST_XDIST_WORKER")
    assert swarm_command("sim", "--drones", "2")[-1] == "2"  # the serial part starts it
