"""Link faults on the receive side: cuts, one-way cuts, loss, delay, partitions; and the estimator
over the in-memory bus seeing what the faulty radio delivers."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from drone_agent.core.consensus.scalar import ConsensusEstimator, ConsensusParams
from drone_agent.process.link_faults import FaultyTransport, LinkFaults, PairRandom, delay_ticks
from drone_agent.process.transport import AgentTransport
from drone_agent.process.transport_link import AgentLink, LinkSettings
from protocols.bus.memory import MemoryBus
from protocols.wire.consensus_message import ConsensusMessage

pytestmark = pytest.mark.timeout(60)

SETTINGS = LinkSettings("faults", comm_range_m=10.0)


class Swarm:
    """N agents in range of each other on one memory bus, each behind its own fault wrapper
    (all sharing one LinkFaults, as the agents of one process would), on a shared round clock."""

    def __init__(self, n: int, seed: int = 0) -> None:
        self.round = 0
        self.faults = LinkFaults()
        self.session = MemoryBus().session()
        self.positions = [(float(i), 0.0, -1.0) for i in range(n)]
        self.links: list[AgentTransport] = [  # both sides conform to the interface
            FaultyTransport(
                AgentLink(self.session, i, self.positions[i], SETTINGS),
                self.faults,
                np.random.default_rng(seed + i),
                lambda: self.round,
            )
            for i in range(n)
        ]

    def send(self, drone: int, round_: int | None = None) -> None:
        r = self.round if round_ is None else round_
        msg = ConsensusMessage(drone, r, np.zeros(18), {}, frozenset(), 0)
        self.links[drone].publish_consensus(msg, self.positions[drone])

    def exchange(self) -> list[set[int]]:
        """Everyone sends this round's message; then the senders each agent receives."""
        for i in range(len(self.links)):
            self.send(i)
        return [{p.message.sender for p in link.receive()} for link in self.links]

    def close(self) -> None:
        for link in self.links:
            link.close()
        self.session.close()


@pytest.fixture
def swarm() -> Iterator[Swarm]:
    s = Swarm(4)
    yield s
    s.close()


def test_fault_fields_are_those_the_in_process_radio_reads() -> None:
    """LinkFaults.apply and end set these fields (directed pairs, delays in ticks), and the
    in-process radio (gcs/reference/network.py) reads them."""
    names = [f.name for f in dataclasses.fields(LinkFaults)]
    assert names == [
        "cut",
        "loss",
        "link_loss",
        "extra_delay_ticks",
        "link_delay_ticks",
        "partition",
    ]


def test_cut_both_ways_and_restore(swarm: Swarm) -> None:
    swarm.faults.cut_link(0, 1)
    heard = swarm.exchange()
    assert heard[0] == {2, 3} and heard[1] == {2, 3} and heard[2] == {0, 1, 3}
    swarm.faults.restore_link(1, 0)
    assert swarm.exchange()[0] == {1, 2, 3}


def test_one_way_cut(swarm: Swarm) -> None:
    swarm.faults.cut_link(0, 1, one_way=True)  # 0 -> 1 is cut, 1 -> 0 still works
    heard = swarm.exchange()
    assert heard[1] == {2, 3} and heard[0] == {1, 2, 3}
    assert swarm.faults.blocks(0, 1) and not swarm.faults.blocks(1, 0)
    assert swarm.links[1].counters().faults == 1


def test_partition_and_clear(swarm: Swarm) -> None:
    swarm.faults.set_partition([[0, 1], [2]])  # 3 is in no group: a group of its own
    assert swarm.exchange() == [{1}, {0}, set(), set()]
    swarm.faults.set_partition(None)
    assert swarm.exchange()[3] == {0, 1, 2}
    swarm.faults.cut_link(0, 1)
    swarm.faults.set_loss(1.0)
    swarm.faults.set_delay_ticks(3)
    swarm.faults.clear()
    assert swarm.faults == LinkFaults()
    assert swarm.exchange()[0] == {1, 2, 3}


def test_delay_holds_messages_for_whole_rounds(swarm: Swarm) -> None:
    swarm.faults.set_delay_ticks(2, link=(0, 1))  # both ways; other links undelayed
    arrivals: list[tuple[int, int]] = []
    for r in range(6):
        swarm.round = r
        if r == 0:
            swarm.send(0)
        arrivals += [(r, p.message.sender) for p in swarm.links[1].receive()]
    assert arrivals == [(2, 0)]
    assert swarm.faults.delay_for(1, 0) == 2 and swarm.faults.delay_for(2, 0) == 0
    assert delay_ticks(20.0, 0.02) == 1 and delay_ticks(60.0, 0.02) == 3


