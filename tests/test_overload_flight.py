"""Overload is explained, end to end (realtime ``swarm up``): one agent process is frozen for
0.7 s, longer than its vehicle's offboard timeout (0.5 s), as a machine that cannot keep up
freezes it; its vehicle fails safe, the agent takes it back when it runs again, and the ground
station's summary and metrics.json say that this drone failed safe because its agent fell behind,
with the share of ticks it answered in time."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from agent_harness import up_with_a_frozen_agent, write_scenario

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
    report = tmp_path / "report"
    code, text = up_with_a_frozen_agent(
        scenario,
        report,
        *("--clock", "realtime"),
        swarm_id="late",
        drones=4,
        freeze=1,
        frozen_s=FROZEN_S,
        flying_after_s=8.0,
        timeout_s=120.0,
    )
    assert code == 0, text[-3000:]
    metrics = json.loads((report / "metrics.json").read_text())
    timing = metrics["agent_timing"]
    assert timing["measured"] and timing["overloaded"], timing
    assert timing["per_drone"]["1"]["in_time_min"] < 0.9, timing
    assert timing["per_drone"]["1"]["worst_lag_ms"] >= 500.0, timing
    assert [(f["drone"], f["cause"]) for f in timing["failsafes"]] == [(1, "overload")], timing
    assert "drone 1 failed safe at" in text and "its agent fell behind" in text, text[-3000:]
    assert "OVERLOAD" in text
    # the agent took its vehicle back: all four fly at the end (up_with_a_frozen_agent checks)
