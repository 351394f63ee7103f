"""Link faults for drills, applied on the receive side of one agent's transport.

:class:`LinkFaults` says what the radio does now (cut links, also one-way; packet loss; added
delay; partitions); :class:`FaultyTransport` wraps any
:class:`~drone_agent.process.transport.AgentTransport` and applies them to what that agent receives,
so its estimator sees exactly what a real radio would deliver. Each agent applies the faults of the
links *into* it: cutting i-j both ways is agent j dropping i's messages and agent i dropping j's.

``LinkFaults`` holds directed pairs ``(sender, receiver)`` and delays in control ticks, read by the
in-process radio (gcs/reference/network.py) and the agents' transports alike. A fault command
(:mod:`protocols.faults`) acts on it through :meth:`LinkFaults.apply` and, when its
``duration_s`` is over, :meth:`LinkFaults.end`: the one rule by which the scenario fault timeline
(drone_agent/process/fault_timeline.py) and the operator's drills
(drone_agent/process/fault_drills.py) act.

Randomness and time (a clock returning the newest control round whose messages are due:
``k - 1`` while tick ``k`` is computed) are injected. With
:class:`PairRandom` each directed link draws from its own seeded generator, in the order of the
rounds of its messages, so which messages a loss drops depends on the seed alone, never on how
the arrivals of different senders interleave (lockstep runs repeat exactly). A message of round
``r`` is released at round ``r`` plus its link's delay (taken in at tick ``r + 1 + delay``, as
the in-process radio delivers it).
"""

from __future__ import annotations

import heapq
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from drone_agent.process.radio import (
    LOST,
    RADIO_STREAM,
    RadioLinks,
    distance_m,
    message_bytes,
)
from drone_agent.process.transport import (
    BY_SENDER_ROUND,
    AgentTransport,
    Position,
    SwarmMessageCounters,
)
from protocols.bus.interface import ClosesOnExit
from protocols.faults import Clear, Delay, LinkCut, LinkFault, LinkRestore, Loss, Partition
from protocols.scenario.scenario_file import RadioConfig
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import ConsensusPacket
from protocols.wire.plan import PlanMessage
from protocols.wire.status import AgentStatus

Pair = tuple[int, int]


_ROUND = operator.attrgetter("message.round")


def delay_ticks(delay_ms: float, dt_s: float) -> int:
    """A delay in ms as a whole number of control ticks of ``dt_s`` s (rounded)."""
    return round(delay_ms / 1000.0 / dt_s)


def _both(i: int, j: int, one_way: bool) -> list[Pair]:
    return [(i, j)] if one_way else [(i, j), (j, i)]


