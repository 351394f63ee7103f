"""The messages of a consensus step, zero-copy: what one
:meth:`~drone_agent.core.consensus.estimator.BatchConsensus.step` puts on its messages is kept as
the arrays it made them from (:class:`Pack`), each message's edge sums and incarnations views of
them, so that a receiver in the same process (and the wire encoder) reads them from the arrays
instead of message by message; :class:`Outgoing` makes the step's messages, :func:`with_level`
puts an agent's settled level on one. Pure and I/O-free.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from drone_agent.core.moments import N_CHANNELS
from protocols.model.frames import FloatArray
from protocols.runtime.fast_dataclass import frozen_factory
from protocols.wire.consensus_message import ConsensusMessage, EdgeIncarnations, EdgeSums
from protocols.wire.format import MessageColumns

_A = TypeVar("_A", bound=np.generic)


class Pack:
    """What one :meth:`BatchConsensus.step` put on its messages, as the arrays it made them from:
    ``keys`` (E,) ``position * span + neighbour`` of every edge sum, ascending (``span`` above
    every neighbour id), ``sums`` (E, 18) and ``tags`` (E,) theirs, ``gamma`` (P, 18) and
    ``heard`` (P, span) per position, ``ids`` (E,) the neighbour of each edge sum and ``bounds``
    (P + 1,) where each position's edge sums start, the objects each position's message was
    made with (``gammas``, ``heard_sets``; ``where``, ``how_fast`` the rows of ``positions`` and
    ``velocities``). A receiver of these messages in the same process reads them from the arrays
    instead of message by message (:func:`packed_of`, :func:`packed_motion`). It refers to no
    message nor mapping of them (no reference cycle: freed as soon as its messages are)."""

    __slots__ = (
        "bounds",
        "gamma",
        "gammas",
        "heard",
        "heard_sets",
        "how_fast",
        "ids",
        "keys",
        "positions",
        "span",
        "sums",
        "tags",
        "velocities",
        "where",
    )  # fmt: skip

    def __init__(
        self,
        keys: npt.NDArray[np.intp],
        ids: npt.NDArray[np.intp],
        bounds: list[int],
        span: int,
        sums: FloatArray,
        tags: npt.NDArray[np.int64],
        gamma: FloatArray,
        heard: npt.NDArray[np.bool_],
    ) -> None:
        self.ids, self.bounds, self.span, self.sums, self.tags = ids, bounds, span, sums, tags
        self.gamma, self.heard = gamma, heard
        self.keys = keys
        self.gammas: list[FloatArray] = list(gamma)
        self.heard_sets: list[frozenset[int]] = []
        #: the senders' positions and velocities (P, 3) and the rows put on the messages (None:
        #: the messages carry none)
        self.positions: FloatArray | None = None
        self.velocities: FloatArray | None = None
        self.where: list[FloatArray | None] = []
        self.how_fast: list[FloatArray | None] = []

    def rows_of(self, per_edge: npt.NDArray[_A], at: int) -> npt.NDArray[_A]:
        """The rows of ``per_edge`` (E, ...) (``ids``, ``sums`` or ``tags``) of position ``at``."""
        b = self.bounds
        return per_edge[b[at] : b[at + 1]]


class PackedSums(EdgeSums):
    """The :class:`EdgeSums` of position ``at`` of a :class:`Pack`: the same mapping, its
    ``ids`` and ``sums`` the pack's rows of that position, sliced when first read."""

    __slots__ = ("at", "pack")

    def __init__(self, pack: Pack, at: int) -> None:  # pylint: disable=super-init-not-called
        self.pack = pack
        self.at = at
        self._index = None

    @property
    def ids(self) -> npt.NDArray[np.intp]:  # type: ignore[override]
        return self.pack.rows_of(self.pack.ids, self.at)

    @property
    def sums(self) -> FloatArray:  # type: ignore[override]
        return self.pack.rows_of(self.pack.sums, self.at)


class PackedIncarnations(EdgeIncarnations):
    """The :class:`EdgeIncarnations` of position ``at`` of a :class:`Pack` (as
    :class:`PackedSums`)."""

    __slots__ = ("at", "pack")

    def __init__(self, pack: Pack, at: int) -> None:  # pylint: disable=super-init-not-called
        self.pack = pack
        self.at = at

    @property
    def ids(self) -> npt.NDArray[np.intp]:  # type: ignore[override]
        return self.pack.rows_of(self.pack.ids, self.at)

    @property
    def tags(self) -> npt.NDArray[np.int64]:  # type: ignore[override]
        return self.pack.rows_of(self.pack.tags, self.at)


