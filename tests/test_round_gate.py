"""Lockstep rounds: the round-done marker on the wire (golden bytes), and the gate an agent passes
before each tick: it waits for every live drone's marker of the previous round, drops a dead one
(liveliness gone) at once, gives a never-seen one a grace, and waits at its first tick until every
drone listens. On the in-memory bus; the wall time is passed in."""

from __future__ import annotations

import struct
from collections.abc import Iterator

import numpy as np
import pytest

from drone_agent.process.link_faults import PairRandom
from drone_agent.process.round_gate import RoundBook, RoundGate
from drone_agent.process.transport_link import AgentLink, ConsensusHub, LinkSettings
from protocols.bus.memory import MemoryBus
from protocols.wire.format import Kind, Reason, WireError
from protocols.wire.round_done import RoundDone, decode_round_done, encode_round_done

SID = "demo"
ROUND_HEX = "5101050464656d6fdc0500000300000003000700"
SETTINGS = LinkSettings("gate", comm_range_m=10.0)


def test_round_done_golden_bytes_and_layout() -> None:
    done = RoundDone(1500, (0, 3, 7))
    by_hand = (
        bytes([0x51, 1, Kind.ROUND_DONE, 4]) + b"demo" + struct.pack("<IH3H", 1500, 3, 0, 3, 7)
    )
    assert encode_round_done(done, SID).hex() == ROUND_HEX == by_hand.hex()
    assert decode_round_done(bytes.fromhex(ROUND_HEX), SID) == done


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (bytes.fromhex(ROUND_HEX)[:-1], Reason.TRUNCATED),
        (bytes.fromhex(ROUND_HEX) + b"\0", Reason.TRAILING),
        (bytes.fromhex(ROUND_HEX.replace("03000700", "07000300")), Reason.BAD_VALUE),
        (bytes.fromhex(ROUND_HEX)[:12], Reason.TRUNCATED),
    ],
)
def test_bad_markers_are_refused_with_their_reason(data: bytes, reason: Reason) -> None:
    with pytest.raises(WireError) as err:
        decode_round_done(data, SID)
    assert err.value.reason == reason
    with pytest.raises(WireError) as other:
        decode_round_done(bytes.fromhex(ROUND_HEX), "other")
    assert other.value.reason == Reason.WRONG_SWARM


class Swarm:
    """Three agent processes (one drone each) on one memory bus, with their books and gates."""

    def __init__(self, n: int = 3) -> None:
        self.bus = MemoryBus()
        self.sessions = [self.bus.session() for _ in range(n)]
        self.books = [RoundBook(s, SETTINGS.keys(), [i]) for i, s in enumerate(self.sessions)]
        self.gates = [RoundGate(i, range(n), b, join_grace_s=1.0) for i, b in enumerate(self.books)]
        self.links: list[AgentLink | None] = [None] * n

    def join(self, i: int) -> None:
        self.links[i] = AgentLink(self.sessions[i], i, (float(i), 0.0, 0.0), SETTINGS)

    def finish(self, i: int, round_: int) -> None:
        self.books[i].finished(i, round_)
        self.books[i].flush()

    def close(self) -> None:
        for link in self.links:
            if link is not None:
                link.close()
        for book in self.books:
            book.close()


@pytest.fixture
def swarm() -> Iterator[Swarm]:
    s = Swarm()
    yield s
    s.close()


def test_first_tick_waits_until_every_drone_listens(swarm: Swarm) -> None:
    swarm.join(0)
    swarm.join(1)
    assert not swarm.gates[0].ready(0, 0.0)  # drone 2 is not listening yet
    swarm.join(2)
    assert swarm.gates[0].ready(0, 0.1)
    assert swarm.gates[0].members() == frozenset({0, 1, 2})


def test_a_tick_waits_for_every_live_drones_previous_round(swarm: Swarm) -> None:
    for i in range(3):
        swarm.join(i)
    for i in range(3):
        assert swarm.gates[i].ready(0, 0.0)
    swarm.finish(0, 0)
    swarm.finish(1, 0)
    assert not swarm.gates[0].ready(1, 0.1)
    assert not swarm.gates[0].ready(1, 100.0)  # alive: waited for as long as it lives
    swarm.finish(2, 0)
    assert swarm.gates[0].ready(1, 100.1)
    # a marker means "this round and every earlier one"
    swarm.finish(1, 5)
    swarm.finish(2, 5)
    assert swarm.gates[0].ready(6, 100.2)


def test_a_dead_drone_is_dropped_at_once_never_waited_for(swarm: Swarm) -> None:
    for i in range(3):
        swarm.join(i)
    for i in range(3):
        assert swarm.gates[i].ready(0, 0.0)
    for i in range(3):
        swarm.finish(i, 0)
    link = swarm.links[2]
    assert link is not None
    link.close()  # drone 2's agent dies: its token goes
    gate = swarm.gates[0]
    swarm.finish(1, 1)
    assert not gate.ready(2, 10.0)  # a marker it sent just before may still be in flight
    assert gate.ready(2, 10.0 + gate.dead_grace_s)
    assert gate.members() == frozenset({0, 1})
    swarm.finish(1, 2)
    assert gate.ready(3, 10.1)  # gone for good: never waited for again


def test_a_drone_never_seen_gets_the_join_grace_then_is_dropped() -> None:
    s = Swarm()
    try:
        s.join(0)
        s.join(1)
        gate = RoundGate(0, range(3), s.books[0], join_grace_s=1.0, first_grace_s=2.0)
        assert not gate.ready(0, 0.0)
        assert gate.ready(0, 2.0)  # drone 2 never came: the first tick goes on without it
        assert gate.members() == frozenset({0, 1})
        s.finish(1, 0)
        assert gate.ready(1, 2.1)
    finally:
        s.close()


