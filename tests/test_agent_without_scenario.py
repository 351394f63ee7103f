"""``swarm agent`` without ``--scenario``: the scenario is only the plan flown until a ground
station publishes one, so the agent starts on the defaults, joins its vehicle and the swarm, and
waits on the ground for a plan (it used to die with a traceback: ``defaults: duration_s``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from agent_harness import agent_process, observer
from sitl_client import free_port_block, sim_process

from protocols.wire_status import AgentMode, Health

pytestmark = pytest.mark.timeout(60)


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