@dataclass
class LinkFaults:
    """What the radio does now. ``cut``: directed pairs (sender, receiver) that deliver nothing;
    ``loss``: loss probability on every link, ``link_loss`` per directed pair (overrides it);
    ``extra_delay_ticks`` on every link, ``link_delay_ticks`` per directed pair (overrides it);
    ``partition``: group id per drone, only drones of one group hear each other (drones not
    listed form one more group); None: no partition."""

    cut: set[Pair] = field(default_factory=set)
    loss: float = 0.0
    link_loss: dict[Pair, float] = field(default_factory=dict)
    extra_delay_ticks: int = 0
    link_delay_ticks: dict[Pair, int] = field(default_factory=dict)
    partition: dict[int, int] | None = None

    def cut_link(self, i: int, j: int, *, one_way: bool = False) -> None:
        """Cut the link i-j (both ways, or only i -> j when ``one_way``)."""
        self.cut.update(_both(i, j, one_way))

    def restore_link(self, i: int, j: int, *, one_way: bool = False) -> None:
        """Undo :meth:`cut_link`."""
        self.cut.difference_update(_both(i, j, one_way))

    def set_loss(self, probability: float, link: Pair | None = None) -> None:
        """Loss ``probability`` (0..1) on the link ``(i, j)`` both ways, or on every link."""
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"loss probability must be 0..1, got {probability}")
        if link is None:
            self.loss = probability
        else:
            self.link_loss.update(dict.fromkeys(_both(*link, False), probability))

    def end_loss(self, link: Pair | None = None) -> None:
        """Undo :meth:`set_loss`: the link ``(i, j)`` loses at the every-link rate again, both
        ways; without a link, the every-link loss is 0."""
        if link is None:
            self.loss = 0.0
        else:
            for pair in _both(*link, False):
                self.link_loss.pop(pair, None)

    def set_delay_ticks(self, ticks: int, link: Pair | None = None) -> None:
        """Added delay (control ticks >= 0) on the link ``(i, j)`` both ways, or on every link."""
        if ticks < 0:
            raise ValueError(f"delay must be >= 0 ticks, got {ticks}")
        if link is None:
            self.extra_delay_ticks = ticks
        else:
            self.link_delay_ticks.update(dict.fromkeys(_both(*link, False), ticks))

    def end_delay(self, link: Pair | None = None) -> None:
        """Undo :meth:`set_delay_ticks`: the link ``(i, j)`` is delayed as every link again, both
        ways; without a link, the every-link delay is 0."""
        if link is None:
            self.extra_delay_ticks = 0
        else:
            for pair in _both(*link, False):
                self.link_delay_ticks.pop(pair, None)

    def set_partition(self, groups: Sequence[Sequence[int]] | None) -> None:
        """Split the swarm into ``groups`` of drone ids (None or none: heal the partition)."""
        self.partition = {i: g for g, ids in enumerate(groups) for i in ids} if groups else None

    def clear(self) -> None:
        """No faults any more."""
        self.cut.clear()
        self.link_loss.clear()
        self.link_delay_ticks.clear()
        self.loss, self.extra_delay_ticks, self.partition = 0.0, 0, None

    def apply(self, command: LinkFault, dt_s: float) -> None:
        """Start ``command`` now (a delay in whole control ticks of ``dt_s`` s); its
        ``duration_s`` is the caller's to time, then :meth:`end`."""
        if isinstance(command, LinkCut):
            self.cut_link(command.i, command.j, one_way=command.one_way)
        elif isinstance(command, LinkRestore):
            self.restore_link(command.i, command.j)
        elif isinstance(command, Loss):
            self.set_loss(command.probability, command.link)
        elif isinstance(command, Delay):
            self.set_delay_ticks(delay_ticks(command.delay_ms, dt_s), command.link)
        elif isinstance(command, Partition):
            self.set_partition(command.groups)
        elif isinstance(command, Clear):
            self.clear()

    def end(self, command: LinkFault) -> None:
        """Undo ``command`` at the end of its ``duration_s``: a cut is restored the way it was
        cut, a link's loss or delay falls back to the every-link one, the every-link loss or
        delay to 0, a partition heals. Commands without a duration have nothing to undo."""
        if isinstance(command, LinkCut):
            self.restore_link(command.i, command.j, one_way=command.one_way)
        elif isinstance(command, Loss):
            self.end_loss(command.link)
        elif isinstance(command, Delay):
            self.end_delay(command.link)
        elif isinstance(command, Partition):
            self.set_partition(None)

    def idle(self) -> bool:
        """Whether no fault is set: every message passes at once."""
        return not (
            self.cut
            or self.loss
            or self.link_loss
            or self.extra_delay_ticks
            or self.link_delay_ticks
            or self.partition is not None
        )

    def blocks(self, sender: int, receiver: int) -> bool:
        """Whether a cut or the partition stops every message sender -> receiver."""
        p = self.partition
        return (sender, receiver) in self.cut or (
            p is not None and p.get(sender) != p.get(receiver)
        )

    def loss_for(self, sender: int, receiver: int) -> float:
        """Loss probability sender -> receiver."""
        return self.link_loss.get((sender, receiver), self.loss)

    def delay_for(self, sender: int, receiver: int) -> int:
        """Added delay sender -> receiver (control ticks)."""
        return self.link_delay_ticks.get((sender, receiver), self.extra_delay_ticks)


