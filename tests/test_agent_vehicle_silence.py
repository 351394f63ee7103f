"""An agent whose vehicle falls silent leaves the swarm: real ``swarm sim`` and ``swarm agent``
processes; the simulator is frozen (SIGSTOP: its sockets stay open, nothing comes out) or killed
(SIGKILL), and each hosted agent drops its liveliness token once no vehicle sample has come for
``vehicle_timeout_s`` (3 s, drone_agent/process/hosted_agent.py); with all its agents gone the agent
process ends by itself."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from agent_harness import SwarmObserver, agent_process, observer, write_scenario
from sitl_client import free_port_block, sim_process

from drone_agent.process.hosted_agent import RunOptions

pytestmark = pytest.mark.timeout(60)
PAIR = [(0.0, 0.0, 0.0), (3.0, 0.0, 0.0)]
TIMEOUT_S = RunOptions().vehicle_timeout_s


def _ticking(obs: SwarmObserver) -> bool:
    """Both agents joined (tokens up) and report simulated time moving on."""
    st = obs.statuses()
    return (
        obs.alive.get(0) is True
        and obs.alive.get(1) is True
        and len(st) == 2
        and min(s.t_s for s in st.values()) > 1.0
    )


@pytest.mark.parametrize("sig", [signal.SIGSTOP, signal.SIGKILL], ids=["frozen", "killed"])
def test_agents_leave_when_their_vehicles_fall_silent(tmp_path: Path, sig: signal.Signals) -> None:
    scenario = write_scenario(
        tmp_path / "pair.toml", PAIR, centre=(1.5, 0.0, 0.0), spread=(1.5, 0.0, 0.0)
    )
    base = free_port_block(2)
    with (
        observer() as obs,
        sim_process(
            tmp_path,
            *("--scenario", str(scenario), "--gcs", "none", "--quiet"),
            *("--clock", "lockstep", "--wait-agents", "2"),
            base_port=base,
        ) as sim,
        agent_process(
            tmp_path, "0-1", base, obs.zenoh_args, "--scenario", str(scenario), "--no-arm"
        ) as agents,
    ):
        assert obs.wait_until(lambda: _ticking(obs), 30.0), (obs.alive, obs.statuses())
        silenced = time.monotonic()
        sim.proc.send_signal(sig)
        try:
            assert obs.wait_until(lambda: not obs.alive[0] and not obs.alive[1], TIMEOUT_S + 5.0)
            gone = {
                d: next(t for t, drone, alive in obs.changes if drone == d and not alive) - silenced
                for d in (0, 1)
            }
            # not before the timeout (the last sample came at most a resend period before the
            # silence), and within a second of it
            assert all(TIMEOUT_S - 0.5 < g < TIMEOUT_S + 1.0 for g in gone.values()), gone
            # the ticks stopped with the samples: no status after the silence
            last_status = max(seen.at for seen in obs.latest.values())
            assert last_status < silenced + 0.5, last_status - silenced
            # nothing left to fly: the agent process ends by itself, cleanly
            assert agents.proc.wait(5.0) == 0, agents.log.read_text()[-2000:]
            log = agents.log.read_text()
            for d in (0, 1):  # and says why, even with --quiet
                assert f"drone {d} left the swarm at t=" in log, log[-2000:]
            assert f"no state from its vehicle for {TIMEOUT_S:g} s" in log, log[-2000:]
        finally:
            if sig == signal.SIGSTOP:
                sim.proc.send_signal(signal.SIGCONT)  # so that it can be stopped normally
