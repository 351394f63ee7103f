"""``swarm up --drones N`` before anything flies: the flags, the session's scenario (made by the
scenario generator, resting on the ground), what each child is told, the commands a grounded
swarm accepts, and the supervisor's shutdown on Ctrl-C (with stand-in children)."""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from sitl_client import free_port_block, free_udp_port

from gcs.cli.gcs import RECORDING
from gcs.cli.main import _parser, main
from gcs.cli.session import SESSION_FILE, session_request, session_scenario
from gcs.cli.supervisor import SHUT_DOWN, Child, RunPlan, supervise
from gcs.cli.up import build_plan
from gcs.station.commands import Request, parse_request, plan_command
from gcs.station.planner import Envelope, PlanRefused
from protocols.scenario.layout import layout_positions
from protocols.scenario.scenario_file import load_scenario
from protocols.wire.plan import FlightCommand, PlanMessage
from sitl_sim.launch import START_LINE_PREFIX


# -- the flags ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["up"], "give a scenario file (swarm up SCENARIO) or --drones N"),
        (["up", "s.toml", "--drones", "4"], "for an operator session give --drones N without a"),
        (["up", "--drones", "0"], "--drones: need 2..250, got 0"),
        (["up", "--drones", "300"], "--drones: need 2..250, got 300"),
        (["up", "--drones", "1"], "--drones: need 2..250, got 1"),
        (["up", "s.toml", "--layout", "circle"], "--layout goes with --drones N"),
        (["up", "s.toml", "--range-m", "8"], "--range-m goes with --drones N"),
        (["up", "--drones", "4", "--duration-s", "30"], "--duration-s: an operator session"),
        (["up", "--drones", "4", "--range-m", "1"], "--range-m: at 1 m the radio graph"),
        (["up", "--drones", "4", "--spacing-m", "0"], "--spacing-m: must be a positive number"),
        (["up", "--drones", "4", "--shutdown-timeout-s", "0"], "--shutdown-timeout-s: must be"),
        (["up", "--drones", "0-4"], "--drones: an operator session needs a number of drones"),
        (["up", "s.toml", "--drones", "0-4"], "--drones is for a swarm spread over hosts"),
        (["up", "--drones", "4", "--router", "tcp/10.0.0.1:7447"], "--router: an operator"),
    ],
)
def test_bad_combinations_are_one_line_and_exit_2(
    argv: list[str], says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main([*argv, "--report", str(tmp_path / "report")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("swarm: error: "), err
    assert says in err, err
    assert not (tmp_path / "report" / "logs" / SESSION_FILE).exists()  # nothing started


def test_up_help_explains_the_two_ways(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["up", "--help"])
    text = capsys.readouterr().out
    for words in ("swarm up SCENARIO", "swarm up --drones N", "swarm takeoff --altitude-m",
                  "swarm shutdown", "Ctrl-C", "--layout", "--spacing-m", "--range-m"):  # fmt: skip
        assert words in text, words


def test_defaults_of_a_session() -> None:
    request = session_request(_parser().parse_args(["up", "--drones", "4"]))
    assert request is not None
    assert (request.drones, request.layout, request.spacing_m, request.range_m) == (
        4, "grid", 2.5, 6.0,
    )  # fmt: skip
    assert session_request(_parser().parse_args(["up", "s.toml"])) is None
    assert session_request(_parser().parse_args(["demo"])) is None


# -- the session's scenario --------------------------------------------------------------------
@pytest.mark.parametrize("layout", ["grid", "line", "circle", "random"])
def test_the_session_scenario_is_the_generator_s_layout_resting_on_the_ground(
    layout: str, tmp_path: Path
) -> None:
    argv = ["up", "--drones", "7", "--layout", layout, "--spacing-m", "3", "--range-m", "7"]
    request = session_request(_parser().parse_args(argv))
    assert request is not None
    generated = session_scenario(request, tmp_path / SESSION_FILE)
    expected = layout_positions(layout, 7, 3.0, np.random.default_rng(0), reach_m=7.0)
    np.testing.assert_allclose(generated.positions_ned_m, expected)
    scenario = generated.scenario
    assert scenario.comms.range_m == 7.0
    trajectory = scenario.trajectory()
    a, rate, _ = trajectory.evaluate_many(np.linspace(0.0, 3600.0, 500))
    np.testing.assert_allclose(a[:, 2], 0.0, atol=1e-12)  # the centre never leaves the ground
    np.testing.assert_allclose(rate, 0.0, atol=1e-12)
    np.testing.assert_allclose(a[0, :2], expected.mean(axis=0)[:2], atol=1e-6)
    assert "swarm up --drones 7 --layout " + layout in generated.text
    (tmp_path / SESSION_FILE).write_text(generated.text)
    assert load_scenario(tmp_path / SESSION_FILE).n_drones == 7


def test_each_child_is_told_it_is_a_session(tmp_path: Path) -> None:
    ports = ["--base-port", str(free_port_block(4)), "--gcs-port", str(free_udp_port())]
    argv = ["up", "--drones", "4", "--report", str(tmp_path), *ports]
    args = _parser().parse_args(argv)
    request = session_request(args)
    path = tmp_path / "logs" / SESSION_FILE
    plan, n = build_plan(args, path, request)
    assert n == 4 and plan.session and plan.agent_drones == [range(4)]  # hosted: one process
    assert path.exists() and load_scenario(path).n_drones == 4
    assert "--session" in plan.gcs.argv and "--duration-s" not in plan.gcs.argv
    assert "--duration-s" not in plan.sim.argv  # the simulator runs until it is stopped
    assert all("--wait-for-plan" in a.argv for a in plan.agents)  # not the file's plan: GROUND
    for child in plan.children:
        assert child.argv[child.argv.index("--scenario") + 1] == str(path)


# -- what a grounded swarm accepts -------------------------------------------------------------
def _grounded() -> PlanMessage:
    request = session_request(_parser().parse_args(["up", "--drones", "4"]))
    assert request is not None
    scenario = session_scenario(request, Path("session.toml")).scenario
    return PlanMessage(scenario.trajectory(), FlightCommand.GROUND)


@pytest.mark.parametrize(
    "request_",
    [
        Request("formation", {"heading_deg": 30.0}),
        Request("move", {"north_m": 2.0}),
        Request("rotate", {"delta_deg": 10.0}),
        Request("scale", {"factor": 1.2}),
        Request("land", {}),
    ],
)
def test_on_the_ground_only_takeoff_flies(request_: Request) -> None:
    with pytest.raises(PlanRefused, match="on the ground: take off first"):
        plan_command(request_, _grounded(), 20.0, Envelope())


def test_takeoff_from_the_ground_climbs_and_says_fly() -> None:
    grounded = _grounded()
    plan, when = plan_command(Request("takeoff", {"altitude_m": 3.0}), grounded, 20.0, Envelope())
    assert plan.command == FlightCommand.FLY and plan.seq == grounded.seq + 1
    assert "centre arrives" in when
    a0 = plan.trajectory.evaluate(20.0)[0]
    a1 = plan.trajectory.evaluate(plan.trajectory.end_s)[0]
    assert a0[2] == pytest.approx(0.0, abs=1e-9) and a1[2] == pytest.approx(-3.0)
    np.testing.assert_allclose(a1[3:], a0[3:])  # the layout's formation, 3 m up


def test_shutdown_is_a_command_without_arguments() -> None:
    assert parse_request(b'{"version": 1, "command": "shutdown", "args": {}}').name == "shutdown"


# -- the supervisor's Ctrl-C in a session ------------------------------------------------------
#: a ground station that lands on SIGINT; it says it records (what the supervisor waits for
#: before it starts the simulator) once its handlers are in place
GCS_STANDIN = f"""
import signal, sys, time
def on_int(*_):
    print("SIGINT: landing", flush=True)
    time.sleep(0.5)
    sys.exit(0)
signal.signal(signal.SIGINT, on_int)
signal.signal(signal.SIGTERM, lambda *_: sys.exit(3))
print({RECORDING!r}, "udp:127.0.0.1:0", flush=True)
while True:
    time.sleep(0.05)
"""
#: a simulator that says it started (what the supervisor waits for before the agents) and runs on
SIM_STANDIN = f"import time; print({START_LINE_PREFIX!r}, flush=True); time.sleep(60)"


def _standin_plan(tmp_path: Path) -> RunPlan:
    sim = [sys.executable, "-c", SIM_STANDIN]
    gcs = Child("gcs", [sys.executable, "-c", GCS_STANDIN], tmp_path / "gcs.log")
    plan = RunPlan(gcs, Child("simulator", sim, tmp_path / "sim.log"))
    plan.session, plan.shutdown_wait_s = True, 20.0
    return plan


def test_a_session_s_ctrl_c_lets_the_ground_station_land_and_end_the_run(tmp_path: Path) -> None:
    plan = _standin_plan(tmp_path)
    # one Ctrl-C, seen as soon as everything started (the stand-in said it records: its SIGINT
    # handler is in place, however slowly a loaded machine started it)
    assert supervise(plan, should_stop=lambda: 1, poll_s=0.1) == SHUT_DOWN
    assert "SIGINT: landing" in (tmp_path / "gcs.log").read_text()
    assert plan.gcs.proc is not None and plan.gcs.proc.returncode == 0
    assert not plan.sim.running


def test_a_second_ctrl_c_stops_everything_at_once(tmp_path: Path) -> None:
    plan = _standin_plan(tmp_path)
    assert supervise(plan, should_stop=lambda: 2, poll_s=0.1) == "interrupted"
    assert not plan.gcs.running and not plan.sim.running
    assert plan.gcs.proc is not None and plan.gcs.proc.returncode in (3, -signal.SIGTERM)


# -- the ground station of a session -----------------------------------------------------------
def test_a_session_gcs_starts_grounded_and_its_shutdown_gives_up_after_the_timeout(
    tmp_path: Path,
) -> None:
    """First plan GROUND; a shutdown while a vehicle is still up waits for it, at most
    ``shutdown_timeout_s``, then ends the run with a report; commands after it are refused."""
    from gcs.report.events import read_events
    from gcs.station.commands import encode_request
    from gcs.station.ground_station import GcsOptions, GroundStation
    from gcs.station.telemetry import VehicleState
    from protocols.bus.zenoh_bus import ZenohSettings

    request = session_request(_parser().parse_args(["up", "--drones", "4"]))
    assert request is not None
    scenario = session_scenario(request, tmp_path / SESSION_FILE).scenario
    options = GcsOptions(
        scenario=scenario,
        report_dir=tmp_path / "report",
        zenoh=ZenohSettings(listen=("tcp/127.0.0.1:0",)),
        gcs_port=free_udp_port(),
        plan_query_s=0.2,
        plots=False,
        session=True,
        shutdown_timeout_s=1.0,
    )
    with GroundStation(options) as station:
        assert station.plan.command == FlightCommand.GROUND
        station.telemetry.vehicles[2] = VehicleState(position_ned_m=(0.0, 0.0, -2.0), armed=True)
        assert station.airborne_drones() == [2]
        reply = station.execute(encode_request(Request("shutdown", {})))
        assert reply.accepted and "landing" in reply.reason, reply
        refused = station.execute(encode_request(Request("takeoff", {"altitude_m": 3.0})))
        assert not refused.accepted and "shutting down" in refused.reason
        started = time.monotonic()
        files = station.run()
        assert 1.0 <= time.monotonic() - started < 10.0
    assert tmp_path / "report" / "metrics.json" in files
    kinds = [e["kind"] for e in read_events(tmp_path / "report" / "events.jsonl")]
    assert kinds[-2:] == ["shutdown_timeout", "run_end"], kinds
