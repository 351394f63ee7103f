"""One agent's :class:`~drone_agent.transport.AgentTransport` over any
:class:`~drone_agent.transport.Bus`, and the ground station's plan server.

:class:`AgentLink` publishes the agent's consensus message on the key of its spatial cell,
subscribes to the 27 cells around it (re-subscribing when it moves to another cell), applies the
radio range to what arrives (between the sender's position and its own of the message's round, as
the in-process radio does; in lockstep a message of a round it has not sent yet waits until it
has), holds the agent's liveliness token and watches everyone's, publishes its status, and keeps
the newest plan (fetched on joining, then subscribed; it also answers other agents' plan queries,
so a late joiner gets the plan even when the ground station is gone).
"""

from __future__ import annotations

import math
import threading
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from drone_agent.transport import (
    Bus,
    Closeable,
    ClosesOnExit,
    Congestion,
    Inbox,
    LinkCounters,
    Position,
    Publisher,
)
from protocols.consensus_message import ConsensusMessage
from protocols.keys import Cell, SwarmKeys, cell_size_for, neighbourhood, track_cell
from protocols.wire import (
    MAX_CONSENSUS_BYTES,
    ConsensusPacket,
    Reason,
    WireError,
    consensus_head,
    decode_consensus,
    encode_consensus,
)
from protocols.wire_plan import MAX_PLAN_BYTES, PlanMessage, decode_plan, encode_plan
from protocols.wire_status import AgentStatus, encode_status

_COUNTER_OF = {Reason.WRONG_SWARM: "wrong_swarm", Reason.BAD_VERSION: "wrong_version"}
#: Rounds of own positions kept for the range check of late messages.
_HISTORY = 64


@dataclass(frozen=True)
class LinkSettings:
    """How an agent links to its swarm.

    ``comm_range_m``: radio range (m); messages from farther senders are dropped.
    ``hysteresis_fraction``: how far past its cell's border (fraction of the range) a drone goes
    before changing cell. ``cell_size_m``: None for the smallest that covers the range; all
    agents of a swarm must use the same. ``inbox_capacity``: messages kept per subscribed cell
    between two ``receive`` calls (oldest dropped beyond). ``plan_query_timeout_s``: how long (s)
    the fetch-on-join query waits for replies; ``plan_retry_calls``: while there is no plan, ask
    again every that many ``plan()`` calls. ``serve_plan``: answer other agents' plan queries.
    """

    swarm_id: str
    comm_range_m: float
    hysteresis_fraction: float = 0.1
    cell_size_m: float | None = None
    inbox_capacity: int = 256
    max_consensus_bytes: int = MAX_CONSENSUS_BYTES
    max_plan_bytes: int = MAX_PLAN_BYTES
    plan_query_timeout_s: float = 2.0
    plan_retry_calls: int = 50
    serve_plan: bool = True
    #: lockstep: a message of a round this agent has not sent yet waits until it has, so that
    #: the range is measured between the two drones' positions of that round
    hold_early: bool = False
    #: the consensus and status publishers' congestion control: DROP (express; realtime) or
    #: QUEUED (lockstep: a process's pass of messages and statuses leaves in one send batch
    #: behind its round-done marker; express, 25 hosted agents' statuses alone took 25 batches)
    consensus_congestion: Congestion = Congestion.DROP

    def __post_init__(self) -> None:
        if not (math.isfinite(self.comm_range_m) and self.comm_range_m > 0):
            raise ValueError(f"comm_range_m must be a positive number, got {self.comm_range_m}")
        if not 0.0 <= self.hysteresis_fraction <= 1.0:
            raise ValueError(f"hysteresis_fraction must be 0..1, got {self.hysteresis_fraction}")
        smallest = cell_size_for(self.comm_range_m, self.hysteresis_m)
        if self.cell_size_m is not None and not self.cell_size_m >= smallest:
            raise ValueError(
                f"cell_size_m {self.cell_size_m} is smaller than range + 2 x hysteresis "
                f"= {smallest} m: drones in range would be missed"
            )
        if min(self.inbox_capacity, self.plan_retry_calls) < 1 or self.plan_query_timeout_s <= 0:
            raise ValueError("inbox_capacity, plan_retry_calls, plan_query_timeout_s must be > 0")
        self.keys()  # validates the swarm id

    @property
    def hysteresis_m(self) -> float:
        """Cell hysteresis (m)."""
        return self.hysteresis_fraction * self.comm_range_m

    def keys(self) -> SwarmKeys:
        """The swarm's keys with this cell size."""
        size = self.cell_size_m or cell_size_for(self.comm_range_m, self.hysteresis_m)
        return SwarmKeys(self.swarm_id, size)