class PairRandom:
    """One generator per directed link (sender, receiver), seeded by ``(seed, sender,
    receiver)`` (``(seed, sender, receiver, stream)`` for a tagged ``stream``: another user's
    draws, drone_agent/process/radio.py): a link's draws do not depend on any other link's
    traffic, nor on which drones share a process."""

    def __init__(self, seed: int, stream: int | None = None) -> None:
        self.seed = seed
        self.stream = stream
        self._streams: dict[Pair, np.random.Generator] = {}
        self._ahead: dict[Pair, list[float]] = {}

    def __call__(self, sender: int, receiver: int) -> np.random.Generator:
        """The generator of the link sender -> receiver."""
        rng = self._streams.get((sender, receiver))
        if rng is None:
            key = (self.seed, sender, receiver)
            rng = self._streams[(sender, receiver)] = np.random.default_rng(
                key if self.stream is None else (*key, self.stream)
            )
        return rng

    def draw(self, sender: int, receiver: int) -> float:
        """The link's next ``random()`` value: the one its generator's next ``random()`` call
        would give (a generator's ``random(size)`` is its next ``size`` single draws), taken
        from :data:`DRAW_BLOCK` values drawn ahead at a time (~0.1 us instead of ~0.6 us a
        draw). The link's generator must then have no other user."""
        ahead = self._ahead.get((sender, receiver))
        if not ahead:
            ahead = self._ahead[(sender, receiver)] = (
                self(sender, receiver).random(DRAW_BLOCK).tolist()[::-1]
            )
        return ahead.pop()


#: loss draws a link of :meth:`PairRandom.draw` makes ahead at a time
DRAW_BLOCK = 64


def radio_links(config: RadioConfig, dt_s: float, seed: int) -> RadioLinks:
    """The radio's limits (drone_agent/process/radio.py) of a run seeded ``seed``: each link
    draws from its own stream, tagged :data:`~drone_agent.process.radio.RADIO_STREAM`."""
    return RadioLinks(config, dt_s, PairRandom(seed, stream=RADIO_STREAM).draw)


#: rounds of its own positions a :class:`FaultyTransport` with a radio keeps
_OWN_ROUNDS = 256