def test_delayed_messages_come_out_sorted(swarm: Swarm) -> None:
    """A message of round r on a link delayed by d ticks is released at round r + d of the
    receiver's clock (whenever it arrived), sorted by (sender, round)."""
    swarm.faults.set_delay_ticks(1)
    swarm.round = 3
    for r in (5, 3, 4):
        swarm.send(2, round_=r)
    swarm.send(1, round_=4)
    assert swarm.links[0].receive() == []
    swarm.round = 5
    got = [(p.message.sender, p.message.round) for p in swarm.links[0].receive()]
    assert got == [(1, 4), (2, 3), (2, 4)]
    swarm.round = 6
    assert [(p.message.sender, p.message.round) for p in swarm.links[0].receive()] == [(2, 5)]


def test_loss_rate_and_determinism() -> None:
    def run(seed: int) -> list[set[int]]:
        s = Swarm(3, seed)
        s.faults.set_loss(0.3)
        s.faults.set_loss(0.0, link=(1, 2))  # a per-link value overrides the global one
        out = []
        for r in range(1000):
            s.round = r
            out += s.exchange()
        lost = s.links[0].counters().faults
        assert 0.25 < lost / 2000 < 0.35  # drone 0 hears 1 and 2, 1000 rounds
        assert s.links[2].counters().faults == pytest.approx(300, abs=60)  # only from 0
        s.close()
        return out

    assert run(7) == run(7)
    assert run(7) != run(8)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda f: f.set_loss(1.5), "probability"),
        (lambda f: f.set_delay_ticks(-1), "delay"),
    ],
)
def test_bad_fault_values_are_refused(call: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call(LinkFaults())  # type: ignore[operator]


def test_estimator_over_the_faulty_bus_converges_without_bias() -> None:
    """Five agents, one link cut, 5 % loss and one tick of extra delay on every link: every
    estimate reaches the true average of the channels (ALGORITHM.md §3 rules at work)."""
    s = Swarm(5)
    s.faults.cut_link(0, 1)
    s.faults.set_loss(0.05)
    s.faults.set_delay_ticks(1)
    zeta = np.random.default_rng(1).normal(size=(5, 18))
    estimators = [ConsensusEstimator(i, ConsensusParams()) for i in range(5)]
    for r in range(300):
        s.round = r
        outs = [
            est.step(r, zeta[i], [p.message for p in link.receive()], link.members())
            for i, (est, link) in enumerate(zip(estimators, s.links, strict=True))
        ]
        for i, out in enumerate(outs):
            s.links[i].publish_consensus(out.message, s.positions[i])
    for out in outs:
        np.testing.assert_allclose(out.estimate, zeta.mean(axis=0), atol=1e-9)
        assert 0 not in out.active_neighbours or out.message.sender != 1
    assert 1 not in outs[0].active_neighbours
    s.close()


def test_what_the_faults_drop_or_hold_back_is_reported_as_withheld_not_delivered(
    swarm: Swarm,
) -> None:
    """The realtime neighbour wait must not wait for a message that came and was lost: the
    wrapper says, per sender, the newest round it dropped or holds back (the estimator never
    sees those messages)."""
    swarm.faults.cut.add((1, 0))  # 1 -> 0 cut
    swarm.faults.link_delay_ticks[(2, 0)] = 2  # 2 -> 0 two rounds late
    swarm.round = 5
    got = swarm.exchange()
    assert got[0] == {3}
    assert swarm.links[0].withheld() == {1: 5, 2: 5}
    assert swarm.links[0].withheld() == {}  # since the last call
    assert swarm.links[3].withheld() == {}  # nothing withheld from 3
    swarm.round = 7
    assert {p.message.sender for p in swarm.links[0].receive()} == {2}  # released: round 5 + 2
    assert swarm.links[0].withheld() == {}


def test_pair_random_draws_ahead_are_the_generators_single_draws() -> None:
    ahead, single = PairRandom(3), PairRandom(3)
    assert [ahead.draw(1, 2) for _ in range(300)] == [single(1, 2).random() for _ in range(300)]
    assert ahead.draw(2, 1) == PairRandom(3)(2, 1).random()  # each link its own stream


class _Radio:
    """A bare inner transport: hands over the packets it is given (sorted by sender and
    round, as AgentLink does)."""

    drone = 0

    def __init__(self) -> None:
        self.next: list[Any] = []

    def receive(self) -> list[Any]:
        out, self.next = self.next, []
        return out


def _reference_receive(
    state: dict, faults: LinkFaults, pair: PairRandom, now: int, packets: list
) -> list:
    """FaultyTransport.receive as first written (a message at a time, every one through the
    heap): the model the faster loop must match."""
    import heapq

    for packet in packets:
        sender, round_ = packet.message.sender, packet.message.round
        loss = faults.loss_for(sender, 0)
        if faults.blocks(sender, 0) or (loss > 0.0 and pair(sender, 0).random() < loss):
            state["dropped"] += 1
            if round_ > state["withheld"].get(sender, -1):
                state["withheld"][sender] = round_
            continue
        state["arrivals"] += 1
        release = round_ + faults.delay_for(sender, 0)
        if release > now and round_ > state["withheld"].get(sender, -1):
            state["withheld"][sender] = round_
        heapq.heappush(state["held"], (release, state["arrivals"], packet))
    out = []
    while state["held"] and state["held"][0][0] <= now:
        out.append(heapq.heappop(state["held"])[2])
    out.sort(key=lambda p: (p.message.sender, p.message.round))
    return out


def test_the_fault_loop_delivers_drops_and_withholds_as_the_reference() -> None:
    """Loss per link and on all, delays per link and on all, cuts and a partition switched
    on and off over 400 rounds of up to 12 senders: the same packets out, in the same order,
    the same withheld rounds and counters as the one-at-a-time model."""
    rng = np.random.default_rng(11)
    faults, radio = LinkFaults(), _Radio()
    ft = FaultyTransport(radio, faults, PairRandom(5), lambda: now)  # type: ignore[arg-type]
    model_faults, pair = LinkFaults(), PairRandom(5)
    state: dict = {"held": [], "withheld": {}, "dropped": 0, "arrivals": 0}
    delivered = 0
    for now in range(400):
        if now % 40 == 0:  # new faults every 40 rounds, the same on both sides
            for f in (faults, model_faults):
                f.clear()
            draws = rng.random(6)
            if draws[0] < 0.7:
                loss = float(rng.choice([0.1, 0.5, 1.0]))
                for f in (faults, model_faults):
                    f.set_loss(loss)
            if draws[1] < 0.5:
                link = (int(rng.integers(1, 13)), 0)
                for f in (faults, model_faults):
                    f.set_loss(0.0, link=link)
            if draws[2] < 0.4:
                ticks = int(rng.integers(1, 4))
                for f in (faults, model_faults):
                    f.set_delay_ticks(ticks)
            if draws[3] < 0.4:
                link, ticks = (int(rng.integers(1, 13)), 0), int(rng.integers(0, 5))
                for f in (faults, model_faults):
                    f.set_delay_ticks(ticks, link=link)
            if draws[4] < 0.3:
                cut = int(rng.integers(1, 13))
                for f in (faults, model_faults):
                    f.cut_link(cut, 0, one_way=True)
            if draws[5] < 0.2:
                for f in (faults, model_faults):
                    f.set_partition([[0, 1, 2, 3], [4, 5, 6]])
        senders = rng.choice(np.arange(1, 13), size=int(rng.integers(0, 13)), replace=False)
        packets = [
            SimpleNamespace(message=SimpleNamespace(sender=int(s), round=now - int(d)))
            for s, d in zip(senders, rng.integers(0, 3, size=len(senders)), strict=True)
        ]
        radio.next = sorted(packets, key=lambda p: (p.message.sender, p.message.round))
        got = ft.receive()
        want = _reference_receive(state, model_faults, pair, now, packets)
        assert got == want  # the same objects, in the same order
        delivered += len(want)
        assert ft.withheld() == state["withheld"]
        state["withheld"] = {}
    assert ft._dropped == state["dropped"] and ft._delivered == delivered


def test_the_wrappers_counters_are_the_inner_ones_with_its_drops_and_deliveries() -> None:
    """Every field of the inner counters is carried (a field added to SwarmMessageCounters later
    must not come out as 0)."""
    from drone_agent.process.transport import SwarmMessageCounters

    inner = SwarmMessageCounters(*range(1, len(dataclasses.fields(SwarmMessageCounters)) + 1))
    radio = _Radio()
    radio.counters = lambda: inner  # type: ignore[attr-defined]
    faults = LinkFaults()
    faults.set_loss(1.0)
    ft = FaultyTransport(radio, faults, PairRandom(0), lambda: 0)  # type: ignore[arg-type]
    radio.next = [SimpleNamespace(message=SimpleNamespace(sender=1, round=0))]
    assert ft.receive() == []
    want = dataclasses.replace(inner, faults=inner.faults + 1, delivered=0)
    assert ft.counters() == want
