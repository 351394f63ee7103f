"""``swarm agent`` without ``--scenario``: the scenario is only the plan flown until a ground
station publishes one, so the agent starts on the defaults, joins its vehicle and the swarm, and
waits on the ground for a plan (it used to die with a traceback: ``defaults: duration_s``)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from agent_harness import SWARM, agent_process, observer, write_scenario
from sitl_client import ENV, ROOT, free_port_block, free_udp_port, sim_process, swarm_command

from protocols.wire.status import AgentMode, Health

pytestmark = pytest.mark.timeout(150)


def test_an_agent_without_a_scenario_joins_and_waits_for_a_plan(tmp_path: Path) -> None:
    base = free_port_block(1)
    with (
        observer() as obs,
        sim_process(tmp_path, "--drones", "1", "--gcs", "none", "--quiet", base_port=base),
        agent_process(tmp_path, "0", base, obs.zenoh_args) as agent,
    ):
        joined = obs.wait_until(lambda: 0 in obs.statuses() and obs.statuses()[0].t_s > 1.0, 30.0)
        log = agent.log.read_text()
        assert joined, log[-2000:]
        status = obs.statuses()[0]
        assert status.mode == AgentMode.WARMUP and not status.armed
        assert status.health & Health.VEHICLE_LINK and not status.health & Health.PLAN
        assert agent.proc.poll() is None and "Traceback" not in log


def test_agents_without_a_scenario_fly_the_ground_stations_plan(tmp_path: Path) -> None:
    """Simulator and ground station know the scenario; the agents do not: they say they wait for
    the ground station's plan, then fly it."""
    scenario = write_scenario(
        tmp_path / "pair.toml",
        [(0.0, 0.0, 0.0), (3.0, 0.0, 0.0)],
        centre=(1.5, 0.0, -2.0),
        spread=(1.5, 0.0, 0.0),
        duration_s=60.0,
        settle_s=8.0,
    )
    base, gcs_port = free_port_block(2), free_udp_port()
    with (
        observer() as obs,
        sim_process(
            tmp_path,
            *("--scenario", str(scenario), "--clock", "lockstep", "--wait-agents", "2"),
            *("--gcs", f"udp:127.0.0.1:{gcs_port}", "--quiet"),
            base_port=base,
        ),
        agent_process(tmp_path, "0-1", base, obs.zenoh_args) as agents,
    ):
        assert obs.wait_until(lambda: len(obs.statuses()) == 2, 30.0), agents.log.read_text()
        assert all(s.plan_seq is None for s in obs.statuses().values())
        gcs = subprocess.Popen(
            swarm_command(
                *("gcs", "--scenario", str(scenario), "--report", str(tmp_path / "r")),
                *("--gcs-port", str(gcs_port), "--swarm-id", SWARM, "--quiet"),
                *("--no-plots", "--no-recording"),
                *obs.zenoh_args,
            ),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=ENV,
            cwd=ROOT,
        )
        try:
            flying = obs.wait_until(
                lambda: all(
                    s.mode == AgentMode.FLYING and s.plan_seq == 0 and -s.estimate[2] > 1.5
                    for s in obs.statuses().values()
                ),
                90.0,
            )
            assert flying, obs.statuses()
        finally:
            gcs.terminate()
            gcs.wait(20)
    log = agents.log.read_text()
    assert "Traceback" not in log
