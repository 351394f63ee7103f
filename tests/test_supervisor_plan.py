"""What ``swarm up`` hands out: agent groups per process and the run file the ground station
reads for the dropout drill and operators read for the endpoint."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from agent_harness import GRID, write_scenario
from sitl_client import free_port_block, free_udp_port

from gcs.cli.main import _parser
from gcs.cli.supervisor import Child, RunPlan, agent_groups, agent_ranges
from gcs.cli.up import build_plan


def test_agent_groups_and_ranges() -> None:
    assert agent_groups(4, 1) == ["0", "1", "2", "3"]
    assert agent_groups(9, 4) == ["0-3", "4-7", "8-8"]
    assert [list(r) for r in agent_ranges(5, 2)] == [[0, 1], [2, 3], [4]]


def test_run_file_lists_each_drone_with_its_process(tmp_path: Path) -> None:
    sleeper = [sys.executable, "-c", "import time; time.sleep(30)"]
    agents = [Child(f"agent {i}", sleeper, tmp_path / f"a{i}.log") for i in range(2)]
    plan = RunPlan(
        Child("gcs", sleeper, tmp_path / "g.log"),
        Child("simulator", sleeper, tmp_path / "s.log"),
        agents,
        agent_ranges(3, 2),
        tmp_path / "run.json",
        "tcp/127.0.0.1:7447",
    )
    try:
        for a in agents:
            a.start()
        plan.write_run_file()
        run = json.loads((tmp_path / "run.json").read_text())
    finally:
        for a in agents:
            a.stop(timeout_s=5)
    assert run["zenoh"] == "tcp/127.0.0.1:7447"
    pids = [a.proc.pid for a in agents if isinstance(a.proc, subprocess.Popen)]
    assert run["agents"] == {"0": pids[0], "1": pids[0], "2": pids[1]}
    assert not (tmp_path / "run.tmp").exists()


def _up_plan(tmp_path: Path, *flags: str) -> RunPlan:
    scenario = write_scenario(tmp_path / "s.toml", GRID, centre=(3, 2, -3), spread=(2, 1, 0))
    ports = ["--base-port", str(free_port_block(9)), "--gcs-port", str(free_udp_port())]
    args = _parser().parse_args(["up", str(scenario), "--report", str(tmp_path), *ports, *flags])
    return build_plan(args, scenario)[0]


def _flag(argv: list[str], name: str) -> str | None:
    return argv[argv.index(name) + 1] if name in argv else None


def test_with_zenoh_connect_no_child_takes_the_rendezvous_port(tmp_path: Path) -> None:
    """Regression: with ``--zenoh-connect`` the ground station was left to listen on its default,
    the rendezvous port 7447, so the run failed whenever another swarm on the machine held it."""
    plan = _up_plan(tmp_path, "--zenoh-connect", "tcp/127.0.0.1:17999")
    assert plan.zenoh_endpoint == "tcp/127.0.0.1:17999"
    for child in (plan.gcs, *plan.agents):
        assert _flag(child.argv, "--zenoh-listen") == "tcp/127.0.0.1:0", child.argv
        assert _flag(child.argv, "--zenoh-connect") == "tcp/127.0.0.1:17999", child.argv


def test_by_default_the_ground_station_is_the_rendezvous(tmp_path: Path) -> None:
    plan = _up_plan(tmp_path)
    endpoint = plan.zenoh_endpoint
    assert endpoint is not None and endpoint.startswith("tcp/127.0.0.1:")
    assert _flag(plan.gcs.argv, "--zenoh-listen") == endpoint
    assert all(_flag(a.argv, "--zenoh-connect") == endpoint for a in plan.agents)


def test_a_report_folder_used_again_shows_this_runs_last_line_not_the_old_ones(
    tmp_path: Path,
) -> None:
    """The logs of a report folder are appended to: the status line of a new run must not show
    the last run's final status (``sim 199.96 s ... crashed 1``) before its own first line."""
    log = tmp_path / "sim.log"
    log.write_bytes(b"sim    199.96 s | wall 175.6 s | crashed 1\r")
    quiet = Child("simulator", [sys.executable, "-c", "import time; time.sleep(30)"], log)
    quiet.start()
    try:
        assert quiet.last_line() == ""
    finally:
        quiet.stop()
    talker = Child("simulator", [sys.executable, "-c", "print('sim 0.02 s', flush=True)"], log)
    talker.start()
    assert talker.proc is not None and talker.proc.wait(30) == 0
    assert talker.last_line() == "sim 0.02 s"
    assert log.read_text().startswith("sim    199.96 s")  # the old run's log is kept


