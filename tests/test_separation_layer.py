"""The separation layer wired into the agents' core (drone_agent/separation_layer.py): what each
agent hears of its neighbours rides on the consensus messages, and the core's command is filtered
only when a neighbour comes too close; far apart, the command is the controller's, bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np

from drone_agent.agent_core import AgentConfig, BatchAgentCore
from drone_agent.config import agent_config
from drone_agent.separation_layer import SeparationConfig
from protocols.scenario import parse_scenario

SCENARIO = parse_scenario(
    {
        "version": 1,
        "name": "pair",
        "duration_s": 10.0,
        "drones": [{"position_ned_m": [0.0, 0.0, 0.0]}, {"position_ned_m": [4.0, 0.0, 0.0]}],
        "trajectory": {
            "waypoints": [
                {"t_s": 0.0, "centre_ned_m": [2.0, 0.0, -3.0], "spread_m": [2.0, 0.0, 0.0]}
            ]
        },
        "consensus": {"warmup_s": 0.0},
    },
    "test",
)


def _fly(config: AgentConfig, gap_m: float, closing_m_s: float) -> list[object]:
    """Two agents ``gap_m`` apart on the north axis closing at ``closing_m_s``: the outputs of
    the second tick (the first in which each has heard the other)."""
    core = BatchAgentCore((0, 1), config)
    plan = SCENARIO.trajectory()
    x = np.array([[2.0 - gap_m / 2, 0.0, -3.0], [2.0 + gap_m / 2, 0.0, -3.0]])
    v = np.array([[closing_m_s / 2, 0.0, 0.0], [-closing_m_s / 2, 0.0, 0.0]])
    members = frozenset({0, 1})
    first = core.tick((0, 1), 0, 1.0, x, v, [plan] * 2, [[], []], [members] * 2)
    m0, m1 = first[0].message, first[1].message
    assert m0.position_ned_m is not None and m0.velocity_ned_m_s is not None  # for neighbours
    return core.tick((0, 1), 1, 1.02, x, v, [plan] * 2, [[m1], [m0]], [members] * 2)


def test_far_apart_the_command_is_the_controllers() -> None:
    on = agent_config(SCENARIO)
    off = dataclasses.replace(on, separation=None)
    for a, b in zip(_fly(on, 4.0, 0.0), _fly(off, 4.0, 0.0), strict=True):
        assert not a.separating  # type: ignore[attr-defined]
        assert a.setpoint == b.setpoint  # type: ignore[attr-defined]


def test_closing_neighbours_are_pushed_apart_by_both_agents() -> None:
    on = agent_config(SCENARIO)
    assert on.separation == SeparationConfig()  # the scenario's defaults: 1 m, fence, ceiling
    off = dataclasses.replace(on, separation=None)
    filtered, raw = _fly(on, 1.6, 3.0), _fly(off, 1.6, 3.0)
    assert all(out.separating for out in filtered)  # type: ignore[attr-defined]
    # drone 0 (south) brakes: its pitch goes nose-up (more positive) than the controller's;
    # drone 1 (north) the mirror image
    p0, r0 = filtered[0].setpoint.pitch_rad, raw[0].setpoint.pitch_rad  # type: ignore[attr-defined]
    p1, r1 = filtered[1].setpoint.pitch_rad, raw[1].setpoint.pitch_rad  # type: ignore[attr-defined]
    assert p0 > r0 + 0.05 and p1 < r1 - 0.05, (p0, r0, p1, r1)
    assert abs(p0 + p1) < 1e-6  # symmetric pair, symmetric answers
