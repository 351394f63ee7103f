"""One agent's :class:`~drone_agent.process.transport.AgentTransport` over any
:class:`~protocols.bus.interface.Bus`, and the ground station's plan server.

:class:`AgentLink` publishes the agent's consensus message on the key of its spatial cell,
subscribes to the 27 cells around it (re-subscribing when it moves to another cell), applies the
radio range to what arrives (between the sender's position and its own of the message's round, as
the in-process radio does; in lockstep a message of a round it has not sent yet waits until it
has), holds the agent's liveliness token and watches everyone's, publishes its status, and keeps
the newest plan (fetched on joining, then subscribed; it also answers other agents' plan queries,
so a late joiner gets the plan even when the ground station is gone).

The consensus traffic of the agents of one process goes through one :class:`ConsensusHub`
(issue 9, batched messaging): one subscription per cell any of its agents listens to, each sample
opened once (a batch in columns checked whole; a message is built once, the first time an agent
in range takes it), and, with ``batch=True``, the messages its agents publish in one pass laid
out together (:func:`wire_parts`: a batched core step's messages from its arrays) and sent as one
sample per cell (protocols/wire/batch.py, in columns; the host calls :meth:`ConsensusHub.flush`
before its round-done markers), and their statuses of the pass as one status batch
(protocols/wire/status.py, on the first drone's status key). The process's one hub (``sole``,
as ``swarm agent`` makes it) publishes to other sessions only and hands its agents' messages to
their siblings itself, as they would have come back through the bus (no Zenoh loopback, no
decoding of its own batches). Each agent still applies its own cells, radio range, early-round
hold and counters exactly as when it had its own subscriptions. An agent made without a hub gets
a private one that publishes each message (and status) at once, alone (the single-message
schemas on the wire).
"""

from __future__ import annotations

import contextlib
import math
import operator
import threading
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from drone_agent.core.consensus.packing import from_step, message_columns
from drone_agent.process.membership_views import Views
from drone_agent.process.transport import BY_SENDER_ROUND, Position, SwarmMessageCounters
from protocols.bus.interface import Bus, Closeable, ClosesOnExit, Congestion, Inbox, Publisher
from protocols.wire.batch import ConsensusBatch, encode_columns, open_batch
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import (
    MAX_CONSENSUS_BYTES,
    ConsensusPacket,
    ConsensusParts,
    Kind,
    Reason,
    WireError,
    column_parts,
    consensus_head,
    consensus_parts,
    decode_consensus,
    encode_parts,
)
from protocols.wire.keys import Cell, SwarmKeys, cell_size_for, neighbourhood, track_cell
from protocols.wire.plan import MAX_PLAN_BYTES, PlanMessage, decode_plan, encode_plan
from protocols.wire.status import AgentStatus, encode_status, encode_status_batch

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
    #: the consensus publishers' congestion control: DROP (express; realtime) or QUEUED
    #: (lockstep: a process's pass of messages leaves in one send batch behind its round-done
    #: marker). Statuses are QUEUED either way (nobody waits on them: far cheaper)
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
    if type(position_ned_m) is np.ndarray and position_ned_m.shape == (3,):
        x, y, z = (float(p) for p in position_ned_m.tolist())  # the usual case, no new array
    else:
        x, y, z = (float(p) for p in np.asarray(position_ned_m, dtype=np.float64).reshape(3))
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ValueError(f"position must be finite, got {(x, y, z)}")
    return (x, y, z)


class _Entry:
    """One consensus message as received: its sender, round and radio origin, and its payload
    (a single message's bytes, or message ``index`` of a checked batch), decoded at most once
    (by the first agent that takes it)."""

    __slots__ = ("_packet", "batch", "error", "index", "origin", "payload", "round", "sender")

    def __init__(
        self,
        sender: int,
        round_: int,
        origin: Sequence[float],
        payload: bytes,
        error: str | None = None,
        batch: ConsensusBatch | None = None,
        index: int = 0,
        packet: ConsensusPacket | None = None,
    ) -> None:
        self.sender, self.round, self.origin, self.payload = sender, round_, origin, payload
        self.error = error  # the counter to bump for a payload that did not decode
        self.batch, self.index = batch, index
        self._packet = packet  # given: a sibling's message handed over in the process

    def packet(self, swarm_id: str, max_bytes: int) -> ConsensusPacket:
        """The decoded message (WireError if it does not decode, each time asked)."""
        if self._packet is None:
            if self.batch is not None:
                self._packet = self.batch.packet(self.index, swarm_id, max_bytes)
            else:
                self._packet = decode_consensus(self.payload, swarm_id, max_bytes=max_bytes)
        return self._packet