def test_a_lost_marker_is_made_up_for_by_a_repeat(swarm: Swarm) -> None:
    for i in range(3):
        swarm.join(i)
    for i in range(3):
        assert swarm.gates[i].ready(0, 0.0)
    swarm.books[1].finished(1, 0)  # finished but its marker never went out (lost)
    swarm.books[1]._to_send.clear()
    swarm.finish(2, 0)
    assert not swarm.gates[0].ready(1, 0.1)
    swarm.books[1].repeat()
    assert swarm.gates[0].ready(1, 0.2)


def test_each_link_draws_its_own_seeded_losses_whatever_the_order() -> None:
    a, b = PairRandom(7), PairRandom(7)
    first = [a(1, 2).random() for _ in range(5)]
    b(3, 2).random()  # another link's traffic in between changes nothing
    b(2, 1).random()
    assert [b(1, 2).random() for _ in range(5)] == first
    assert a(2, 1).random() != PairRandom(7)(1, 2).random()
    assert np.isclose(PairRandom(8)(1, 2).random(), first[0]) is np.False_


def test_a_restarted_agent_waits_for_nobody_at_its_first_tick(swarm: Swarm) -> None:
    """Markers of earlier rounds flow: the swarm runs, its drones that are gone are not awaited."""
    swarm.join(0)
    swarm.join(1)
    swarm.finish(0, 40)
    swarm.finish(1, 40)
    late = RoundGate(2, range(3), swarm.books[2], first_grace_s=60.0)
    swarm.join(2)
    assert late.ready(41, 0.0)


def test_a_gate_held_up_by_a_live_drone_waits_for_it_and_still_drops_one_that_died() -> None:
    """A host re-asks its waiting gates at every marker that comes in: a gate held up by a live
    drone stays shut until that drone's marker is in, whatever else arrives; a drone that dies
    meanwhile is dropped after its grace as when nobody was waited for."""
    s = Swarm(4)
    try:
        for i in range(4):
            s.join(i)
        for i in range(4):
            assert s.gates[i].ready(0, 0.0)
            s.finish(i, 0)
        gate = s.gates[0]
        s.finish(1, 1)
        assert not gate.ready(2, 10.0)  # drones 2 and 3 alive, round 1 not done
        s.finish(3, 1)
        assert not gate.ready(2, 10.01)  # drone 2 still holds it up
        link = s.links[3]
        assert link is not None
        link.close()  # drone 3 dies (its round 1 was done)
        s.finish(1, 2)
        assert not gate.ready(2, 10.02)
        s.finish(2, 1)
        assert gate.ready(2, 10.03)
        assert gate.members() == frozenset({0, 1, 2, 3})  # 3 finished round 1 before it died
        s.finish(2, 2)
        assert not gate.ready(3, 11.0)  # 3 is gone: its grace (a marker may be in flight)
        assert gate.ready(3, 11.0 + gate.dead_grace_s)
        assert gate.members() == frozenset({0, 1, 2})
    finally:
        s.close()


def test_gates_of_one_process_share_the_book_and_skip_only_their_own_drone() -> None:
    """Two agents hosted by one process (one book, two gates) and one elsewhere: each gate waits
    for the others' rounds, never for its own drone's marker (which comes back later), although
    the book works out the roster's lowest rounds once for both."""
    bus = MemoryBus()
    here, there = bus.session(), bus.session()
    book, far = RoundBook(here, SETTINGS.keys(), [0, 1]), RoundBook(there, SETTINGS.keys(), [2])
    gates = [RoundGate(i, range(3), book) for i in (0, 1)]
    links = [AgentLink(s, i, (float(i), 0.0, 0.0), SETTINGS) for s, i in ((here, 0), (here, 1),
                                                                          (there, 2))]  # fmt: skip
    try:
        assert all(g.ready(0, 0.0) for g in gates)
        far.finished(2, 0)
        far.flush()
        book.finished(0, 0)
        book.flush()  # drone 0 done; drone 1 not yet
        assert not gates[0].ready(1, 0.1)  # waits for drone 1
        assert gates[1].ready(1, 0.1)  # drone 1's own round is not waited for
        assert gates[0]._shared is gates[1]._shared  # one roster tuple in the book
        book.finished(1, 0)
        book.flush()
        assert gates[0].ready(1, 0.2)
        assert not gates[1].ready(2, 0.3) and not gates[0].ready(2, 0.3)
    finally:
        for link in links:
            link.close()
        book.close()
        far.close()


def test_the_gates_and_links_of_one_process_hand_out_one_view_object() -> None:
    """Agents of one process with the same roster (lockstep) or the same drones alive
    (realtime) hand the batched core one frozenset: its mask per view object is built once, not
    once per agent and tick (drone_agent/process/membership_views.py)."""
    bus = MemoryBus()
    session = bus.session()
    book = RoundBook(session, SETTINGS.keys(), [0, 1, 2])
    gates = [RoundGate(i, range(3), book) for i in range(3)]
    assert gates[0].members() == frozenset({0, 1, 2})
    assert gates[0].members() is gates[1].members() is gates[2].members()
    hub = ConsensusHub(session, SETTINGS)
    links = [AgentLink(session, i, (0.0, 0.0, 0.0), SETTINGS, hub) for i in range(3)]
    try:
        views = [link.members() for link in links]
        assert views[0] == frozenset({0, 1, 2}), views
        assert views[0] is views[1] is views[2] and links[0].members() is views[0]
        links[2].close()
        after = [link.members() for link in links[:2]]
        assert after[0] == frozenset({0, 1}) and after[0] is after[1]
    finally:
        for link in links[:2]:
            link.close()