class FaultyTransport(ClosesOnExit):
    """``inner`` as seen through ``faults``: on :meth:`receive`, messages on blocked links are
    dropped, others lost with their link's probability (drawn from the link's generator of
    ``rng`` when it is a :class:`PairRandom`, else from the one generator ``rng`` in (sender,
    round) order) and held back until round ``r`` plus their link's delay (``r`` the
    message's round), in rounds of ``round_clock()`` (the newest round whose messages are
    due). With ``radio`` (drone_agent/process/radio.py: the radio's limits, the same rule as
    ``swarm simulate``'s radio), each message that no cut or partition stops first meets the
    radio, measured from the sender's position to this agent's of the message's round (as
    published), which may drop it or delay it further. Everything else is passed through. Drops
    are counted in ``counters().faults`` (link faults) and ``counters().radio`` (the radio)."""

    def __init__(
        self,
        inner: AgentTransport,
        faults: LinkFaults,
        rng: np.random.Generator | PairRandom,
        round_clock: Callable[[], int],
        radio: RadioLinks | None = None,
    ) -> None:
        self._inner, self.faults, self._clock = inner, faults, round_clock
        self._radio = radio
        #: this agent's positions as published, by round (the radio's distances)
        self._own: dict[int, tuple[float, float, float]] = {}
        self._draw: Callable[[int, int], float] = (
            rng.draw if isinstance(rng, PairRandom) else (lambda _i, _j: float(rng.random()))
        )
        self._held: list[tuple[int, int, ConsensusPacket]] = []
        #: per sender, the newest round dropped or held back since the last :meth:`withheld`
        self._withheld: dict[int, int] = {}
        self._arrivals = 0
        self._dropped = 0
        self._radio_dropped = 0
        self._delivered = 0

    @property
    def drone(self) -> int:
        """The wrapped agent's drone index."""
        return self._inner.drone

    def receive(self) -> list[ConsensusPacket]:
        """What the faulty radio delivers now, sorted by (sender, round)."""
        now, me, faults = self._clock(), self._inner.drone, self.faults
        packets = self._inner.receive()
        radio = self._radio
        if (
            radio is None
            and not self._held
            and faults.idle()
            and (not packets or max(map(_ROUND, packets)) <= now)
        ):
            self._delivered += len(packets)  # no fault, nothing held: as the loop below would
            return packets
        withheld, out, held = self._withheld, [], self._held
        draw = self._draw
        for packet in packets:
            message = packet.message
            sender, round_ = message.sender, message.round
            blocked = faults.blocks(sender, me)
            radio_ticks = 0
            if radio is not None and not blocked:
                p = packet.position_ned_m
                origin = (float(p[0]), float(p[1]), float(p[2]))
                own = self._own.get(round_) or origin  # (ours of a round not sent: no distance)
                radio_ticks = radio.admit(
                    sender, me, round_, message_bytes(message), distance_m(origin, own)
                )
                if radio_ticks == LOST:
                    self._radio_dropped += 1
                    if round_ > withheld.get(sender, -1):
                        withheld[sender] = round_
                    continue
            loss = faults.loss_for(sender, me)
            if blocked or (loss > 0.0 and draw(sender, me) < loss):
                self._dropped += 1
                if round_ > withheld.get(sender, -1):
                    withheld[sender] = round_
                continue
            self._arrivals += 1
            release = round_ + faults.delay_for(sender, me) + radio_ticks
            if release > now:
                if round_ > withheld.get(sender, -1):
                    withheld[sender] = round_
                heapq.heappush(held, (release, self._arrivals, packet))
            else:
                out.append(packet)  # due now: as pushed and popped at once
        while held and held[0][0] <= now:
            out.append(heapq.heappop(held)[2])
        out.sort(key=BY_SENDER_ROUND)
        self._delivered += len(out)
        return out

    def withheld(self) -> dict[int, int]:
        """Per sender, the newest round this wrapper dropped or held back since the last call
        (see AgentTransport.withheld)."""
        out, self._withheld = self._withheld, {}
        return out

    def counters(self) -> SwarmMessageCounters:
        """The inner counters, with this wrapper's drops and deliveries."""
        i = self._inner.counters()
        # built field by field (dataclasses.replace reads the fields anew each call: ~6 us)
        return SwarmMessageCounters(
            rx=i.rx, malformed=i.malformed, wrong_swarm=i.wrong_swarm,
            wrong_version=i.wrong_version, out_of_range=i.out_of_range,
            faults=i.faults + self._dropped, radio=i.radio + self._radio_dropped,
            delivered=self._delivered, tx=i.tx, plans_rejected=i.plans_rejected,
        )  # fmt: skip

    def publish_consensus(self, message: ConsensusMessage, position_ned_m: Position) -> None:
        """Passed through (with the radio: the position kept for the round's distances)."""
        if self._radio is not None:
            p = position_ned_m
            self._own[message.round] = (float(p[0]), float(p[1]), float(p[2]))
            if len(self._own) > _OWN_ROUNDS:
                del self._own[min(self._own)]
        self._inner.publish_consensus(message, position_ned_m)

    def members(self) -> frozenset[int]:
        """Passed through: liveliness does not travel over the faulty radio."""
        return self._inner.members()

    def publish_status(self, status: AgentStatus) -> None:
        """Passed through."""
        self._inner.publish_status(status)

    def plan(self) -> PlanMessage | None:
        """Passed through."""
        return self._inner.plan()

    def close(self) -> None:
        """Close the inner transport; held messages are forgotten."""
        self._held.clear()
        self._inner.close()
