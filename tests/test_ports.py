"""The UDP port layout (protocols/mavlink_conventions.vehicle_port): defaults that never collide
for any number of drones (PX4's ports kept for the first ten), explicit clashes refused with one
line before anything starts, and a 12-drone swarm started with every default flies."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from agent_harness import write_scenario
from sitl_client import ENV, ROOT, swarm_command
from test_drill_flight import _default_ports_lock

from gcs.report.tlog import read_tlog
from protocols.mavlink.conventions import (
    DEFAULT_GCS_PORT,
    MAX_VEHICLES,
    describe_ports,
    port_clash,
    vehicle_port,
    vehicle_ports,
)


def test_the_default_layout_never_collides_and_keeps_px4_ports_for_ten() -> None:
    assert vehicle_ports(10) == list(range(14540, 14550))
    for n in range(1, MAX_VEHICLES + 1):
        ports = vehicle_ports(n)
        assert port_clash(ports, DEFAULT_GCS_PORT) is None, n
        assert all(p < 14550 or p >= 14560 for p in ports)  # 14550-14559: ground stations
    assert vehicle_port(10) == 14560 and vehicle_port(249) == 14799
    assert describe_ports(vehicle_ports(12)) == "14540-14549, 14560-14561"
    assert vehicle_ports(3, 20000) == [20000, 20001, 20002]  # an explicit base: contiguous


def test_clashes_are_named() -> None:
    clash = port_clash(vehicle_ports(12, 14540), 14550)
    assert clash is not None
    assert clash.startswith("vehicle 10 (system id 11) would listen on UDP 14550, the ground")
    assert "--base-port" in clash and "defaults" in clash
    bad = port_clash(vehicle_ports(3, 65534), None)
    assert bad is not None and "65536" in bad and "outside 1..65535" in bad
    assert port_clash([15000, 15000], None) == "vehicles 0 and 1 would both listen on UDP 15000"


@pytest.mark.parametrize(
    "argv",
    [
        # (refused before it starts: on the lockstep clock, which the first part may run)
        ("sim", "--drones", "12", "--base-port", "14540", "--clock", "lockstep"),
        ("up", "SCENARIO", "--base-port", "14540"),
    ],
)
def test_a_clash_the_user_picked_stops_before_anything_starts(
    tmp_path: Path, argv: tuple[str, ...]
) -> None:
    scenario = write_scenario(
        tmp_path / "twelve.toml", _grid(12), centre=(2.0, 2.5, -2.0), spread=(1.6, 1.7, 0.0)
    )
    args = [str(scenario) if a == "SCENARIO" else a for a in argv]
    out = subprocess.run(
        swarm_command(*args, "--report", str(tmp_path / "r")) if argv[0] == "up"
        else swarm_command(*args),
        capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "vehicle 10 (system id 11) would listen on UDP 14550" in lines[0]
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "r" / "logs" / "run.json").exists()  # nothing was started


def _up_with_defaults(folder: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """``swarm up ARGS`` in ``folder`` on the default ports and report folder; it must succeed."""
    with _default_ports_lock():
        out = subprocess.run(
            swarm_command("up", *args),
            capture_output=True, text=True, env=ENV, cwd=folder, timeout=400,
        )  # fmt: skip
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    return out


def _grid(n: int) -> list[tuple[float, float, float]]:
    return [(2.0 * (i // 4), 2.0 * (i % 4), 0.0) for i in range(n)]


@pytest.mark.slow
def test_twelve_drones_with_every_default_fly(tmp_path: Path) -> None:
    """``swarm up twelve.toml`` as a newcomer types it (default ports, endpoint and report):
    vehicles 10 and 11 are on 14560-14561, the ground station gets every vehicle's telemetry on
    14550, and all twelve fly."""
    scenario = write_scenario(
        tmp_path / "twelve.toml",
        _grid(12),
        centre=(2.0, 3.0, -2.0),
        spread=(1.63, 2.24, 0.0),
        duration_s=14.0,
        settle_s=8.0,
    )
    _up_with_defaults(tmp_path, str(scenario), "--agents-per-process", "12")
    sim_log = (tmp_path / "report" / "logs" / "sim.log").read_text()
    assert "UDP 127.0.0.1:14540-14549, 14560-14561, GCS udp:127.0.0.1:14550" in sim_log
    assert json.loads((tmp_path / "report" / "logs" / "run.json").read_text())["agents"]
    track = read_tlog(tmp_path / "report" / "flight.tlog")
    assert set(track.vehicles) == set(range(1, 13))
    for sysid, v in track.vehicles.items():
        assert -v.position_ned_m[-1, 2] > 1.5, (sysid, v.position_ned_m[-1])


def test_the_default_hosting_is_one_process_up_to_25_drones_then_one_per_core() -> None:
    from gcs.cli.up import default_agents_per_process

    assert [default_agents_per_process(n, cpus=2) for n in (1, 9, 16, 25)] == [1, 9, 16, 25]
    assert default_agents_per_process(26, cpus=2) == 13  # 2 processes: 13, 13
    assert default_agents_per_process(100, cpus=2) == 50
    assert default_agents_per_process(100, cpus=8) == 13  # 8 processes
    assert default_agents_per_process(100, cpus=1) == 50  # at least 2 processes
    assert default_agents_per_process(250, cpus=2) == 125


@pytest.mark.slow
def test_a_large_swarm_with_every_default_is_hosted_and_flies(tmp_path: Path) -> None:
    """``swarm up scenarios/large_grid25.toml`` as a newcomer types it: a hundred drones with
    one process each took 16 GB and two minutes for 0.06 simulated seconds on two cores, so
    the agents are hosted: all 25 in one process (the fastest layout measured up to 25 drones).
    The first 11 s (before the scenario's drop-out): all 25 vehicles climb to the plan's 3 m."""
    from gcs.cli.up import default_agents_per_process

    k = default_agents_per_process(25)
    scenario = ROOT / "scenarios" / "large_grid25.toml"
    out = _up_with_defaults(tmp_path, str(scenario), "--duration-s", "11")
    processes = -(-25 // k)
    assert processes == 1 and "25 drones, 1 agent process (the default: all in one" in out.stderr
    run = json.loads((tmp_path / "report" / "logs" / "run.json").read_text())
    assert len(set(run["agents"].values())) == processes and len(run["agents"]) == 25
    track = read_tlog(tmp_path / "report" / "flight.tlog")
    assert set(track.vehicles) == set(range(1, 26))
    for sysid, v in track.vehicles.items():
        assert -v.position_ned_m[-1, 2] > 2.5, (sysid, v.position_ned_m[-1])