def test_the_agents_start_once_the_simulator_has_bound_its_ports(tmp_path: Path) -> None:
    """An agent binds an ephemeral UDP port for its vehicle link; started while the simulator
    was still building its world, one of a hundred agents' ports landed on a vehicle's port of a
    block picked in the ephemeral range (1 of 4 bench runs of 100 drones: "UDP port ... is in
    use", nothing flew). The agents now start after the simulator's line saying where its
    vehicles listen (printed once the ports are bound), also when the log holds an older run's."""
    from gcs.cli.supervisor import SIM_BOUND, _start

    sim_log = tmp_path / "sim.log"
    sim_log.write_text(f"{SIM_BOUND}9 vehicles on UDP 127.0.0.1:14540-14548\n")  # the last run's
    slow_sim = (
        f"import time; time.sleep(1.5); print({SIM_BOUND!r} + '1 vehicle on UDP', flush=True); "
        "time.sleep(30)"
    )
    stamp = tmp_path / "agent-started"
    agent = f"import pathlib, time; pathlib.Path({str(stamp)!r}).write_text(str(time.time()))"
    plan = RunPlan(
        gcs=None,
        sim=Child("simulator", [sys.executable, "-c", slow_sim], sim_log),
        agents=[Child("agent 0", [sys.executable, "-c", agent], tmp_path / "agent-0.log")],
        agent_drones=[range(1)],
        run_file=tmp_path / "run.json",
    )
    began = time.time()
    _start(plan)
    try:
        assert plan.agents[0].proc is not None and plan.agents[0].proc.wait(30) == 0
        assert float(stamp.read_text()) - began >= 1.5
    finally:
        for child in plan.children:
            child.stop()


def test_the_simulator_starts_once_the_ground_station_records(tmp_path: Path) -> None:
    """On a loaded machine the ground station's start (imports, then binding the telemetry port)
    took over a second; the simulator started 0.3 s after it, so flight.tlog missed the flight's
    first second (seen in CI). The simulator now starts after the ground station's line saying it
    records, also when a report folder used again already holds that line from an older run."""
    from gcs.cli.gcs import RECORDING
    from gcs.cli.supervisor import _start

    gcs_log = tmp_path / "gcs.log"
    gcs_log.write_text(f"{RECORDING} udp:127.0.0.1:14550\n")  # the last run's
    slow_gcs = (
        f"import time; time.sleep(1.5); print({RECORDING!r} + ' udp:127.0.0.1:1', flush=True); "
        "time.sleep(30)"
    )
    stamp = tmp_path / "sim-started"
    sim = f"import pathlib, time; pathlib.Path({str(stamp)!r}).write_text(str(time.time()))"
    plan = RunPlan(
        gcs=Child("gcs", [sys.executable, "-c", slow_gcs], gcs_log),
        sim=Child("simulator", [sys.executable, "-c", sim], tmp_path / "sim.log"),
        run_file=tmp_path / "run.json",
    )
    began = time.time()
    _start(plan)
    try:
        assert plan.sim is not None and plan.sim.proc is not None and plan.sim.proc.wait(30) == 0
        assert float(stamp.read_text()) - began >= 1.5
    finally:
        for child in plan.children:
            child.stop()