def _rejected(sender: int, exc: WireError) -> _Entry:
    return _Entry(sender, -1, (0.0, 0.0, 0.0), b"", _COUNTER_OF.get(exc.reason, "malformed"))


#: a message staged in a hub: (sender, its parts (None: laid out at flush), message, position)
_Staged = tuple[int, ConsensusParts | None, ConsensusMessage, tuple[float, float, float]]


def wire_parts(
    messages: Sequence[ConsensusMessage],
    positions: Sequence[tuple[float, float, float]],
    swarm_id: str,
    max_bytes: int = MAX_CONSENSUS_BYTES,
) -> list[ConsensusParts]:
    """Each message laid out for the wire from its position (NED, m), the bytes of
    protocols.wire.format.consensus_parts: the messages of one batched core step together, in a few
    array operations (protocols.wire.format.column_parts on
    drone_agent.core.consensus.packing.message_columns), any other one alone. ValueError as
    consensus_parts for one that cannot be sent."""
    out: list[ConsensusParts | None] = [None] * len(messages)
    steps: dict[int, list[int]] = {}
    for i, m in enumerate(messages):
        if from_step(m):
            steps.setdefault(id(m.edge_sums.pack), []).append(i)  # type: ignore[attr-defined]
    for picked in steps.values():
        if len(picked) < 2:
            continue
        cols = message_columns([messages[i] for i in picked], [positions[i] for i in picked])
        if cols is not None:
            laid = column_parts(cols, swarm_id, max_bytes=max_bytes)
            for i, parts in zip(picked, laid, strict=True):
                out[i] = parts
    return [
        consensus_parts(messages[i], positions[i], swarm_id, max_bytes=max_bytes)
        if parts is None
        else parts
        for i, parts in enumerate(out)
    ]


