"""The separation layer wired into the agents' core (drone_agent/core/separation/layer.py): what
each agent hears of its neighbours rides on the consensus messages, and the core's command is
filtered only when a neighbour comes too close; far apart, the command is the controller's, bit for
bit."""

from __future__ import annotations

import dataclasses

import numpy as np

from drone_agent.core.agent_core import AgentConfig, BatchAgentCore
from drone_agent.core.config import agent_config
from drone_agent.core.separation.layer import SeparationConfig
from protocols.scenario.scenario_file import parse_scenario

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


def _random_swarm(rng: np.random.Generator, k: int, spread_m: float) -> tuple[np.ndarray, ...]:
    x = rng.uniform(-spread_m, spread_m, (k, 3))
    x[:, 2] = rng.uniform(-4.0, -0.3, k)  # some near the floor, some below its margin
    v = rng.normal(0.0, 0.7, (k, 3))
    u = rng.normal(0.0, 2.0, (k, 3))
    return x, v, u


def test_the_pre_check_clears_only_agents_the_filter_leaves_alone() -> None:
    """Exact: wherever ``nobody_near`` is sure, the filter returns the command unchanged (bit for
    bit) and not active; and it is sure of most agents of a spread-out swarm."""
    from drone_agent.core.separation.filter import filter_accelerations, nobody_near

    params = SeparationConfig().params(agent_config(SCENARIO).limits)
    rng = np.random.default_rng(3)
    cleared = unsure = 0
    for trial in range(300):
        k = 12
        x, v, u = _random_swarm(rng, k, spread_m=(2.0, 10.0, 30.0)[trial % 3])
        common = rng.normal(0.0, 1.0, 3)
        owner, nb = np.nonzero(~np.eye(k, dtype=bool))
        nb_pos = x[nb] + rng.normal(0.0, 0.05, (nb.shape[0], 3))  # each agent's own view
        nb_vel = v[nb]
        sure, closest = nobody_near(x, v, u, owner, nb_pos, nb_vel, params, common)
        pos, vel = nb_pos.reshape(k, k - 1, 3), nb_vel.reshape(k, k - 1, 3)
        full = filter_accelerations(x, v, u, pos, vel, np.ones((k, k - 1), dtype=bool), params,
                                    common_accel_ned_m_s2=common)  # fmt: skip
        assert not full.active[sure].any()
        assert (full.accel_ned_m_s2[sure] == u[sure]).all()
        np.testing.assert_allclose(closest, full.closest_m, rtol=1e-12)
        cleared += int(sure.sum())
        unsure += int((~sure & ~full.active).sum())
    assert cleared > 1200 and unsure > 100, (cleared, unsure)  # not vacuous; conservative


def test_the_layer_gives_the_filter_of_every_agent() -> None:
    """The layer (pre-check, then the filter on the agents it is not sure of) against the
    filter on every agent, from the same heard neighbours, close and far."""
    from drone_agent.core.separation.filter import filter_accelerations
    from drone_agent.core.separation.layer import SeparationLayer
    from protocols.wire.consensus_message import ConsensusMessage

    config = agent_config(SCENARIO)
    rng = np.random.default_rng(5)
    for trial in range(40):
        k = 10
        layer = SeparationLayer(SeparationConfig(), config.limits, 0.02, 5)
        x, v, u = _random_swarm(rng, k, spread_m=(1.5, 8.0)[trial % 2])
        msgs = [
            ConsensusMessage(
                j, 9, np.zeros(18), {}, frozenset(), 0, position_ned_m=x[j], velocity_ned_m_s=v[j]
            )
            for j in range(k)
        ]
        heard = [[m for m in msgs if m.sender != i and rng.random() < 0.8] for i in range(k)]
        common = np.tile(rng.normal(0.0, 1.0, 3), (k, 1))
        got = layer.filter(range(k), 10, x, v, u, heard, common_accel_ned_m_s2=common)
        pairs = layer.table.query(range(k), 10)
        pos, vel, mask, _ = pairs.padded()
        want = filter_accelerations(x, v, u, pos, vel, mask, layer.params,
                                    common_accel_ned_m_s2=common)  # fmt: skip
        np.testing.assert_array_equal(got.active, want.active)
        np.testing.assert_allclose(got.accel_ned_m_s2, want.accel_ned_m_s2, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got.n_constraints, want.n_constraints)