def _vec3(position_ned_m: Position) -> tuple[float, float, float]:
    x, y, z = (float(p) for p in np.asarray(position_ned_m, dtype=np.float64).reshape(3))
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ValueError(f"position must be finite, got {(x, y, z)}")
    return (x, y, z)


class AgentLink(ClosesOnExit):
    """Drone ``drone``'s transport over ``bus``, starting at ``position_ned_m`` (3,) NED, m.

    Declares, in order: the liveliness watch, status publisher, plan subscription (and plan
    queryable), the consensus subscriptions and publisher of the starting cell, and finally the
    agent's liveliness token, so that peers see it alive only once it listens; then it asks for
    the current plan.
    """

    def __init__(
        self, bus: Bus, drone: int, position_ned_m: Position, settings: LinkSettings
    ) -> None:
        self._bus, self._drone, self._settings = bus, drone, settings
        self._keys = settings.keys()
        self._keys.alive(drone)  # validates the drone id
        self._position = _vec3(position_ned_m)
        self._counts: Counter[str] = Counter()
        self._alive: set[int] = set()
        self._sender_of: dict[str, int | None] = {}  # consensus key -> drone id
        self._alive_lock = threading.Lock()
        self._plan: PlanMessage | None = None
        self._plan_payload: bytes | None = None
        self._plan_inbox: deque[bytes] = deque(maxlen=64)
        self._plan_calls = 0
        self._cell: Cell | None = None
        self._inboxes: dict[Cell, Inbox] = {}
        self._pending: list[tuple[str, bytes]] = []
        #: own positions by the round they were published at (the last _HISTORY rounds)
        self._sent_at: dict[int, tuple[float, float, float]] = {}
        self._last_sent = -1
        #: messages of rounds not sent by this agent yet: (key, payload, sender, round, origin)
        self._early: list[tuple[str, bytes, int, int, tuple[float, float, float]]] = []
        self._publisher: Publisher | None = None
        self._closed = False
        self._declared: list[Closeable] = []
        try:
            self._declare(bus.watch_liveliness(self._keys.alive_all(), self._on_liveliness))
            self._status = bus.publisher(self._keys.status(drone), settings.consensus_congestion)
            self._declare(self._status)
            self._declare(bus.subscribe_callback(self._keys.plan, self._on_plan))
            if settings.serve_plan:
                self._declare(bus.serve(self._keys.plan, lambda: self._plan_payload))
            self._move(self._position)
            self._token = bus.declare_token(self._keys.alive(drone))
            self._ask_for_plan()
        except BaseException:
            self.close()
            raise

    @property
    def drone(self) -> int:
        """This agent's drone index."""
        return self._drone

    @property
    def cell(self) -> Cell | None:
        """The spatial cell the agent publishes from."""
        return self._cell

    def _declare(self, thing: Closeable) -> None:
        self._declared.append(thing)

    def _on_liveliness(self, key: str, alive: bool) -> None:
        drone = self._keys.drone_of(key)
        if drone is None:
            return
        with self._alive_lock:
            if alive:
                self._alive.add(drone)
            else:
                self._alive.discard(drone)

    def _on_plan(self, _key: str, payload: bytes) -> None:
        self._plan_inbox.append(payload)

    def _ask_for_plan(self) -> None:
        timeout_s = self._settings.plan_query_timeout_s
        self._bus.query(self._keys.plan, self._plan_inbox.append, timeout_s)

    def _move(self, position: tuple[float, float, float]) -> None:
        """Follow the drone to ``position``: change cell (subscriptions, publisher) if needed."""
        keys, settings = self._keys, self._settings
        cell = track_cell(self._cell, position, keys.cell_size_m, settings.hysteresis_m)
        if cell == self._cell:
            return
        wanted = set(neighbourhood(cell))
        for c in sorted(wanted - set(self._inboxes)):
            self._inboxes[c] = self._bus.subscribe(keys.consensus_cell(c), settings.inbox_capacity)
        for c in sorted(set(self._inboxes) - wanted):
            inbox = self._inboxes.pop(c)
            self._pending += inbox.drain()
            inbox.close()
        publisher = self._bus.publisher(
            keys.consensus(cell, self._drone), settings.consensus_congestion
        )
        old, self._publisher, self._cell = self._publisher, publisher, cell
        if old is not None:
            old.close()

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"the transport of drone {self._drone} is closed")

    def publish_consensus(self, message: ConsensusMessage, position_ned_m: Position) -> None:
        """Send this round's message from ``position_ned_m`` (3,) NED, m (see AgentTransport)."""
        self._check_open()
        if message.sender != self._drone:
            raise ValueError(f"drone {self._drone} cannot send a message of {message.sender}")
        self._position = _vec3(position_ned_m)
        self._move(self._position)
        if self._publisher is None:  # only if _move failed half-way
            raise RuntimeError(f"drone {self._drone} has no consensus publisher")
        self._publisher.put(
            encode_consensus(
                message,
                self._position,
                self._keys.swarm_id,
                max_bytes=self._settings.max_consensus_bytes,
            )
        )
        self._counts["tx"] += 1
        self._last_sent = max(self._last_sent, message.round)
        self._sent_at[message.round] = self._position
        if len(self._sent_at) > _HISTORY:
            del self._sent_at[min(self._sent_at)]

    def receive(self) -> list[ConsensusPacket]:
        """Decoded messages from drones within range since the last call (see AgentTransport);
        messages of rounds this agent has not sent yet wait for the next calls."""
        self._check_open()
        samples, self._pending = self._pending, []
        for inbox in self._inboxes.values():
            samples += inbox.drain()
        early, self._early = self._early, []
        out = [p for e in early if (p := self._in_range(*e)) is not None]
        out += [p for key, payload in samples if (p := self._accept(key, payload)) is not None]
        out.sort(key=lambda p: (p.message.sender, p.message.round))
        self._counts["delivered"] += len(out)
        return out

    def _accept(self, key: str, payload: bytes) -> ConsensusPacket | None:
        """The packet if it is well-formed, from another drone, within range; else counted."""
        sender = self._sender_of.get(key, -1)
        if sender == -1:
            if len(self._sender_of) > 4096:  # bounded: garbage may come on many keys
                self._sender_of.clear()
            sender = self._sender_of[key] = self._keys.drone_of(key)
        if sender == self._drone:
            return None  # our own message, back from our own cell
        counts, sid, limit = self._counts, self._keys.swarm_id, self._settings.max_consensus_bytes
        counts["rx"] += 1
        try:
            origin_sender, round_, origin = consensus_head(payload, sid, max_bytes=limit)
            if origin_sender != sender:
                raise WireError(Reason.BAD_VALUE, f"key {key} carries sender {origin_sender}")
        except WireError as exc:
            counts[_COUNTER_OF.get(exc.reason, "malformed")] += 1
            return None
        return self._in_range(key, payload, sender, round_, origin)

    def _in_range(
        self, key: str, payload: bytes, sender: int, round_: int, origin: tuple[float, float, float]
    ) -> ConsensusPacket | None:
        """Range check between the sender's position and ours of the message's round (ours now
        for rounds not in the history); with ``hold_early`` a message of a round we have not
        sent yet waits (at most 4 x _HISTORY of them; beyond, the oldest are dropped)."""
        if self._settings.hold_early and self._last_sent >= 0 and round_ > self._last_sent:
            self._early.append((key, payload, sender, round_, origin))
            if len(self._early) > 4 * _HISTORY:
                self._counts["malformed"] += 1
                del self._early[0]
            return None
        own = self._sent_at.get(round_, self._position)
        if math.dist(origin, own) >= self._settings.comm_range_m:
            self._counts["out_of_range"] += 1
            return None
        try:
            return decode_consensus(
                payload, self._keys.swarm_id, max_bytes=self._settings.max_consensus_bytes
            )
        except WireError as exc:
            self._counts[_COUNTER_OF.get(exc.reason, "malformed")] += 1
            return None

    def members(self) -> frozenset[int]:
        """The drones whose liveliness tokens are alive, this one included."""
        with self._alive_lock:
            return frozenset(self._alive)

    def publish_status(self, status: AgentStatus) -> None:
        """Publish this agent's status."""
        self._check_open()
        if status.drone != self._drone:
            raise ValueError(f"drone {self._drone} cannot publish the status of {status.drone}")
        self._status.put(encode_status(status, self._keys.swarm_id))

    def plan(self) -> PlanMessage | None:
        """The newest plan received (largest seq), or None (then asks again now and then, in
        case the first query went out before the plan's holders were reachable)."""
        self._plan_calls += 1
        if self._plan is None and self._plan_calls % self._settings.plan_retry_calls == 0:
            self._check_open()
            self._ask_for_plan()
        while self._plan_inbox:
            payload = self._plan_inbox.popleft()
            try:
                plan = decode_plan(
                    payload, self._keys.swarm_id, max_bytes=self._settings.max_plan_bytes
                )
            except WireError:
                self._counts["plans_rejected"] += 1
                continue
            if self._plan is None or plan.seq > self._plan.seq:
                self._plan, self._plan_payload = plan, payload
        return self._plan

    def counters(self) -> LinkCounters:
        """A snapshot of the message counters."""
        return LinkCounters(**self._counts)

    def close(self) -> None:
        """Drop the token first (peers remove this drone at once), then undeclare the rest."""
        if self._closed:
            return
        self._closed = True
        token = getattr(self, "_token", None)
        things = [token, self._publisher, *self._inboxes.values(), *reversed(self._declared)]
        for thing in things:
            if thing is not None:
                thing.close()
        self._inboxes.clear()


class PlanServer(ClosesOnExit):
    """The ground station's side of the plan: publishes each new plan reliably (BLOCK) and
    answers late joiners' queries with the current one."""

    def __init__(self, bus: Bus, swarm_id: str, *, max_plan_bytes: int = MAX_PLAN_BYTES) -> None:
        self._keys = SwarmKeys(swarm_id, 1.0)
        self._max_bytes = max_plan_bytes
        self._current: PlanMessage | None = None
        self._payload: bytes | None = None
        self._publisher = bus.publisher(self._keys.plan, Congestion.BLOCK)
        try:
            self._queryable = bus.serve(self._keys.plan, lambda: self._payload)
        except BaseException:
            self._publisher.close()
            raise

    def publish(self, plan: PlanMessage) -> None:
        """Make ``plan`` the current plan; its seq must be larger than the current one's."""
        if self._current is not None and plan.seq <= self._current.seq:
            raise ValueError(f"plan seq {plan.seq} is not after {self._current.seq}")
        payload = encode_plan(plan, self._keys.swarm_id, max_bytes=self._max_bytes)
        self._current, self._payload = plan, payload
        self._publisher.put(payload)

    def close(self) -> None:
        """Stop publishing and answering."""
        self._queryable.close()
        self._publisher.close()