def packed_of(messages: list[ConsensusMessage]) -> tuple[Pack, npt.NDArray[np.intp]] | None:
    """The pack of ``messages`` and each one's position in it, if all come from one step of a
    :class:`BatchConsensus` with the gamma, heard-set and incarnations it made them with (a
    message rebuilt with other values of those is read message by message); else None."""
    first = messages[0].edge_sums
    if type(first) is not PackedSums:
        return None
    pack = first.pack
    gammas, heard_sets = pack.gammas, pack.heard_sets
    at: list[int] = []
    for m in messages:
        e, tags = m.edge_sums, m.edge_incarnations
        if type(e) is not PackedSums or e.pack is not pack:
            return None
        k = e.at
        if (
            m.gamma is not gammas[k]
            or m.heard is not heard_sets[k]
            or type(tags) is not PackedIncarnations
            or tags.pack is not pack
            or tags.at != k
        ):
            return None
        at.append(k)
    return pack, np.array(at, dtype=np.intp)


def packed_motion(messages: list[ConsensusMessage]) -> tuple[FloatArray, FloatArray] | None:
    """The positions and velocities (len(messages), 3) ``messages`` carry, read from the arrays
    their :class:`BatchConsensus` step made them from, if all come from one step with the
    position and velocity rows it put on them (each message then has both); else None (read
    them message by message)."""
    if not messages:
        return None
    first = messages[0].edge_sums
    if type(first) is not PackedSums or first.pack.positions is None:
        return None
    pack = first.pack
    where, how_fast = pack.where, pack.how_fast
    at: list[int] = []
    for m in messages:
        e = m.edge_sums
        if type(e) is not PackedSums or e.pack is not pack:
            return None
        k = e.at
        if m.position_ned_m is not where[k] or m.velocity_ned_m_s is not how_fast[k]:
            return None
        at.append(k)
    assert pack.positions is not None and pack.velocities is not None
    picked = np.array(at, dtype=np.intp)
    return pack.positions[picked], pack.velocities[picked]


def from_step(message: ConsensusMessage) -> bool:
    """Whether ``message`` was made by a :class:`BatchConsensus` step (its edge sums are the
    step's arrays; :func:`message_columns` may read it from them)."""
    return type(message.edge_sums) is PackedSums


def message_columns(
    messages: list[ConsensusMessage], positions: Sequence[tuple[float, float, float]]
) -> MessageColumns | None:
    """``messages`` sent from ``positions`` as the columns of
    :func:`protocols.wire.format.column_parts`, read from the arrays their step made them from, if
    all come from one step with the values it made them with (:func:`packed_of`); else None."""
    got = packed_of(messages)
    if got is None:
        return None
    pack, at = got
    round_ = messages[0].round
    if any(m.round != round_ for m in messages):
        return None
    n = at.shape[0]
    heard_at, heard_ids = np.nonzero(pack.heard[at])
    bounds = np.array(pack.bounds, dtype=np.intp)
    starts = bounds[at]
    lens = bounds[at + 1] - starts
    total = int(lens.sum())
    edge_at = np.repeat(np.arange(n), lens)
    # the edges of each message in turn: its run of the pack's edge rows
    take = np.arange(total) + np.repeat(starts - (np.cumsum(lens) - lens), lens)
    motion = packed_motion(messages)
    if motion is not None:
        velocities = motion[1]
    else:
        velocities = np.array(
            [np.zeros(3) if m.velocity_ned_m_s is None else m.velocity_ned_m_s for m in messages],
            dtype=np.float64,
        ).reshape(n, 3)
    return MessageColumns(
        round_,
        [m.sender for m in messages],
        [m.degree for m in messages],
        [m.ready_hops for m in messages],
        [m.incarnation for m in messages],
        [-1 if m.takeoff_round is None else m.takeoff_round for m in messages],  # takeoffs
        positions,
        velocities,
        pack.gamma[at],
        heard_at,
        heard_ids,
        edge_at,
        pack.ids[take],
        pack.tags[take],
        pack.sums[take],
    )


def _tags(message: ConsensusMessage, n_edges: int) -> npt.NDArray[np.int64]:
    """The partner incarnations (n_edges,) of an :class:`EdgeSums` message, -1 where not said."""
    tags = message.edge_incarnations
    if tags is None:
        return np.full(n_edges, -1, dtype=np.int64)
    if isinstance(tags, EdgeIncarnations) and tags.tags.shape[0] == n_edges:
        return tags.tags
    assert isinstance(message.edge_sums, EdgeSums)
    return np.array([tags.get(j, -1) for j in message.edge_sums.ids.tolist()], dtype=np.int64)


