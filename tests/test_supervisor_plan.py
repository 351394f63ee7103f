"""What ``swarm up`` hands out: agent groups per process and the run file the ground station
reads for the dropout drill and operators read for the endpoint."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from gcs.supervisor import Child, RunPlan, agent_groups, agent_ranges


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
