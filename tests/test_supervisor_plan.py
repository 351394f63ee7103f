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


def _slow_then_next(tmp_path: Path, line: str, slow: str, nxt: str) -> float:
    """Start a plan of two fake children with :func:`_start`: ``slow`` (the ground station or
    the simulator) prints ``line`` after 1.5 s, its log already holding that line from an older
    run; ``nxt`` (the simulator or an agent) writes when it started. How long after the start
    the second one started (s)."""
    from gcs.cli.supervisor import _start

    first_log = tmp_path / f"{slow}.log"
    first_log.write_text(f"{line} (the last run's)\n")
    first = Child(
        slow,
        [sys.executable, "-c",
         f"import time; time.sleep(1.5); print({line!r}, flush=True); time.sleep(30)"],
        first_log,
    )  # fmt: skip
    stamp = tmp_path / "started"
    second = Child(
        nxt,
        [sys.executable, "-c",
         f"import pathlib, time; pathlib.Path({str(stamp)!r}).write_text(str(time.time()))"],
        tmp_path / f"{nxt}.log",
    )  # fmt: skip
    if slow == "gcs":
        plan = RunPlan(gcs=first, sim=second, run_file=tmp_path / "run.json")
    else:
        plan = RunPlan(gcs=None, sim=first, agents=[second], agent_drones=[range(1)],
                       run_file=tmp_path / "run.json")  # fmt: skip
    began = time.time()
    _start(plan)
    try:
        assert second.proc is not None and second.proc.wait(30) == 0
        return float(stamp.read_text()) - began
    finally:
        for child in plan.children:
            child.stop()


def test_the_agents_start_once_the_simulator_has_bound_its_ports(tmp_path: Path) -> None:
    """An agent binds an ephemeral UDP port for its vehicle link; started while the simulator
    was still building its world, one of a hundred agents' ports landed on a vehicle's port of a
    block picked in the ephemeral range (1 of 4 bench runs of 100 drones: "UDP port ... is in
    use", nothing flew). The agents now start after the simulator's line saying where its
    vehicles listen (printed once the ports are bound), also when the log holds an older run's."""
    from sitl_sim.launch import START_LINE_PREFIX

    line = f"{START_LINE_PREFIX}1 vehicle (system id 1) on UDP 127.0.0.1:14540"
    assert _slow_then_next(tmp_path, line, "simulator", "agent 0") >= 1.5


def test_the_simulator_starts_once_the_ground_station_records(tmp_path: Path) -> None:
    """On a loaded machine the ground station's start (imports, then binding the telemetry port)
    took over a second; the simulator started 0.3 s after it, so flight.tlog missed the flight's
    first second (seen in CI). The simulator now starts after the ground station's line saying it
    records, also when a report folder used again already holds that line from an older run."""
    from gcs.cli.gcs import RECORDING

    line = f"{RECORDING} udp:127.0.0.1:14550"
    assert _slow_then_next(tmp_path, line, "gcs", "simulator") >= 1.5


def _report_run(
    tmp_path: Path, report_stop_s: float, writing_s: float, ctrl_c_after_s: float | None = None
) -> tuple[str, Child, bool]:
    """A run of a fake ground station that takes ``writing_s`` to write its report once told to
    stop (SIGTERM) and a fake simulator that ends the run at once (and a Ctrl-C that many
    seconds after it ended); (why it ended, the ground station, whether its report was
    written)."""
    from gcs.cli.gcs import RECORDING
    from gcs.cli.supervisor import supervise
    from sitl_sim.launch import START_LINE_PREFIX

    tmp_path.mkdir()
    written = tmp_path / "report.done"
    gcs = Child(
        "gcs",
        [sys.executable, "-c",
         "import pathlib, signal, sys, time\n"
         "def stop(*_):\n"
         f"    time.sleep({writing_s})\n"
         f"    pathlib.Path({str(written)!r}).write_text('ok')\n"
         "    sys.exit(0)\n"
         "signal.signal(signal.SIGTERM, stop)\n"
         f"print({RECORDING + ' udp:127.0.0.1:1'!r}, flush=True)\n"
         "time.sleep(60)\n"],
        tmp_path / "gcs.log",
    )  # fmt: skip
    sim = Child(
        "simulator",
        [sys.executable, "-c", f"print({START_LINE_PREFIX + '1 vehicle'!r}, flush=True)"],
        tmp_path / "sim.log",
    )
    plan = RunPlan(gcs=gcs, sim=sim, report_stop_s=report_stop_s)
    seen: list[str] = []
    ended: list[float] = []

    def ctrl_c() -> int:
        if ctrl_c_after_s is None or sim.running or sim.proc is None:
            return 0
        if not ended:
            ended.append(time.monotonic())
        return int(time.monotonic() - ended[0] > ctrl_c_after_s)

    reason = supervise(plan, seen.append, ctrl_c, poll_s=0.05)
    assert "the ground station writes the report ... (Ctrl-C: stop it at once)" in seen
    return reason, gcs, written.exists()


def test_the_ground_station_gets_the_time_to_write_the_report(tmp_path: Path) -> None:
    """swarm up stops the ground station first and waits for its report longer than for the
    other children (a test suite's load once killed the paper flight's after two of its three
    plots, at the 15 s every child got); one that still does not finish is killed and said."""
    from gcs.cli.supervisor import REPORT_STOP_S, STOP_TIMEOUT_S

    assert REPORT_STOP_S >= 4 * STOP_TIMEOUT_S
    reason, gcs, written = _report_run(tmp_path / "a", report_stop_s=10.0, writing_s=1.0)
    assert reason == "finished" and written and not gcs.killed
    reason, gcs, written = _report_run(tmp_path / "b", report_stop_s=0.3, writing_s=5.0)
    assert reason == "finished" and not written and gcs.killed
    # a Ctrl-C while it writes: stopped at once, not after the 20 s it would take
    began = time.monotonic()
    reason, gcs, written = _report_run(tmp_path / "c", 60.0, writing_s=20.0, ctrl_c_after_s=0.5)
    assert reason == "finished" and not written and gcs.killed
    assert time.monotonic() - began < 10.0
