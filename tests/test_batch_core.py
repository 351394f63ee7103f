"""The batched agent core gives every agent the same outputs whichever agents share its call.

Twelve agents on a sparse radio graph (a chain with a hub: degrees 1 to 5), through the in-memory
radio with loss, extra delay, a one-way cut and a partition; two of them drop out (the others'
membership views shrink, each agent's view at its own time); two plans are in use, and one plan is
decoded twice (equal content, distinct objects). The same flight is run with all agents in one
batch, in batches of 3, one by one (K = 1 cores), and in one batch whose rows are called in a
different random grouping every tick (as a host calls the agents due together); every output
agrees to 1e-9 over 300 ticks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from drone_agent.core.agent_core import AgentConfig, AgentCore, AgentOutput, BatchAgentCore
from drone_agent.core.consensus.scalar import ConsensusParams
from drone_agent.core.cooperative import CooperativeGains
from drone_agent.core.thrust_attitude import ThrustLimits
from gcs.reference.network import InProcessNetwork
from protocols.model.frames import FloatArray
from protocols.model.trajectory import DescriptorTrajectory, Waypoint

N = 12
TICKS = 300
DT_S = 0.02
T0_S = 2.0  # warm-up ends at 3 s: setpoints from tick 50
DROP_OUTS = {150: 5, 220: 9}


def _config(degree_normalised: bool) -> AgentConfig:
    return AgentConfig(
        consensus=ConsensusParams(
            rho=4.0 if degree_normalised else 1.0,
            degree_normalised=degree_normalised,
            dt_s=DT_S,
            heard_timeout_ticks=5,
            history_ticks=25,
        ),
        gains=CooperativeGains(),
        limits=ThrustLimits(mass_kg=1.5, max_thrust_n=2.0 * 1.5 * 9.81),
    )


def _plan(shift_m: float, yaw: float) -> DescriptorTrajectory:
    a0 = np.array([shift_m, 0.0, -1.0, 0.0, 0.0, yaw, 6.0, 3.0, 0.0])
    a1 = np.array([shift_m + 2.0, 1.0, -3.0, 0.02, -0.01, yaw + 0.3, 8.0, 4.0, 0.3])
    return DescriptorTrajectory.from_waypoints([Waypoint(0.0, a0), Waypoint(10.0, a1)])


def _graph() -> FloatArray:
    """A chain 0 - 1 - ... - 11 with a hub (6) and two cross links: degrees 1 to 5."""
    adjacency = np.zeros((N, N), dtype=bool)
    for a, b in [(i, i + 1) for i in range(N - 1)] + [(6, 0), (6, 2), (6, 9), (3, 8), (4, 8)]:
        adjacency[a, b] = adjacency[b, a] = True
    return adjacency


def _positions() -> FloatArray:
    """A bent line, 2 m apart."""
    rng = np.random.default_rng(4)
    x = np.stack([2.0 * np.arange(N), 1.5 * np.sin(np.arange(N)), np.zeros(N)], axis=1)
    return x + rng.normal(scale=0.3, size=(N, 3))


@dataclass
class _Flight:
    """One run: a grouping of the agents into batched calls, and what each agent produced."""

    grouping: str
    outputs: dict[tuple[int, int], AgentOutput] = field(default_factory=dict)


def _fly(grouping: str, degree_normalised: bool) -> _Flight:
    config = _config(degree_normalised)
    plan_a, plan_b = _plan(0.0, 0.1), _plan(1.0, -0.2)
    plan_a_again = _plan(0.0, 0.1)  # equal content, another object (decoded by another agent)
    plans = [plan_a if i % 3 == 0 else plan_a_again if i % 3 == 1 else plan_b for i in range(N)]
    home = _positions()
    phase = np.random.default_rng(2).uniform(0.0, 2.0 * np.pi, size=(N, 3))
    rng = np.random.default_rng(11)
    net = InProcessNetwork(N, 1.0, rng)
    adjacency = _graph()
    degrees = adjacency.sum(axis=1)
    assert degrees.min() == 1 and degrees.max() >= 4  # heterogeneous, sparse
    net.conditions.set_loss(0.1)
    groups: list[list[int]]
    if grouping == "one batch" or grouping == "random groups":
        cores = {
            i: AgentCore(i, config, batch)
            for batch in [BatchAgentCore(range(N), config)]
            for i in range(N)
        }
    elif grouping == "batches of 3":
        cores = {}
        for lo in range(0, N, 3):
            batch = BatchAgentCore(range(lo, lo + 3), config)
            cores.update({i: AgentCore(i, config, batch) for i in range(lo, lo + 3)})
    else:
        cores = {i: AgentCore(i, config) for i in range(N)}
    live = set(range(N))
    split = np.random.default_rng(5)
    flight = _Flight(grouping)
    for k in range(TICKS):
        _faults(net, k)
        if k in DROP_OUTS:
            live.discard(DROP_OUTS[k])
        # each agent's liveliness view: agent i learns of a drop-out 5 (i % 3) ticks late
        views = {
            lag: frozenset(live | {d for t, d in DROP_OUTS.items() if t <= k < t + 5 * lag})
            for lag in range(3)
        }
        t_s = T0_S + k * DT_S
        pos = home + 0.2 * np.sin(0.7 * t_s + phase) + np.array([0.0, 0.0, -1.0])
        vel = 0.14 * np.cos(0.7 * t_s + phase)
        inboxes = net.receive(k)
        order = sorted(live)
        if grouping == "random groups":
            shuffled = list(split.permutation(order))
            cuts = sorted(split.choice(np.arange(1, len(order)), size=3, replace=False))
            groups = [list(g) for g in np.split(np.array(shuffled, dtype=int), cuts)]
        else:
            by_batch: dict[int, list[int]] = {}
            for i in order:
                by_batch.setdefault(id(cores[i].batch), []).append(i)
            groups = list(by_batch.values())
        for group in groups:
            group = [int(i) for i in group]
            batch = cores[group[0]].batch
            outs = batch.tick(
                [cores[i].row for i in group],
                k,
                t_s,
                pos[group],
                vel[group],
                [plans[i] for i in group],
                [inboxes[i] for i in group],
                [views[i % 3] for i in group],
            )
            flight.outputs.update({(k, i): out for i, out in zip(group, outs, strict=True)})
        messages = [flight.outputs[(k, i)].message for i in order]
        net.send(k, messages, adjacency)
    return flight


def _faults(net: InProcessNetwork, k: int) -> None:
    c = net.conditions
    if k == 40:
        c.set_delay_ticks(1)
    if k == 70:
        c.cut_link(2, 3, one_way=True)
    if k == 100:
        c.set_delay_ticks(2, (6, 7))
    if k == 130:
        c.restore_link(2, 3, one_way=True)
        c.set_delay_ticks(0)
    if k == 180:
        c.set_partition([[0, 1, 2, 3, 4, 5], [6, 7, 8, 9, 10, 11]])
    if k == 200:
        c.set_partition(None)


def _close(a: Any, b: Any, what: str) -> None:
    np.testing.assert_allclose(
        np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol=0, atol=1e-9, err_msg=what
    )


def _same(a: AgentOutput, b: AgentOutput, where: str) -> None:
    _close(a.message.gamma, b.message.gamma, f"{where}: message gamma")
    assert sorted(a.message.edge_sums) == sorted(b.message.edge_sums), where
    for j in a.message.edge_sums:
        _close(a.message.edge_sums[j], b.message.edge_sums[j], f"{where}: edge sum {j}")
    assert a.message.heard == b.message.heard and a.message.degree == b.message.degree, where
    _close(a.estimate, b.estimate, f"{where}: estimate")
    assert a.active_neighbours == b.active_neighbours, where
    _close(a.disagreement, b.disagreement, f"{where}: disagreement")
    assert a.ready_to_fly == b.ready_to_fly, where
    assert (a.setpoint is None) == (b.setpoint is None), where
    if a.setpoint is not None and b.setpoint is not None:
        sa, sb = a.setpoint, b.setpoint
        values_a = (sa.roll_rad, sa.pitch_rad, sa.yaw_rad, sa.thrust_normalised)
        values_b = (sb.roll_rad, sb.pitch_rad, sb.yaw_rad, sb.thrust_normalised)
        _close(values_a, values_b, f"{where}: setpoint")
        assert sa.limited == sb.limited, where


@pytest.mark.parametrize("degree_normalised", [False, True], ids=["fixed-gain", "degree-norm"])
def test_batched_and_one_by_one_agree(degree_normalised: bool) -> None:
    reference = _fly("one by one", degree_normalised)
    flights = [_fly(g, degree_normalised) for g in ("one batch", "batches of 3", "random groups")]
    assert len(reference.outputs) == sum(
        len([i for i in range(N) if not any(k >= t and i == d for t, d in DROP_OUTS.items())])
        for k in range(TICKS)
    )
    for flight in flights:
        assert flight.outputs.keys() == reference.outputs.keys(), flight.grouping
        for key, expected in reference.outputs.items():
            _same(
                flight.outputs[key], expected, f"{flight.grouping}, tick {key[0]}, agent {key[1]}"
            )
    # the flight did exercise what it claims: setpoints, integrating edges, and the faults
    late = [reference.outputs[(TICKS - 1, i)] for i in range(N) if i not in DROP_OUTS.values()]
    assert all(o.setpoint is not None for o in late)
    degrees = {len(o.active_neighbours) for o in late}
    assert min(degrees) >= 1 and max(degrees) >= 3
    after_drop = reference.outputs[(TICKS - 1, 4)].message.edge_sums
    assert 5 not in after_drop  # the dead partner's edge was discarded


def test_edge_sums_is_a_read_only_mapping_that_goes_on_the_wire() -> None:
    """The batched core's messages carry their running sums as EdgeSums (rows of one array):
    it behaves as the dict it replaces, and encodes to the same bytes."""
    from protocols.wire.consensus_message import ConsensusMessage, EdgeSums
    from protocols.wire.format import decode_consensus, encode_consensus

    rows = np.arange(3 * 18, dtype=float).reshape(3, 18)
    sums = EdgeSums(np.array([2, 5, 9]), rows)
    plain = {2: rows[0], 5: rows[1], 9: rows[2]}
    assert list(sums) == [2, 5, 9] and len(sums) == 3 and 5 in sums and 4 not in sums
    assert sums.get(4) is None and np.array_equal(sums[9], rows[2])
    with pytest.raises(KeyError):
        sums[4]

    def message(edge_sums: Any) -> ConsensusMessage:
        return ConsensusMessage(3, 7, np.ones(18), edge_sums, frozenset({2, 5}), 2)

    wire = encode_consensus(message(sums), (1.0, 2.0, -3.0), "swarm")
    assert wire == encode_consensus(message(plain), (1.0, 2.0, -3.0), "swarm")
    decoded = decode_consensus(wire, "swarm").message
    assert sorted(decoded.edge_sums) == [2, 5, 9]
    assert np.array_equal(decoded.edge_sums[5], rows[1])


def test_a_sender_id_beyond_any_swarm_is_dropped_not_grown_into() -> None:
    """A forged message from sender 65535 would size every edge array by it: it is dropped and
    counted, and the estimator carries on."""
    from drone_agent.core.consensus.scalar import ConsensusEstimator, ConsensusParams
    from protocols.wire.consensus_message import ConsensusMessage

    est = ConsensusEstimator(0, ConsensusParams())
    forged = ConsensusMessage(65535, 0, np.ones(18), {}, frozenset({0}), 1)
    est.step(0, np.zeros(18), [])
    out = est.step(1, np.zeros(18), [forged])
    assert out.active_neighbours == () and np.all(np.isfinite(out.estimate))
    assert est.dropped_messages == 1
