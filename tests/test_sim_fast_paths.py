"""The shortcuts of ``swarm simulate``'s hot loop give what the plain code gives."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drone_agent.core.agent_core import AgentOutput, Setpoint
from drone_agent.core.consensus.estimator import BatchConsensus
from drone_agent.core.consensus.scalar import ConsensusParams
from drone_agent.core.flight_phase import VehicleView
from drone_agent.core.inboxes import Inboxes
from drone_agent.core.moments import SwarmMoments
from drone_agent.core.neighbours import NeighbourTable
from drone_agent.process.link_faults import PairRandom
from gcs.reference.network import DRAW_BLOCK, InProcessNetwork
from protocols.mavlink.conventions import MAX_VEHICLES
from protocols.runtime.fast_dataclass import frozen_factory
from protocols.wire.consensus_message import ConsensusMessage


def _message() -> ConsensusMessage:
    return ConsensusMessage(
        sender=3,
        round=17,
        gamma=np.arange(18.0),
        edge_sums={1: np.ones(18)},
        heard=frozenset({1, 2}),
        degree=2,
        position_ned_m=np.zeros(3),
        incarnation=4,
    )


def test_frozen_factory_makes_the_dataclass_instance() -> None:
    msg = _message()
    values = [getattr(msg, f.name) for f in dataclasses.fields(ConsensusMessage)]
    made = frozen_factory(ConsensusMessage)(*values)
    assert type(made) is ConsensusMessage
    assert made == msg and vars(made) == vars(msg)
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.round = 5  # type: ignore[misc]
    assert frozen_factory(VehicleView)(True, True, False, False, 2.0, None) == VehicleView(
        True, True, False, False, 2.0
    )
    setpoint = frozen_factory(Setpoint)(0.1, -0.2, 0.3, 0.5, False)
    assert setpoint == Setpoint(0.1, -0.2, 0.3, 0.5, False)
    with pytest.raises(TypeError):
        frozen_factory(Setpoint)(0.1, -0.2, 0.3)  # every field is given
    moments = frozen_factory(SwarmMoments)(np.zeros(3), np.ones(3), np.eye(3), np.zeros((3, 3)))
    out = frozen_factory(AgentOutput)(msg, np.zeros(9), moments, setpoint, (1, 2), True, 0.1,
                                      None, False)  # fmt: skip
    assert out.moments is moments and out.setpoint == setpoint and out.separating is False


def test_outgoing_messages_with_levels_are_the_step_messages_with_their_level() -> None:
    """Made with their settled levels at once (``swarm simulate``), a step's messages are the
    messages :meth:`BatchConsensus.step_messages` makes with that level put on each."""
    ids = (0, 1, 2)
    batches = [BatchConsensus(ids, ConsensusParams()) for _ in range(2)]
    rng = np.random.default_rng(5)
    inboxes: list[list[ConsensusMessage]] = [[], [], []]
    for round_ in range(4):
        zeta = rng.normal(size=(3, 18))
        motion = (rng.normal(size=(3, 3)), rng.normal(size=(3, 3)))
        _, plain, _, _ = batches[0].step_messages(ids, round_, zeta, inboxes, [None] * 3, motion)
        _, outgoing, _, _ = batches[1].step_outgoing(ids, round_, zeta, inboxes, [None] * 3,
                                                     motion)  # fmt: skip
        levels = [round_, 2 * round_, 7]
        made = outgoing.messages(levels)
        assert outgoing.round == round_
        for m, p, level in zip(made, plain, levels, strict=True):
            assert m.ready_hops == level and p.ready_hops == 0
            assert vars(m).keys() == vars(p).keys()
            for name, value in vars(dataclasses.replace(p, ready_hops=level)).items():
                mine = getattr(m, name)
                if isinstance(value, np.ndarray):
                    assert np.array_equal(mine, value)
                elif name in ("edge_sums", "edge_incarnations"):
                    assert np.array_equal(mine.ids, value.ids)
                else:
                    assert mine == value
        inboxes = [[made[j] for j in ids if j != i] for i in ids]


def test_radio_range_is_the_norm_below_the_range() -> None:
    """The radio's compiled range test picks the pairs ``np.linalg.norm`` puts below the
    range, also for pairs a rounding away from it."""
    rng = np.random.default_rng(3)
    net = InProcessNetwork(40, 6.0, PairRandom(1))
    for scale in (1.0, 4.0, 20.0):
        pos = rng.normal(scale=scale, size=(40, 3))
        pos[1] = pos[0] + np.array([6.0, 0.0, 0.0])  # on the range
        pos[2] = pos[0] + np.array([np.nextafter(6.0, 0.0), 0.0, 0.0])  # just inside
        pos[3] = pos[0] + np.array([3.6, 4.8, 0.0])  # 6 m, rounded
        d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1)
        want = d < 6.0
        np.fill_diagonal(want, False)
        assert np.array_equal(net.in_range(pos), want)


def test_radio_link_draws_are_the_links_own_draws_in_order() -> None:
    """Drawn ahead in blocks, each link's loss draws are those of one ``random()`` per message
    on its own generator (as every agent of ``swarm up`` draws them), also for a link drawn
    twice in one call and across block boundaries."""
    net = InProcessNetwork(6, 10.0, PairRandom(11))
    reference = PairRandom(11)
    rng = np.random.default_rng(2)
    for _ in range(3 * DRAW_BLOCK):
        m = int(rng.integers(1, 10))
        senders, receivers = rng.integers(0, 6, m), rng.integers(0, 6, m)
        got = net._link_draws(senders, receivers)
        want = [reference(int(a), int(b)).random() for a, b in zip(senders, receivers, strict=True)]
        assert np.array_equal(got, want)


def test_inboxes_read_once_file_what_the_lists_file() -> None:
    """Read once for the whole batch (:class:`Inboxes`), a tick's inboxes give the consensus
    step and the neighbour table the same state and outputs as the same lists read by each:
    shared messages, a duplicate, a message from a later round (it waits: the next tick reads
    the lists again), own messages and a sender beyond any swarm (counted, dropped)."""
    ids = (0, 1, 2, 3)
    params = ConsensusParams()
    plain, shared = BatchConsensus(ids, params), BatchConsensus(ids, params)
    tables = NeighbourTable(0.02), NeighbourTable(0.02)
    rng = np.random.default_rng(9)
    sent: list[ConsensusMessage] = []
    for round_ in range(6):
        boxes = [[m for m in sent if m.sender != i and rng.random() < 0.8] for i in ids]
        if round_ == 2:
            boxes[1].append(boxes[1][0])  # a duplicate
            ahead = dataclasses.replace(sent[2], round=round_ + 1)  # from a later round
            boxes[0].append(ahead)
            boxes[3].append(ahead)
            boxes[2].append(sent[2])  # its own
        if round_ == 4:
            boxes[0].append(dataclasses.replace(sent[1], sender=MAX_VEHICLES + 5))
        zeta = rng.normal(size=(4, 18))
        motion = (rng.normal(size=(4, 3)), rng.normal(size=(4, 3)))
        got = [
            batch.step_messages(ids, round_, zeta, inboxes, [None] * 4, motion)
            for batch, inboxes in ((plain, [list(b) for b in boxes]), (shared, Inboxes(boxes)))
        ]
        assert np.array_equal(got[0][0], got[1][0])  # the estimates
        assert got[0][2] == got[1][2] and np.array_equal(got[0][3], got[1][3])
        for table, inboxes in zip(tables, ([list(b) for b in boxes], Inboxes(boxes)), strict=True):
            table.hear(ids, round_, inboxes)
        a, b = (table.query(ids, round_) for table in tables)
        assert np.array_equal(a.ids, b.ids) and np.array_equal(a.owner, b.owner)
        assert np.array_equal(a.position_ned_m, b.position_ned_m)
        sent = got[1][1]
    assert plain.dropped_messages == shared.dropped_messages
    assert sum(plain.dropped_messages) > 0
    for name in ("_q_own", "_edge", "_latest", "_q_for_me", "_hist_gamma"):
        assert np.array_equal(getattr(plain, name), getattr(shared, name))


def test_radio_inboxes_know_their_distinct_messages() -> None:
    """The radio's inboxes of some drones are its plain inboxes of them, and the distinct
    messages it hands with them are each delivered message object once, the index of every
    value its own; with two delays in flight (one send's messages arrive in two batches) and a
    message object sent twice, as well as with one send at one delay."""
    n = 6
    nets = [InProcessNetwork(n, 100.0, PairRandom(4), 1) for _ in range(2)]
    for net in nets:
        net.conditions.loss = 0.3
        net.conditions.link_delay_ticks[(2, 4)] = 1
    rng = np.random.default_rng(1)
    pos = rng.normal(size=(n, 3))
    checked = 0
    for round_ in range(12):
        sent = [dataclasses.replace(_message(), sender=i, round=round_) for i in range(n)]
        if round_ == 5:
            sent.append(sent[0])  # one object twice
        for net in nets:
            net.send(round_, sent, net.in_range(pos))
        drones = [0, 2, 3, 5] if round_ % 2 else list(range(n))
        plain = nets[0].receive(round_ + 1)
        boxes = nets[1].receive_inboxes(round_ + 1, drones)
        assert boxes.lists == [plain[i] for i in drones]
        assert np.array_equal(nets[0].arrivals.receiver, nets[1].arrivals.receiver)
        messages, which = boxes.distinct()
        assert len({id(m) for m in messages}) == len(messages)
        assert all(messages[w] is m for w, m in zip(which.tolist(), boxes.flat, strict=True))
        assert set(which.tolist()) == set(range(len(messages)))
        checked += len(boxes.flat)
    assert checked > 100


def test_with_level_is_replace_of_the_ready_hops() -> None:
    """An agent's settled level put on its message (packing.with_level) is
    ``dataclasses.replace`` of ``ready_hops``: every other field the same object (also after a
    field is added to ConsensusMessage, which with_level must then pass on)."""
    from drone_agent.core.consensus.packing import with_level

    ids = (0, 1, 2)
    batch = BatchConsensus(ids, ConsensusParams())
    motion = (np.ones((3, 3)), np.zeros((3, 3)))
    _, out, _, _ = batch.step_outgoing(ids, 0, np.ones((3, 18)), [[], [], []], [None] * 3, motion)
    message = out.messages()[1]
    leveled = with_level(message, 4)
    expected = dataclasses.replace(message, ready_hops=4)
    assert leveled.ready_hops == 4 and type(leveled) is type(expected)
    for f in dataclasses.fields(expected):
        if f.name != "ready_hops":
            assert getattr(leveled, f.name) is getattr(expected, f.name), f.name
    assert with_level(message, message.ready_hops) is message