class ConsensusHub(ClosesOnExit):
    """The consensus subscriptions and publications of the agents of one process (module doc).

    ``batch``: send the messages staged in a pass (:meth:`send`) as one sample per cell at
    :meth:`flush` (a cell with one message sends it alone); otherwise each is sent at once."""

    def __init__(
        self,
        bus: Bus,
        settings: LinkSettings,
        *,
        batch: bool = True,
        news: Callable[[], int] | None = None,
        sole: bool = False,
    ) -> None:
        """``news``: a counter that moves whenever the process's lockstep round book took in a
        marker (:attr:`RoundBook.version`); with it and :meth:`new_pass`, :meth:`pump` drains
        the subscriptions only when something may have come that an agent must see. ``sole``:
        this hub holds every consensus subscription of its session (the process's one hub):
        its messages reach its own agents directly, as the decoded messages would, and go out
        to other sessions only (:meth:`_hand_over`)."""
        self._bus, self._settings, self._keys = bus, settings, settings.keys()
        self._batch = batch
        self._sole = sole
        #: the process's one frozenset per membership view (its agents' members())
        self.views = Views()
        self._news = news
        # pulled ring channels (no Python on Zenoh's threads), drained by :meth:`pump`
        self._subs: dict[Cell, Inbox] = {}
        self._readers: dict[Cell, list[AgentLink]] = {}
        self._cell_of_key: dict[str, tuple[Cell, int | None] | None] = {}
        #: per cell, the messages staged in this pass: (sender, laid out, or the message and the
        #: position it goes from, to be laid out at :meth:`flush` with the pass's others)
        self._outbox: dict[Cell, list[_Staged]] = {}
        #: statuses staged in this pass: (drone, payload, the drone's status publisher)
        self._statuses: list[tuple[int, bytes, Publisher]] = []
        #: by (cell, sender): the key of each, made once
        self._publishers: dict[tuple[Cell, int], Publisher] = {}
        self._pass: int | None = None  # None: not paced by a host, drain on every pump
        self._pumped: tuple[int, int] | None = None
        self._closed = False

    def new_pass(self) -> None:
        """A host's new pass over its agents: the next :meth:`pump` drains."""
        self._pass = 0 if self._pass is None else self._pass + 1

    def follow(self, link: AgentLink, old: Cell | None, new: Cell | None) -> None:
        """``link`` now listens to the 27 cells around ``new`` (None: to none)."""
        with contextlib.suppress(RuntimeError):  # a closed session: nothing more comes
            self._drain()  # what came in so far goes to the readers of its time
        before = set(neighbourhood(old)) if old is not None else set()
        after = set(neighbourhood(new)) if new is not None else set()
        for c in sorted(after - before):
            readers = self._readers.setdefault(c, [])
            readers.append(link)
            if c not in self._subs:
                key = self._keys.consensus_cell(c)
                self._subs[c] = self._bus.subscribe(key, self._settings.inbox_capacity)
        for c in sorted(before - after):
            readers = self._readers.get(c, [])
            if link in readers:
                readers.remove(link)
            if not readers:
                self._readers.pop(c, None)
                sub = self._subs.pop(c, None)
                if sub is not None:
                    sub.close()

    def _where(self, key: str) -> tuple[Cell, int | None] | None:
        """The cell and drone of a consensus key (None for a key that is not one)."""
        got = self._cell_of_key.get(key, ())
        if got == ():
            if len(self._cell_of_key) > 4096:  # bounded: garbage may come on many keys
                self._cell_of_key.clear()
            cell = self._keys.cell_of_key(key)
            got = None if cell is None else (cell, self._keys.drone_of(key))
            self._cell_of_key[key] = got
        return got  # type: ignore[return-value]

    def pump(self) -> None:
        """Split the samples that arrived and hand their messages to the agents of their cell.
        Paced by a host (:meth:`new_pass`): once per pass, and again after the round book took
        in a marker (whose messages came before it: they must be drained before an agent that
        saw the marker takes in its inbox)."""
        if self._pass is not None:
            epoch = (self._pass, self._news() if self._news is not None else 0)
            if epoch == self._pumped:
                return
            self._pumped = epoch
        self._drain()

    def _drain(self) -> None:
        sid, limit = self._keys.swarm_id, self._settings.max_consensus_bytes
        readers_of = self._readers
        for cell, inbox in list(self._subs.items()):
            samples = inbox.drain()
            if not samples:
                continue
            readers = readers_of.get(cell)
            if not readers:
                continue
            for key, payload in samples:
                where = self._where(key)
                if where is None or where[0] != cell:
                    continue
                sender = where[1]
                entries = self._split(payload, -1 if sender is None else sender, sid, limit)
                for link in readers:
                    link._incoming.append(entries)

    def _split(self, payload: bytes, key_sender: int, sid: str, limit: int) -> list[_Entry]:
        """The messages of one sample (a single message or a batch), heads read."""
        try:
            if len(payload) > 2 and payload[2] == Kind.CONSENSUS_BATCH:
                batch = open_batch(payload, sid, max_consensus_bytes=limit)
                if batch.senders[0] != key_sender:
                    raise WireError(Reason.BAD_VALUE, f"batch of {key_sender} from another")
                return [
                    _Entry(s, r, o, b"", None, batch, k)
                    for k, (s, r, o) in enumerate(
                        zip(batch.senders, batch.rounds, batch.origins, strict=True)
                    )
                ]
            sender, round_, origin = consensus_head(payload, sid, max_bytes=limit)
            if sender != key_sender:
                raise WireError(Reason.BAD_VALUE, f"key of {key_sender} carries sender {sender}")
            return [_Entry(sender, round_, origin, payload)]
        except WireError as exc:
            return [_rejected(key_sender, exc)]

    def publish(
        self,
        cell: Cell,
        sender: int,
        message: ConsensusMessage,
        position: tuple[float, float, float],
    ) -> None:
        """Publish ``sender``'s ``message`` from ``position`` (NED, m) in ``cell``: now, or (a
        batching hub) at :meth:`flush`, laid out there with the pass's other messages
        (:func:`wire_parts`). ValueError as protocols.wire.format.consensus_parts for a message that
        cannot be sent (a batched core's message: at :meth:`flush`)."""
        sid, limit = self._keys.swarm_id, self._settings.max_consensus_bytes
        if self._batch:
            parts = None if from_step(message) else consensus_parts(message, position, sid,
                                                                    max_bytes=limit)  # fmt: skip
            self._outbox.setdefault(cell, []).append((sender, parts, message, position))
            return
        parts = consensus_parts(message, position, sid, max_bytes=limit)
        self._put(cell, sender, encode_parts(parts, sid))
        self._hand_over(cell, [(sender, parts, message, position)])

    def _hand_over(self, cell: Cell, sent: list[_Staged]) -> None:
        """A sole hub: the messages it just sent from ``cell`` (their publishers send to other
        sessions only) to its own agents that listen to that cell, as :meth:`_drain` would hand
        them over had they come back through the bus. A batched core's message with its motion
        is handed over as it is (its position and velocity, a vehicle's telemetry, are float32
        values: what the wire carries); any other as its single payload, decoded when taken."""
        readers = self._readers.get(cell)
        if not self._sole or not readers or (len(readers) == 1 and len(sent) == 1
                                             and readers[0].drone == sent[0][0]):  # fmt: skip
            return
        sid = self._keys.swarm_id
        entries = []
        for sender, parts, message, position in sent:
            if (
                from_step(message)
                and message.position_ned_m is not None
                and message.velocity_ned_m_s is not None
            ):
                packet = ConsensusPacket(message, message.position_ned_m)
                entries.append(_Entry(sender, message.round, position, b"", packet=packet))
            else:
                assert parts is not None
                entries.append(_Entry(sender, message.round, position, encode_parts(parts, sid)))
        for link in readers:
            link._incoming.append(entries)

    def send_status(self, drone: int, payload: bytes, publisher: Publisher) -> None:
        """Publish ``drone``'s status payload on its own ``publisher``: now, or at :meth:`flush`
        with the pass's other statuses in one status batch (protocols/wire/status.py)."""
        if self._batch:
            self._statuses.append((drone, payload, publisher))
        else:
            publisher.put(payload)

    def flush(self) -> None:
        """Publish the staged messages: one sample per cell, and the statuses in one sample."""
        if self._statuses:
            statuses, self._statuses = self._statuses, []
            if len(statuses) == 1:
                statuses[0][2].put(statuses[0][1])
            else:
                statuses.sort(key=lambda s: s[0])
                batch = encode_status_batch([(d, p) for d, p, _ in statuses], self._keys.swarm_id)
                statuses[0][2].put(batch)  # on the first drone's status key
        if not self._outbox:
            return
        outbox, self._outbox = self._outbox, {}
        sid, limit = self._keys.swarm_id, self._settings.max_consensus_bytes
        messages, positions = [], []
        for staged in outbox.values():
            for _, ready, message, position in staged:
                if ready is None:
                    messages.append(message)
                    positions.append(position)
        laid = iter(wire_parts(messages, positions, sid, limit))
        for cell, staged in outbox.items():
            cell_parts = [next(laid) if p is None else p for _, p, _, _ in staged]
            staged = [(s, p, m, o) for (s, _, m, o), p in zip(staged, cell_parts, strict=True)]
            if len(cell_parts) == 1:
                self._put(cell, cell_parts[0].sender, encode_parts(cell_parts[0], sid))
            else:
                cell_parts.sort(key=operator.attrgetter("sender"))
                self._put(cell, cell_parts[0].sender, encode_columns(cell_parts, sid))
            self._hand_over(cell, staged)

    def _put(self, cell: Cell, sender: int, payload: bytes) -> None:
        publisher = self._publishers.get((cell, sender))
        if publisher is None:
            key = self._keys.consensus(cell, sender)
            if self._bus.is_closed():
                raise RuntimeError("cannot publish: the session is closed")
            if len(self._publishers) >= 64:  # cells left long ago
                for old in self._publishers.values():
                    old.close()
                self._publishers.clear()
            # QUEUED in lockstep: the pass's batches leave in one send batch behind the
            # round-done marker (drone_agent/transport.Congestion)
            publisher = self._bus.publisher(
                key, self._settings.consensus_congestion, remote_only=self._sole
            )
            self._publishers[(cell, sender)] = publisher
        publisher.put(payload)

    def close(self) -> None:
        """Undeclare the subscriptions and publishers."""
        if self._closed:
            return
        self._closed = True
        for thing in [*self._publishers.values(), *self._subs.values()]:
            thing.close()
        self._publishers.clear()
        self._subs.clear()
        self._readers.clear()


