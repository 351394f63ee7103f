"""The messaging interface of one agent, :class:`AgentTransport`, over the byte-level
:class:`~protocols.bus.interface.Bus` (a Zenoh session or its in-memory twin).

An :class:`AgentTransport` is what one agent uses; ``drone_agent.process.transport_link.AgentLink``
implements it over any Bus, and ``drone_agent.process.link_faults.FaultyTransport`` wraps any
transport with link faults. Several agents hosted in one process share one Bus and one consensus hub
(``transport_link.ConsensusHub``); each still holds its own keys, token, cells, radio range and
counters. Its siblings' messages reach it from the hub directly (the hub publishes to other
processes only), as they would come back through the bus; remote agents' through the bus.

Threading: the bus fills subscription inboxes on its threads; they are drained, decoded and
filtered on the agent's own thread.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Protocol, Self

from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import ConsensusPacket
from protocols.wire.plan import PlanMessage
from protocols.wire.status import AgentStatus, StatusCounters

Position = Sequence[float] | FloatArray
"""A position (3,) NED, m."""

#: the order of what :meth:`AgentTransport.receive` returns: a packet's (sender, round)
BY_SENDER_ROUND = operator.attrgetter("message.sender", "message.round")


@dataclass(frozen=True)
class SwarmMessageCounters:
    """Cumulative counts of the swarm messages (consensus, plans) of one agent's transport.

    ``rx``: consensus payloads received from other drones (before any check). Dropped:
    ``malformed`` (any WireError but the two below, or a key/sender mismatch), ``wrong_swarm``,
    ``wrong_version``, ``out_of_range`` (sender farther than the communication range), ``faults``
    (cut, loss or partition of a link-fault wrapper), ``radio`` (the radio's limits: a full
    queue, a burst, distance; drone_agent/process/radio.py). ``delivered`` were returned by
    ``receive``.
    ``tx``: consensus messages published. ``plans_rejected``: plan payloads that did not decode.
    """

    rx: int = 0
    malformed: int = 0
    wrong_swarm: int = 0
    wrong_version: int = 0
    out_of_range: int = 0
    faults: int = 0
    radio: int = 0
    delivered: int = 0
    tx: int = 0
    plans_rejected: int = 0

    def status(self, rejected_setpoints: int = 0) -> StatusCounters:
        """The counters an agent reports in its status. Its ``rx`` counts what the radio
        delivered: messages from beyond the communication range, dropped by a link fault (cut,
        loss, partition) or by the radio's limits never reached the drone, so the ground
        station's link quality (received over expected) shows them."""
        return StatusCounters(
            rx=self.rx - self.out_of_range - self.faults - self.radio,
            rx_dropped_malformed=self.malformed,
            rx_dropped_wrong_swarm=self.wrong_swarm,
            rx_dropped_wrong_version=self.wrong_version,
            tx=self.tx,
            rejected_setpoints=rejected_setpoints,
            rx_lost_radio=self.radio,
        )


class AgentTransport(Protocol):
    """What one agent uses to talk to the swarm. One per hosted agent; not thread-safe (call it
    from the agent's own thread). Use as a context manager or call :meth:`close`."""

    @property
    def drone(self) -> int:
        """This agent's drone index."""
        ...

    def publish_consensus(self, message: ConsensusMessage, position_ned_m: Position) -> None:
        """Send this round's message from ``position_ned_m`` (3,) NED, m. The position also
        sets the agent's spatial cell (re-subscribing when it changes) and the point the radio
        range is measured from."""
        ...

    def receive(self) -> list[ConsensusPacket]:
        """The consensus messages from other drones within range that arrived since the last
        call, decoded and sorted by (sender, round). Bad payloads are dropped and counted."""
        ...

    def withheld(self) -> dict[int, int]:
        """Per sender, the newest round of its messages that reached this agent's radio since
        the last call but were not delivered (link faults dropped them, or hold them back for
        a later round); empty without faults. Not for the estimator: for the realtime
        neighbour wait, which need not wait for a message that came and was lost."""
        ...

    def members(self) -> frozenset[int]:
        """The drones whose agents are alive (liveliness tokens), this one included."""
        ...

    def publish_status(self, status: AgentStatus) -> None:
        """Publish this agent's status (``status.drone`` must be this agent)."""
        ...

    def plan(self) -> PlanMessage | None:
        """The newest plan received (largest seq), fetched on joining and kept up to date by a
        subscription; None until one arrived."""
        ...

    def counters(self) -> SwarmMessageCounters:
        """A snapshot of the message counters."""
        ...

    def close(self) -> None:
        """Leave the swarm: drop the liveliness token (everyone removes this drone at once),
        undeclare subscriptions and publishers. Idempotent."""
        ...

    def __enter__(self) -> Self: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None: ...