def sums_for(
    receivers: npt.NDArray[np.intp],
    which: npt.NDArray[np.intp],
    messages: list[ConsensusMessage],
    packed: tuple[Pack, npt.NDArray[np.intp]] | None = None,
) -> tuple[npt.NDArray[np.bool_], FloatArray, npt.NDArray[np.int64]]:
    """``messages[which[k]].edge_sums.get(receivers[k])`` for every k: whether it is there
    (n,), the ones that are (n_found, 18) and the receiver incarnation each was made with
    (n_found,; -1 where the message does not say). :class:`EdgeSums` are looked up all at once
    (one sorted key per (message, neighbour)), other mappings one by one; ``packed``: the
    messages' :class:`Pack` and their positions in it (:func:`packed_of`), read as its arrays."""
    if packed is not None and int(receivers.max(initial=0)) < packed[0].span:
        pack, at = packed
        keys = pack.keys
        wanted = at[which] * pack.span + receivers
        where = np.searchsorted(keys, wanted)
        has = where < keys.shape[0]
        has[has] = keys[where[has]] == wanted[has]
        found = where[has]
        return has, pack.sums[found], pack.tags[found]
    tables = [m.edge_sums for m in messages]
    arrays = [t for t in tables if isinstance(t, EdgeSums)]
    if len(arrays) < len(tables):  # some plain mappings (decoded from the wire): one by one
        pairs = list(zip(which.tolist(), receivers.tolist(), strict=True))
        sums = [tables[k].get(i) for k, i in pairs]
        has = np.array([x is not None for x in sums], dtype=bool)
        found = [x for x in sums if x is not None]
        tagged = [
            -1 if (e := messages[k].edge_incarnations) is None else e.get(i, -1)
            for (k, i), x in zip(pairs, sums, strict=True)
            if x is not None
        ]
        return (
            has,
            np.array(found, dtype=float).reshape(-1, N_CHANNELS),
            np.array(tagged, dtype=np.int64),
        )
    sizes = [t.ids.shape[0] for t in arrays]
    ids = np.concatenate([t.ids for t in arrays])
    span = int(max(ids.max(initial=0), receivers.max(initial=0))) + 1
    keys = np.repeat(np.arange(len(arrays)), sizes) * span + ids  # ascending
    wanted = which * span + receivers
    at = np.searchsorted(keys, wanted)
    has = at < keys.shape[0]
    has[has] = keys[at[has]] == wanted[has]
    found = at[has]
    if all(m.edge_incarnations is None for m in messages):
        tags = np.full(found.shape[0], -1, dtype=np.int64)
    else:
        tags = np.concatenate([_tags(m, n) for m, n in zip(messages, sizes, strict=True)])[found]
    return has, np.concatenate([t.sums for t in arrays])[found], tags


_new_message = frozen_factory(ConsensusMessage)


def with_level(
    message: ConsensusMessage, ready_hops: int, *, takeoff_round: int | None = None
) -> ConsensusMessage:
    """``dataclasses.replace(message, ready_hops=ready_hops, takeoff_round=takeoff_round)``,
    several times cheaper (an agent puts its settled level and the round its swarm took off at
    on its message every tick); ``message`` itself if it has that level and take-off round."""
    if message.ready_hops == ready_hops and message.takeoff_round == takeoff_round:
        return message
    m = message
    return _new_message(
        m.sender, m.round, m.gamma, m.edge_sums, m.heard, m.degree, ready_hops,
        m.position_ned_m, m.velocity_ned_m_s, m.incarnation, m.edge_incarnations, takeoff_round,
    )  # fmt: skip


class Outgoing:
    """The messages of one
    :meth:`~drone_agent.core.consensus.estimator.BatchConsensus.step_outgoing`, one per row, before
    they are made: the senders, the round, the step's :class:`Pack` and each row's mappings, motion
    rows (None: none) and incarnation. :meth:`messages` makes them."""

    __slots__ = (
        "edge_sums",
        "edge_tags",
        "incarnations",
        "pack",
        "positions",
        "round",
        "senders",
        "velocities",
    )  # fmt: skip

    def __init__(
        self,
        senders: list[int],
        round_: int,
        pack: Pack,
        edge_sums: list[PackedSums],
        edge_tags: list[PackedIncarnations],
        positions: Sequence[FloatArray | None],
        velocities: Sequence[FloatArray | None],
        incarnations: list[int],
    ) -> None:
        self.senders, self.round, self.pack = senders, round_, pack
        self.edge_sums, self.edge_tags = edge_sums, edge_tags
        self.positions, self.velocities = positions, velocities
        self.incarnations = incarnations

    def messages(
        self,
        ready_hops: Sequence[int] | None = None,
        takeoffs: Sequence[int | None] | None = None,
    ) -> list[ConsensusMessage]:
        """Each row's message, with its settled level ``ready_hops[k]`` (None: 0 each, for the
        adapter to put its own on) and its swarm's take-off round ``takeoffs[k]`` (None: None
        each)."""
        pack = self.pack
        gammas, heard_sets = pack.gammas, pack.heard_sets
        levels = [0] * len(self.senders) if ready_hops is None else ready_hops
        takeoff_rounds = [None] * len(self.senders) if takeoffs is None else takeoffs
        edge_sums, edge_tags = self.edge_sums, self.edge_tags
        positions, velocities, own_inc = self.positions, self.velocities, self.incarnations
        return [
            _new_message(
                sender,
                self.round,
                gammas[p],
                edge_sums[p],
                heard_sets[p],
                len(heard_sets[p]),  # degree
                level,  # ready_hops
                positions[p],
                velocities[p],
                own_inc[p],  # incarnation
                edge_tags[p],
                takeoff,  # takeoff_round
            )
            for p, (sender, level, takeoff) in enumerate(
                zip(self.senders, levels, takeoff_rounds, strict=True)
            )
        ]