class AgentLink(ClosesOnExit):
    """Drone ``drone``'s transport over ``bus``, starting at ``position_ned_m`` (3,) NED, m.

    Declares, in order: the liveliness watch, status publisher, plan subscription (and plan
    queryable), the consensus subscriptions and publisher of the starting cell, and finally the
    agent's liveliness token, so that peers see it alive only once it listens; then it asks for
    the current plan.
    """

    def __init__(
        self,
        bus: Bus,
        drone: int,
        position_ned_m: Position,
        settings: LinkSettings,
        hub: ConsensusHub | None = None,
    ) -> None:
        """``hub``: the process's consensus hub (shared by its agents); None for a private one
        that sends each message at once."""
        self._bus, self._drone, self._settings = bus, drone, settings
        self._own_hub = hub is None
        self._hub = ConsensusHub(bus, settings, batch=False) if hub is None else hub
        self._keys = settings.keys()
        self._keys.alive(drone)  # validates the drone id
        self._position = _vec3(position_ned_m)
        self._counts: Counter[str] = Counter()
        self._alive: set[int] = set()
        self._alive_lock = threading.Lock()
        #: members() as handed out, until the next liveliness change (None: to be made)
        self._members: frozenset[int] | None = None
        self._plan: PlanMessage | None = None
        self._plan_payload: bytes | None = None
        self._plan_inbox: deque[bytes] = deque(maxlen=64)
        self._plan_calls = 0
        self._cell: Cell | None = None
        #: what the hub handed over since the last receive: per sample, its messages
        self._incoming: list[list[_Entry]] = []
        #: own positions by the round they were published at (the last _HISTORY rounds)
        self._sent_at: dict[int, tuple[float, float, float]] = {}
        self._last_sent = -1
        #: messages of rounds not sent by this agent yet
        self._early: list[_Entry] = []
        self._closed = False
        self._declared: list[Closeable] = []
        try:
            self._declare(bus.watch_liveliness(self._keys.alive_all(), self._on_liveliness))
            # QUEUED (not express): far cheaper, and nobody waits on a status; in lockstep it
            # leaves with the pass's consensus messages behind the round-done marker
            self._status = bus.publisher(self._keys.status(drone), Congestion.QUEUED)
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
            self._members = None

    def _on_plan(self, _key: str, payload: bytes) -> None:
        self._plan_inbox.append(payload)

    def _ask_for_plan(self) -> None:
        timeout_s = self._settings.plan_query_timeout_s
        self._bus.query(self._keys.plan, self._plan_inbox.append, timeout_s)

    def _move(self, position: tuple[float, float, float]) -> None:
        """Follow the drone to ``position``: change cell (the hub's subscriptions) if needed."""
        keys, settings = self._keys, self._settings
        cell = track_cell(self._cell, position, keys.cell_size_m, settings.hysteresis_m)
        if cell == self._cell:
            return
        self._hub.follow(self, self._cell, cell)
        self._cell = cell

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
        if self._cell is None:  # only if _move failed half-way
            raise RuntimeError(f"drone {self._drone} has no consensus cell")
        self._hub.publish(self._cell, self._drone, message, self._position)
        self._counts["tx"] += 1
        self._last_sent = max(self._last_sent, message.round)
        self._sent_at[message.round] = self._position
        if len(self._sent_at) > _HISTORY:
            del self._sent_at[min(self._sent_at)]

    def receive(self) -> list[ConsensusPacket]:
        """Decoded messages from drones within range since the last call (see AgentTransport);
        messages of rounds this agent has not sent yet wait for the next calls."""
        self._check_open()
        self._hub.pump()
        incoming, self._incoming = self._incoming, []
        early, self._early = self._early, []
        counts, me = self._counts, self._drone
        out = [p for e in early if (p := self._in_range(e)) is not None]
        # the loop of _in_range, inlined for the usual case (a round this agent has sent)
        settings, sent_at, position = self._settings, self._sent_at, self._position
        hold = settings.hold_early and self._last_sent >= 0
        last, reach, dist = self._last_sent, settings.comm_range_m, math.dist
        rx = out_of_range = 0
        at_round, own = None, position  # our position of the round of the last entry
        for entries in incoming:
            for e in entries:
                if e.sender == me:
                    continue  # our own message, back from our own cell
                rx += 1
                if e.error is not None:
                    counts[e.error] += 1
                    continue
                round_ = e.round
                if hold and round_ > last:
                    self._in_range(e)  # held
                    continue
                if round_ != at_round:  # (a sample's messages are mostly of one round)
                    at_round, own = round_, sent_at.get(round_, position)
                if dist(e.origin, own) >= reach:
                    out_of_range += 1
                elif (p := e._packet or self._decoded(e)) is not None:
                    out.append(p)
        counts["rx"] += rx
        counts["out_of_range"] += out_of_range
        out.sort(key=BY_SENDER_ROUND)
        counts["delivered"] += len(out)
        return out

    def _in_range(self, e: _Entry) -> ConsensusPacket | None:
        """Range check between the sender's position and ours of the message's round (ours now
        for rounds not in the history); with ``hold_early`` a message of a round we have not
        sent yet waits (at most 4 x _HISTORY of them; beyond, the oldest are dropped)."""
        round_ = e.round
        if self._settings.hold_early and self._last_sent >= 0 and round_ > self._last_sent:
            self._early.append(e)
            if len(self._early) > 4 * _HISTORY:
                self._counts["malformed"] += 1
                del self._early[0]
            return None
        own = self._sent_at.get(round_, self._position)
        if math.dist(e.origin, own) >= self._settings.comm_range_m:
            self._counts["out_of_range"] += 1
            return None
        return self._decoded(e)

    def _decoded(self, e: _Entry) -> ConsensusPacket | None:
        """The entry's message, decoded once for all the agents that take it; None (counted)
        if it does not decode."""
        try:
            return e.packet(self._keys.swarm_id, self._settings.max_consensus_bytes)
        except WireError as exc:
            self._counts[_COUNTER_OF.get(exc.reason, "malformed")] += 1
            return None

    def withheld(self) -> dict[int, int]:
        """Nothing: this transport delivers what it receives in range (see AgentTransport)."""
        return {}

    def members(self) -> frozenset[int]:
        """The drones whose liveliness tokens are alive, this one included: the process's one
        object for that view (drone_agent/process/membership_views.py) while it does not change."""
        with self._alive_lock:
            if self._members is None:
                self._members = self._hub.views.of(self._alive)
            return self._members

    def publish_status(self, status: AgentStatus) -> None:
        """Publish this agent's status."""
        self._check_open()
        if status.drone != self._drone:
            raise ValueError(f"drone {self._drone} cannot publish the status of {status.drone}")
        self._hub.send_status(self._drone, encode_status(status, self._keys.swarm_id), self._status)

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

    def counters(self) -> SwarmMessageCounters:
        """A snapshot of the message counters."""
        return SwarmMessageCounters(**self._counts)

    def close(self) -> None:
        """Drop the token first (peers remove this drone at once), then undeclare the rest."""
        if self._closed:
            return
        self._closed = True
        token = getattr(self, "_token", None)
        if token is not None:
            token.close()
        if not self._bus.is_closed():
            # what this agent staged goes out now: its status publisher closes below
            self._hub.flush()
        self._hub.follow(self, self._cell, None)
        if self._own_hub:
            self._hub.close()
        for thing in reversed(self._declared):
            thing.close()


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
