"""The messaging interfaces of an agent: the byte-level :class:`Bus` and the per-agent
:class:`AgentTransport`.

A :class:`Bus` is one Zenoh session (``drone_agent.zenoh_transport.ZenohBus``) or a session on
the in-memory twin (``drone_agent.memory_bus.MemoryBus``): publishers, pulled subscriptions,
liveliness tokens, a queryable and queries, on key expressions of ``protocols.keys``.

An :class:`AgentTransport` is what one agent uses; ``drone_agent.transport_link.AgentLink``
implements it over any Bus, and ``drone_agent.link_faults.FaultyTransport`` wraps any transport
with link faults. Several agents hosted in one process share one Bus and one consensus hub
(``transport_link.ConsensusHub``); each still holds its own keys, token, cells, radio range and
counters. Its siblings' messages reach it from the hub directly (the hub publishes to other
processes only), as they would come back through the bus; remote agents' through the bus.

Threading: subscription inboxes are filled by the bus (Zenoh's threads, or the publisher's thread
on the memory bus) and drained, decoded and filtered on the agent's own thread. Callbacks given to
a Bus must only store what they get (no decoding, no blocking).
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from types import TracebackType
from typing import Protocol, Self

from protocols.consensus_message import ConsensusMessage
from protocols.frames import FloatArray
from protocols.wire import ConsensusPacket
from protocols.wire_plan import PlanMessage
from protocols.wire_status import AgentStatus, StatusCounters

Position = Sequence[float] | FloatArray
"""A position (3,) NED, m."""

#: the order of what :meth:`AgentTransport.receive` returns: a packet's (sender, round)
BY_SENDER_ROUND = operator.attrgetter("message.sender", "message.round")


class Congestion(StrEnum):
    """What a publisher does when the network cannot keep up: DROP for periodic, loss-tolerant
    messages (consensus, status), BLOCK for messages that must arrive (plans, commands).

    DROP messages are *express* (each goes out at once, in a send batch of its own), except
    QUEUED: DROP, but the message waits in the link's current batch until a DROP message of
    the same session flushes it (or the link is idle). Lockstep consensus messages are QUEUED
    and the round-done marker that follows them is DROP: a process's whole pass leaves in one
    batch behind its marker, instead of one batch per message, which on a loaded machine filled
    Zenoh's send queue and dropped messages the marker then vouched for."""

    DROP = "drop"
    BLOCK = "block"
    QUEUED = "queued"


class ClosesOnExit:
    """Mixin for things with a ``close()``: ``with thing:`` closes it on the way out."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class Closeable(Protocol):
    """Something declared on a bus; ``close()`` undeclares it (idempotent)."""

    def close(self) -> None: ...


class Publisher(Closeable, Protocol):
    """Publishes on one key."""

    def put(self, payload: bytes) -> None: ...


class Inbox(Closeable, Protocol):
    """A pulled subscription: samples wait until drained (up to a capacity, oldest dropped)."""

    def drain(self) -> list[tuple[str, bytes]]:
        """The ``(key, payload)`` samples received since the last call, oldest first."""
        ...


class Bus(Closeable, Protocol):
    """A byte-level publish/subscribe session on key expressions (``*`` one chunk, ``**`` any)."""

    def publisher(
        self, key: str, congestion: Congestion, *, remote_only: bool = False
    ) -> Publisher:
        """Declare a publisher on the concrete key ``key``; ``remote_only``: its samples go to
        other sessions only, never to this session's own subscriptions."""
        ...

    def subscribe(self, key_expr: str, capacity: int) -> Inbox:
        """Subscribe to ``key_expr``; samples wait in the inbox (at most ``capacity``)."""
        ...

    def subscribe_callback(
        self, key_expr: str, on_sample: Callable[[str, bytes], None]
    ) -> Closeable:
        """Subscribe to ``key_expr``; ``on_sample(key, payload)`` runs on the bus's thread."""
        ...

    def declare_token(self, key: str) -> Closeable:
        """A liveliness token on ``key``: alive until closed or until this session dies."""
        ...

    def is_closed(self) -> bool:
        """Whether the session is closed (callback subscriptions then fall silent)."""
        ...

    def watch_liveliness(self, key_expr: str, on_change: Callable[[str, bool], None]) -> Closeable:
        """``on_change(key, alive)`` for every token matching ``key_expr``: first for those
        already alive (history), then on every change."""
        ...

    def serve(self, key: str, answer: Callable[[], bytes | None]) -> Closeable:
        """A queryable on ``key`` that replies with ``answer()`` (no reply when None)."""
        ...

    def query(self, key: str, on_reply: Callable[[bytes], None], timeout_s: float) -> None:
        """Ask every queryable on ``key``; ``on_reply(payload)`` for each reply, without blocking
        (replies may come after this returns, until ``timeout_s`` s)."""
        ...


@dataclass(frozen=True)
class SwarmMessageCounters:
    """Cumulative counts of the swarm messages (consensus, plans) of one agent's transport.

    ``rx``: consensus payloads received from other drones (before any check). Dropped:
    ``malformed`` (any WireError but the two below, or a key/sender mismatch), ``wrong_swarm``,
    ``wrong_version``, ``out_of_range`` (sender farther than the communication range), ``faults``
    (cut, loss or partition of a link-fault wrapper). ``delivered`` were returned by ``receive``.
    ``tx``: consensus messages published. ``plans_rejected``: plan payloads that did not decode.
    """

    rx: int = 0
    malformed: int = 0
    wrong_swarm: int = 0
    wrong_version: int = 0
    out_of_range: int = 0
    faults: int = 0
    delivered: int = 0
    tx: int = 0
    plans_rejected: int = 0

    def status(self, rejected_setpoints: int = 0) -> StatusCounters:
        """The counters an agent reports in its status. Its ``rx`` counts what the radio
        delivered: messages from beyond the communication range or dropped by a link fault (cut,
        loss, partition) never reached the drone, so the ground station's link quality (received
        over expected) shows them."""
        return StatusCounters(
            rx=self.rx - self.out_of_range - self.faults,
            rx_dropped_malformed=self.malformed,
            rx_dropped_wrong_swarm=self.wrong_swarm,
            rx_dropped_wrong_version=self.wrong_version,
            tx=self.tx,
            rejected_setpoints=rejected_setpoints,
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
