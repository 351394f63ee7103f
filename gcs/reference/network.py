"""An in-memory radio between the agents of one process: range, one-tick delay, the radio's limits
(bandwidth, distance, bursts, latency: drone_agent/process/radio.py), link cuts (also one-way),
packet loss and extra delay, as the consensus estimator would meet them on a real network.

Pure apart from the injected random generator: no sockets, no clock; time is the round number.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from drone_agent.core.flight_phase import NO_ARRIVALS, Arrivals
from drone_agent.core.inboxes import Inboxes
from drone_agent.core.jit_math import jit
from drone_agent.process.link_faults import LinkFaults, PairRandom
from drone_agent.process.radio import LOST, RadioLinks, distance_m, message_bytes
from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage

#: Loss draws made ahead per link at a time (one ``random(size)`` call instead of one call each).
DRAW_BLOCK = 256


class InProcessNetwork:
    """Delivers each round's messages to the drones in range, ``base_delay_ticks`` (≥ 1) later."""

    def __init__(
        self,
        n_drones: int,
        range_m: float,
        rng: np.random.Generator | PairRandom,
        base_delay_ticks: int = 1,
        radio: RadioLinks | None = None,
    ) -> None:
        if base_delay_ticks < 1:
            raise ValueError("a message can arrive at the earliest one tick after it was sent")
        self.n = n_drones
        self.range_m = range_m
        self.rng = rng
        self.base_delay_ticks = base_delay_ticks
        self.conditions = LinkFaults()
        #: the radio's limits beyond its range (None: range only), drone_agent/process/radio.py
        self.radio = radio
        # arrival round -> batches of (receivers, index into messages, messages, the messages'
        # (4, len) senders, rounds, levels and take-off rounds (-1: none)), in send order
        self._in_flight: dict[int, list[_Batch]] = defaultdict(list)
        #: the messages that arrived at the last :meth:`receive`, as arrays
        self.arrivals = NO_ARRIVALS
        self.sent = 0
        self.delivered = 0
        self.lost = 0
        # per link drawing from a PairRandom: its row of draws made ahead, and the next one
        self._link_row: npt.NDArray[np.intp] | None = None  # (N, N) [sender, receiver], -1
        self._drawn = np.empty((0, DRAW_BLOCK))  # a row per link (some spare)
        self._next = np.zeros(0, dtype=np.intp)
        self._n_links = 0  # the rows in use

    def in_range(self, positions_ned_m: FloatArray) -> FloatArray:
        """Boolean matrix (N, N): pairs within radio range (no self-links): the distance
        ``sqrt(dx^2 + dy^2 + dz^2)`` (``np.linalg.norm``'s, term by term) below the range."""
        p = np.ascontiguousarray(positions_ned_m, dtype=np.float64).reshape(-1, 3)
        ok = np.zeros((p.shape[0], p.shape[0]), dtype=bool)
        _within(p, float(self.range_m), ok)
        return ok

    def send(
        self,
        round_: int,
        messages: Sequence[ConsensusMessage],
        in_range: FloatArray,
        positions_ned_m: FloatArray | None = None,
    ) -> None:
        """Put this round's messages on the air; they reach receivers in range after the delay.

        Per (message, receiver in range) in message order, receivers ascending: a cut or the
        partition stops it; else the radio's limits (:attr:`radio`, with the drones'
        ``positions_ned_m`` of this round) may drop or delay it; else it is lost with its
        link's probability (one draw per link with a
        loss: from that link's own generator when ``rng`` is a :class:`PairRandom` — as every
        agent of ``swarm up`` draws them (drone_agent.process.link_faults), so both runners lose the
        same messages —, else from ``rng`` in that order); else it arrives after the base plus its
        link's delay."""
        if not messages:
            return
        meta = np.array(
            [
                (
                    m.sender,
                    m.round,
                    m.ready_hops,
                    -1 if m.takeoff_round is None else m.takeoff_round,
                )
                for m in messages
            ],
            dtype=np.int64,
        ).T.copy()
        senders = meta[0].astype(np.intp)
        reach = np.array(in_range, dtype=bool)[senders]
        reach[np.arange(senders.shape[0]), senders] = False
        which, receivers = np.nonzero(reach)
        # each link once unless a sender has two messages on the air (its receivers distinct)
        one_each = bool(senders.min() >= 0) and int(np.bincount(senders).max()) <= 1
        self.sent += int(receivers.shape[0])
        blocked, loss, delay = self._link_matrices()
        i = senders[which]
        keep = np.ones(receivers.shape[0], dtype=bool)
        if blocked is not None:
            keep &= ~blocked[i, receivers]
        radio_ticks = None
        if self.radio is not None:
            if positions_ned_m is None:
                raise ValueError("a radio with limits needs the drones' positions")
            radio_ticks = self._radio(round_, messages, which, i, receivers, keep, positions_ned_m)
        if loss is not None:
            p = loss[i, receivers]
            draw = keep & (p > 0.0)
            if isinstance(self.rng, PairRandom):
                at = np.flatnonzero(draw)
                keep[at] = self._link_draws(i[at], receivers[at], one_each) >= p[at]
            else:
                keep[draw] = self.rng.random(int(draw.sum())) >= p[draw]
        self.lost += int(receivers.shape[0] - keep.sum())
        which, receivers, i = which[keep], receivers[keep], i[keep]
        ticks = np.full(receivers.shape[0], self.base_delay_ticks, dtype=np.int64)
        if delay is not None:
            ticks += delay[i, receivers]
        if radio_ticks is not None:
            ticks += radio_ticks[keep]
        if receivers.shape[0] == 0:
            return
        msgs = list(messages)
        if int(ticks.min()) == int(ticks.max()):  # one delay for all
            self._in_flight[round_ + int(ticks[0])].append((receivers, which, msgs, meta))
            return
        for d in np.unique(ticks).tolist():
            on = ticks == d
            self._in_flight[round_ + d].append((receivers[on], which[on], msgs, meta))

    def _radio(
        self,
        round_: int,
        messages: Sequence[ConsensusMessage],
        which: npt.NDArray[np.intp],
        senders: npt.NDArray[np.intp],
        receivers: npt.NDArray[np.intp],
        keep: npt.NDArray[np.bool_],
        positions_ned_m: FloatArray,
    ) -> npt.NDArray[np.int64]:
        """The radio's fate of each (message, receiver) still kept, in order: those it drops
        taken out of ``keep``; the ticks it delays the others by."""
        assert self.radio is not None
        admit, ticks = self.radio.admit, np.zeros(receivers.shape[0], dtype=np.int64)
        p = np.asarray(positions_ned_m, dtype=np.float64).reshape(-1, 3).tolist()
        size = [message_bytes(m) for m in messages]
        for t in np.flatnonzero(keep).tolist():
            a, b, m = int(senders[t]), int(receivers[t]), int(which[t])
            fate = admit(a, b, round_, size[m], distance_m(p[a], p[b]))
            if fate == LOST:
                keep[t] = False
            else:
                ticks[t] = fate
        return ticks

    def _link_draws(
        self,
        senders: npt.NDArray[np.intp],
        receivers: npt.NDArray[np.intp],
        distinct: bool = False,
    ) -> FloatArray:
        """The next draw of each link (senders[k], receivers[k]), in order, from its own
        generator of the :class:`PairRandom`: the values one ``random()`` call per message
        would give (a generator's ``random(size)`` is its next ``size`` single draws), taken
        from blocks of :data:`DRAW_BLOCK` drawn ahead per link; so the network must be its
        generators' only user (as in :class:`gcs.reference.flight.ReferenceFlight`).
        ``distinct``: the caller knows every link is there once (not checked again)."""
        assert isinstance(self.rng, PairRandom)
        if self._link_row is None:
            self._link_row = np.full((self.n, self.n), -1, dtype=np.intp)
        links = senders * self.n + receivers
        # a link twice (two messages of a sender): one at a time
        if not distinct and np.unique(links).shape[0] < links.shape[0]:
            return np.array([self._link_draws(senders[k : k + 1], receivers[k : k + 1])[0]
                             for k in range(links.shape[0])])  # fmt: skip
        rows = self._link_row[senders, receivers]
        new = np.flatnonzero(rows < 0)
        if new.shape[0]:
            start = self._n_links
            self._n_links = end = start + new.shape[0]
            rows[new] = self._link_row[senders[new], receivers[new]] = np.arange(start, end)
            if end > self._drawn.shape[0]:  # room for twice as many links: grown seldom
                grown = np.empty((max(end, 2 * self._drawn.shape[0]), DRAW_BLOCK))
                grown[:start] = self._drawn[:start]
                self._drawn = grown
                after = np.full(grown.shape[0], DRAW_BLOCK, dtype=np.intp)  # none drawn yet
                after[:start] = self._next[:start]
                self._next = after
        used = self._next[rows] >= DRAW_BLOCK
        if used.any():
            pair = self.rng
            for row, a, b in zip(
                rows[used].tolist(), senders[used].tolist(), receivers[used].tolist(), strict=True
            ):
                self._drawn[row] = pair(a, b).random(DRAW_BLOCK)
            self._next[rows[used]] = 0
        values: FloatArray = self._drawn[rows, self._next[rows]]
        self._next[rows] += 1
        return values

    def _link_matrices(
        self,
    ) -> tuple[
        npt.NDArray[np.bool_] | None, npt.NDArray[np.float64] | None, npt.NDArray[np.int64] | None
    ]:
        """The faults as (N, N) matrices [sender, receiver]: blocked, loss probability, added
        delay (ticks); None where no link has that fault."""
        c, n = self.conditions, self.n
        blocked = None
        if c.cut or c.partition is not None:
            blocked = np.zeros((n, n), dtype=bool)
            for a, b in c.cut:
                if 0 <= a < n and 0 <= b < n:
                    blocked[a, b] = True
            if c.partition is not None:
                group = np.array([c.partition.get(k, -1) for k in range(n)])
                blocked |= group[:, None] != group[None, :]
        loss = None
        if c.loss > 0.0 or any(v > 0.0 for v in c.link_loss.values()):
            loss = np.full((n, n), float(c.loss))
            for (a, b), v in c.link_loss.items():
                if 0 <= a < n and 0 <= b < n:
                    loss[a, b] = v
        delay = None
        if c.extra_delay_ticks or any(c.link_delay_ticks.values()):
            delay = np.full((n, n), int(c.extra_delay_ticks), dtype=np.int64)
            for (a, b), v in c.link_delay_ticks.items():
                if 0 <= a < n and 0 <= b < n:
                    delay[a, b] = v
        return blocked, loss, delay

    def receive(self, round_: int) -> list[list[ConsensusMessage]]:
        """The inboxes (one list per drone) of messages that arrive at round ``round_``, each in
        send order (batch by batch, messages in order); the same as :attr:`arrivals`."""
        return self.receive_inboxes(round_, range(self.n)).lists

    def receive_inboxes(self, round_: int, drones: Sequence[int]) -> Inboxes:
        """:meth:`receive` of round ``round_``, the inboxes of drones ``drones`` (ascending) as
        :class:`~drone_agent.core.inboxes.Inboxes`, each distinct message among them known from the
        lists they were sent in (when no message object was sent twice) instead of found again
        by the agents. :attr:`arrivals` are every drone's."""
        batches = self._in_flight.pop(round_, [])
        if not batches:
            self.arrivals = NO_ARRIVALS
            return Inboxes([[] for _ in drones], ([], _EMPTY))
        if len(batches) == 1:
            receivers, which, msgs, meta = batches[0]
        else:
            msgs, offsets = [], []
            for batch in batches:
                offsets.append(len(msgs))
                msgs += batch[2]
            receivers = np.concatenate([b[0] for b in batches])
            which = np.concatenate([b[1] + o for b, o in zip(batches, offsets, strict=True)])
            meta = np.concatenate([b[3] for b in batches], axis=1)
        order = np.argsort(receivers, kind="stable")  # by receiver, in send order
        receivers, which = receivers[order], which[order]
        self.delivered += int(receivers.shape[0])
        bounds = np.searchsorted(receivers, np.arange(self.n + 1)).tolist()
        flat = list(map(msgs.__getitem__, which.tolist()))
        lists = [flat[bounds[i] : bounds[i + 1]] for i in drones]
        self.arrivals = Arrivals(
            receivers, meta[0, which], meta[1, which], meta[2, which], meta[3, which]
        )
        if len(set(map(id, msgs))) < len(msgs):  # one object sent twice: the agents find them
            return Inboxes(lists)
        if len(drones) < self.n:  # the values of these drones' inboxes, in turn
            wanted = np.zeros(self.n, dtype=bool)
            wanted[np.asarray(drones, dtype=np.intp)] = True
            which = which[wanted[receivers]]
        sent = np.zeros(len(msgs), dtype=bool)
        sent[which] = True  # the messages delivered to them, in send order
        index = np.cumsum(sent) - 1
        return Inboxes(lists, ([msgs[k] for k in np.flatnonzero(sent).tolist()], index[which]))


@jit
def _within(positions, range_m, out):  # type: ignore[no-untyped-def]
    """:meth:`InProcessNetwork.in_range` into ``out`` (N, N) False: each pair's distance,
    ``sqrt`` of the squared differences summed in axis order, as ``np.linalg.norm`` sums them
    (the same pairs in range to the last bit); symmetric, the diagonal left False."""
    n = positions.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            dx = positions[i, 0] - positions[j, 0]
            dy = positions[i, 1] - positions[j, 1]
            dz = positions[i, 2] - positions[j, 2]
            near = np.sqrt(dx * dx + dy * dy + dz * dz) < range_m
            out[i, j] = near
            out[j, i] = near


_Batch = tuple[
    npt.NDArray[np.intp], npt.NDArray[np.intp], list[ConsensusMessage], npt.NDArray[np.int64]
]
_EMPTY = np.zeros(0, dtype=np.intp)
