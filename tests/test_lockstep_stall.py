"""A stalled process slows lockstep down, it does not change the flight (issue 10): ``swarm up
--clock lockstep`` with two agent processes; once the swarm flies, one of them is frozen
(SIGSTOP) for 4 s, longer than the barrier's and the agents' old wall-clock timeouts (2 s and 3
s: on a machine loaded enough to starve a process, those dropped live agents and the run flew
another flight) and shorter than a lockstep session's Zenoh lease (5 s: a process frozen longer
looks dead to its peers, who then fly on without its drones). Nobody leaves the barrier or the
swarm, every vehicle flies to the end, and the flight's telemetry is ``swarm simulate``'s of the
same scenario, sample for sample."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from agent_harness import up_with_a_frozen_agent, write_scenario
from sitl_client import ENV, ROOT, swarm_command

from gcs.report.tlog import vehicle_samples

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]
SQUARE = [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0), (4.0, 3.0, 0.0)]
FROZEN_S = 4.0


def test_a_frozen_agent_process_slows_lockstep_without_changing_the_flight(
    tmp_path: Path,
) -> None:
    scenario = write_scenario(
        tmp_path / "hover.toml",
        SQUARE,
        centre=(2.0, 1.5, -2.0),
        spread=(2.0, 1.5, 0.0),
        duration_s=16.0,
        settle_s=8.0,
    )
    done = subprocess.run(
        swarm_command(
            "simulate",
            str(scenario),
            "--report",
            str(tmp_path / "sim"),
            "--no-plots",
            "--no-recording",
        ),
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    report = tmp_path / "up"
    code, text = up_with_a_frozen_agent(
        scenario,
        report,
        *("--agents-per-process", "2"),
        swarm_id="stall",
        drones=4,
        freeze=3,
        frozen_s=FROZEN_S,
        flying_after_s=6.0,
    )
    assert code == 0, text[-3000:]
    logs = report / "logs"
    sim_log = (logs / "sim.log").read_text()
    assert "left the barrier" not in sim_log, sim_log[-2000:]
    for log in logs.glob("agent-*.log"):
        assert "left the swarm" not in log.read_text(), log.read_text()[-2000:]
    sim, up = (
        vehicle_samples(tmp_path / "sim" / "flight.tlog"),
        vehicle_samples(report / "flight.tlog"),
    )
    both = sim.keys() & up.keys()
    assert len(both) >= 0.95 * 2 * 4 * 16 * 25, len(both)
    differ = sorted(k for k in both if sim[k] != up[k])
    assert not differ, (len(differ), differ[:3])
    end = max(t for _, _, t in both)
    heights = [-v[2] for (m, _, t), v in up.items() if m == "LOCAL_POSITION_NED" and t == end]
    assert len(heights) == 4 and min(heights) > 1.0, heights
