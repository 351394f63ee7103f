"""A radio with limits, beyond its range: what each directed link does to the consensus messages
that reach it. The one model of ``swarm simulate``'s radio (gcs/reference/network.py) and of the
agents' link layer in ``swarm up`` (drone_agent/process/link_faults.py, on the receive side), so
that both runners lose and delay the same messages. Pure: no clock, no sockets; time is the
control round, randomness each link's own seeded stream.

A message on the link sender -> receiver, sent at round ``r`` from ``d`` metres away, meets in
turn (the scenario's ``[radio]``, protocols/scenario/scenario_file.py ``RadioConfig``):

1. **The link's queue** (``bandwidth_bytes_s`` > 0): the message takes ``bytes / bandwidth`` s
   of the link, after the ones before it. If more than ``queue_messages`` are waiting ahead of it
   it is dropped (tail drop); else it leaves when the link is free again, whole control ticks
   beyond the first (the radio's one-tick delay covers a message sent within its tick) added to
   its delay.
2. **Bursts** (Gilbert–Elliott): the link's two-state Markov chain steps once per message: from
   good to bad with ``p_gb``, from bad to good with ``p_bg = 1 / burst_length`` (spells of
   geometric length, ``burst_length`` messages on average); ``p_gb = p_bg f / (1 - f)`` puts
   ``burst_fraction`` ``f`` of the messages in the bad state, where each is lost with
   ``burst_loss``. Every link starts good.
3. **Distance** (``loss_half_m`` > 0): log-distance path loss ``PL(d) = PL(d50) + 10 n
   log10(d / d50)`` with a fading term ``X ~ N(0, fading_db^2)`` drawn per message; the message
   is lost when the path loss exceeds the link budget, which ``d50 = loss_half_m`` sets (half are
   lost there): ``P(lost | d) = Phi(10 n log10(d / d50) / fading_db)``.
4. **Latency and jitter**: ``latency_s`` plus ``jitter_s`` times an Exp(1) draw, in whole control
   ticks (rounded), added to its delay.

Each message that reaches the radio takes :data:`DRAWS` uniform draws from its link's stream,
whichever stages are on (so a link's draws depend only on its own messages, in round order).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from protocols.scenario.scenario_file import RadioConfig
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import consensus_body_bytes

#: Uniform draws a message takes from its link's stream: the burst chain's step, the loss in a
#: burst, the fading, the jitter.
DRAWS = 4

#: The stream tag of the radio's draws in link_faults' ``PairRandom`` (the link faults' losses
#: draw from the untagged streams: the two never share a draw).
RADIO_STREAM = 1

#: What :meth:`RadioLinks.admit` returns for a lost message.
LOST = -1


def message_bytes(message: ConsensusMessage) -> int:
    """The bytes a consensus message takes on the link: its fields as on the wire (the swarm
    header, which depends on the swarm's name, left out)."""
    return consensus_body_bytes(len(message.heard), len(message.edge_sums))


def distance_m(a: Sequence[float], b: Sequence[float]) -> float:
    """The distance between two points, summed in axis order (the same to the last bit in both
    runners)."""
    dx, dy, dz = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


def loss_at(config: RadioConfig, d_m: float) -> float:
    """The probability that a message sent ``d_m`` metres is lost to distance (stage 3)."""
    if config.loss_half_m <= 0.0 or d_m <= 0.0:
        return 0.0
    margin_db = 10.0 * config.path_loss_exponent * math.log10(d_m / config.loss_half_m)
    return 0.5 * (1.0 + math.erf(margin_db / config.fading_db / math.sqrt(2.0)))


@dataclass
class RadioCounts:
    """Messages the radio dropped, by why: a full queue, a burst, distance."""

    queue: int = 0
    burst: int = 0
    distance: int = 0


class RadioLinks:
    """The state of directed links (their queues and burst chains) and the one rule of the module
    doc. ``draw(sender, receiver)``: the link's next uniform draw, from a stream that is the
    radio's alone (drone_agent/process/link_faults.py ``radio_links`` gives it the link's
    :data:`RADIO_STREAM` of the scenario's seed)."""

    def __init__(self, config: RadioConfig, dt_s: float, draw: Callable[[int, int], float]) -> None:
        self.config = config
        self.dt_s = dt_s
        self.draw = draw
        self.counts = RadioCounts()
        c = config
        self._queue = c.bandwidth_bytes_s > 0.0
        self._bursts = c.burst_fraction > 0.0 and c.burst_loss > 0.0
        self._p_bg = 1.0 / c.burst_length
        self._p_gb = self._p_bg * c.burst_fraction / (1.0 - c.burst_fraction)
        self._free_at: dict[tuple[int, int], float] = {}  # when the link is free (rounds)
        self._bad: dict[tuple[int, int], bool] = {}  # the burst chain's state

    def admit(self, sender: int, receiver: int, round_: int, size_bytes: int, d_m: float) -> int:
        """The message's fate on its link: :data:`LOST`, or the control ticks it is delayed by
        beyond the radio's one (queue, latency and jitter)."""
        c, link, draw = self.config, (sender, receiver), self.draw
        u_chain, u_burst, u_fade, u_jitter = (draw(sender, receiver) for _ in range(DRAWS))
        ticks = 0
        if self._queue:
            service = size_bytes / c.bandwidth_bytes_s / self.dt_s  # rounds
            start = max(float(round_), self._free_at.get(link, -math.inf))
            if start - round_ > c.queue_messages * service:
                self.counts.queue += 1
                return LOST
            free = self._free_at[link] = start + service
            ticks = max(0, math.ceil(free - round_) - 1)
        if self._bursts:
            bad = self._bad.get(link, False)
            bad = (u_chain >= self._p_bg) if bad else (u_chain < self._p_gb)
            self._bad[link] = bad
            if bad and u_burst < c.burst_loss:
                self.counts.burst += 1
                return LOST
        if c.loss_half_m > 0.0 and u_fade < loss_at(c, d_m):
            self.counts.distance += 1
            return LOST
        if c.latency_s > 0.0 or c.jitter_s > 0.0:
            late_s = c.latency_s + c.jitter_s * -math.log1p(-u_jitter)
            ticks += round(late_s / self.dt_s)
        return ticks
