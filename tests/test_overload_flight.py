"""Overload is explained, end to end (realtime ``swarm up``): one agent process is frozen for
0.7 s, longer than its vehicle's offboard timeout (0.5 s), as a machine that cannot keep up
freezes it; its vehicle fails safe, the agent takes it back when it runs again, and the ground
station's summary and metrics.json say that this drone failed safe because its agent fell behind,
with the share of ticks it answered in time."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from agent_harness import observer, write_scenario
from sitl_client import ENV, ROOT, free_port_block, free_udp_port, swarm_command

from protocols.wire_status import AgentMode

pytestmark = pytest.mark.slow
SQUARE = [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0), (4.0, 3.0, 0.0)]
FROZEN_S = 0.7


def test_a_frozen_agent_is_reported_late_and_its_failsafe_explained(tmp_path: Path) -> None:
    scenario = write_scenario(
        tmp_path / "hover.toml",
        SQUARE,
        centre=(2.0, 1.5, -2.0),
        spread=(2.0, 1.5, 0.0),
        duration_s=22.0,
        settle_s=8.0,
    )
    base, gcs_port = free_port_block(4), free_udp_port()
    report = tmp_path / "report"
    with observer(swarm_id="late") as obs:
        proc = subprocess.Popen(
            swarm_command(
                *("up", str(scenario), "--report", str(report), "--clock", "realtime"),
                *("--base-port", str(base), "--gcs-port", str(gcs_port)),
                *("--swarm-id", "late", "--zenoh-connect", obs.endpoint),
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=ENV,
            cwd=ROOT,
        )
        try:
            flying = obs.wait_until(
                lambda: len(obs.statuses()) == 4
                and all(s.mode == AgentMode.FLYING and s.t_s > 8.0
                        for s in obs.statuses().values()),
                60.0,
            )  # fmt: skip
            assert flying, obs.statuses()
            pid = json.loads((report / "logs" / "run.json").read_text())["agents"]["1"]
            os.kill(pid, signal.SIGSTOP)
            time.sleep(FROZEN_S)
            os.kill(pid, signal.SIGCONT)
            out, _ = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    text = out.decode(errors="replace")
    assert proc.returncode == 0, text[-3000:]
    metrics = json.loads((report / "metrics.json").read_text())
    timing = metrics["agent_timing"]
    assert timing["measured"] and timing["overloaded"], timing
    assert timing["per_drone"]["1"]["in_time_min"] < 0.9, timing
    assert timing["per_drone"]["1"]["worst_lag_ms"] >= 500.0, timing
    assert [(f["drone"], f["cause"]) for f in timing["failsafes"]] == [(1, "overload")], timing
    assert "drone 1 failed safe at" in text and "its agent fell behind" in text, text[-3000:]
    assert "OVERLOAD" in text
    # the agent took its vehicle back: all four fly at the end
    assert all(s.mode == AgentMode.FLYING for s in obs.statuses().values()), obs.statuses()
