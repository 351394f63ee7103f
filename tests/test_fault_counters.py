"""Link-fault drills as agents see them. What an agent's status counts as received: only what
the faulty radio delivered (``swarm drill loss`` must show in ``swarm status``: the rx counter
grows slower and the ground station's link quality falls), never messages from beyond the
radio's range. Which messages a loss drill drops: independently per drone."""

from __future__ import annotations

import numpy as np
import pytest

from drone_agent.process.link_faults import FaultyTransport, LinkFaults, PairRandom
from drone_agent.process.transport_link import AgentLink, LinkSettings
from protocols.bus.memory import MemoryBus
from protocols.wire.consensus_message import ConsensusMessage

pytestmark = pytest.mark.timeout(60)
SETTINGS = LinkSettings("counters", comm_range_m=10.0)
#: Drones 0-2 in range of each other; drone 3 in a neighbouring cell (drone 0 gets its messages
#: on the bus) but 11 m from drone 0, beyond the radio's range.
POSITIONS = [(0.0, 0.0, -1.0), (2.0, 0.0, -1.0), (4.0, 0.0, -1.0), (11.0, 0.0, -1.0)]
ROUNDS = 400


def _status_rx(faults: LinkFaults) -> tuple[int, int]:
    """Drone 0's status rx and its transport's raw rx after ROUNDS rounds of everyone sending."""
    session = MemoryBus().session()
    clock = [0]
    links = [
        FaultyTransport(
            AgentLink(session, i, p, SETTINGS), faults, np.random.default_rng(i), lambda: clock[0]
        )
        for i, p in enumerate(POSITIONS)
    ]
    try:
        for r in range(ROUNDS):
            clock[0] = r
            for i, link in enumerate(links):
                link.publish_consensus(
                    ConsensusMessage(i, r, np.zeros(18), {}, frozenset(), 0), POSITIONS[i]
                )
            for link in links:
                link.receive()
        counters = links[0].counters()
        return counters.status().rx, counters.rx
    finally:
        for link in links:
            link.close()
        session.close()


def test_status_rx_counts_what_the_radio_delivered() -> None:
    clean, raw = _status_rx(LinkFaults())
    assert raw == 3 * ROUNDS  # drone 3's messages reach drone 0's process ...
    assert clean == 2 * ROUNDS  # ... but not its radio: out of range

    lossy = LinkFaults()
    lossy.set_loss(0.5)
    got, raw = _status_rx(lossy)
    assert raw == 3 * ROUNDS  # the bus delivered everything; the drill dropped half
    assert got == pytest.approx(ROUNDS, rel=0.1)  # half of the 2 x ROUNDS in range

    cut = LinkFaults()
    cut.cut_link(0, 1)
    assert _status_rx(cut)[0] == ROUNDS  # only drone 2 is heard

    delayed = LinkFaults()
    delayed.set_delay_ticks(5)
    assert _status_rx(delayed)[0] == 2 * ROUNDS  # late, not lost: counted on arrival


def test_loss_drops_each_direction_of_a_link_independently() -> None:
    """Two drones, each in its own agent process with the default seed, loss 0.5: each
    direction loses about half, and both directions of a round together about a quarter.
    Regression: every process drew from one seed, so both ends dropped the same rounds."""
    session = MemoryBus().session()
    faults = LinkFaults()
    faults.set_loss(0.5)
    clock = [0]
    links = [
        FaultyTransport(
            AgentLink(session, i, POSITIONS[i], SETTINGS), faults, PairRandom(0), lambda: clock[0]
        )
        for i in (0, 1)
    ]
    lost = np.zeros((ROUNDS, 2), dtype=bool)
    try:
        for r in range(ROUNDS):
            clock[0] = r
            for i, link in enumerate(links):
                link.publish_consensus(
                    ConsensusMessage(i, r, np.zeros(18), {}, frozenset(), 0), POSITIONS[i]
                )
            for i, link in enumerate(links):
                lost[r, i] = not link.receive()
    finally:
        for link in links:
            link.close()
        session.close()
    assert lost.mean(axis=0) == pytest.approx([0.5, 0.5], abs=0.08)
    assert lost.all(axis=1).mean() == pytest.approx(0.25, abs=0.07)
    assert PairRandom(0)(0, 1).random() == PairRandom(0)(0, 1).random()  # repeatable for a seed
