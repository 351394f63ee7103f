"""Where an agent's radio neighbours are, from the consensus messages it heard. Pure.

Every consensus message carries its sender's position and velocity (NED; wire schema 2, see
protocols/wire/format.py). One rule, one implementation (:class:`NeighbourTable`, arrays over K
agents and every sender id, as the separation layer of drone_agent/core/separation/layer.py uses it;
:func:`neighbours_from_inbox` is its one-agent, one-inbox case):

- *Filing*: per (agent, sender) the newest message with a position is kept (the first copy of
  its highest round; a message without a position says nothing of where its sender is and is
  not filed). A message from a later round than the agent's (a neighbour ahead of it) waits and
  is filed when the agent reaches that round, so it never hides the sender's older message.
- *Staleness*: a message ``age`` rounds old (``round_now - message.round``) is used only while
  ``age <= max_age_rounds`` (the consensus heard-set timeout, 5 ticks, by default): a neighbour
  not heard for longer is as good as gone to the estimator too. Never oneself.
- *Extrapolation*: its position is extrapolated to now at its sent velocity, ``p + v (age dt)``:
  with the normal one-tick delay a drone at 3 m/s is 6 cm further on, after five lost ticks
  30 cm, errors the separation margin should not have to absorb. Velocities are held (no
  acceleration is sent). A sender of wire schema 1 sends no velocity: it is taken at rest, not
  extrapolated, and flagged (``velocity_known`` False).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from drone_agent.core.consensus.packing import packed_motion
from drone_agent.core.inboxes import alone, distinct_messages
from drone_agent.core.jit_math import jit
from protocols.mavlink.conventions import MAX_VEHICLES
from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]

#: Round of a slot never filed (no real round is this old).
_NEVER = -(2**62)


@dataclass(frozen=True)
class Neighbours:
    """The neighbours of one agent at one round, sorted by id.

    ``ids`` (M,); ``position_ned_m`` (M, 3), extrapolated to the round; ``velocity_ned_m_s``
    (M, 3); ``age_rounds`` (M,) of the message used; ``velocity_known`` (M,)."""

    ids: tuple[int, ...]
    position_ned_m: FloatArray
    velocity_ned_m_s: FloatArray
    age_rounds: IntArray
    velocity_known: BoolArray

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class HeardPairs:
    """The (agent, neighbour) pairs of one query, flat, ordered by (agent, neighbour id):
    ``owner`` (P,) the agent's position in the query, ``ids`` (P,) the neighbour's id,
    ``position_ned_m`` (P, 3) extrapolated to the round, ``velocity_ned_m_s`` (P, 3),
    ``age_rounds`` (P,), ``velocity_known`` (P,); ``counts`` (K,) pairs per agent."""

    owner: IntArray
    ids: IntArray
    position_ned_m: FloatArray
    velocity_ned_m_s: FloatArray
    age_rounds: IntArray
    velocity_known: BoolArray
    counts: IntArray

    def padded(
        self, agents: IntArray | None = None
    ) -> tuple[FloatArray, FloatArray, BoolArray, IntArray]:
        """Those of ``agents`` (positions in the query, ascending; default all) as padded arrays
        for ``separation.filter_accelerations``: positions (K', M, 3), velocities (K', M, 3),
        mask (K', M), ids (K', M) (-1 in the padding); M = the largest count (at least 1)."""
        counts = self.counts if agents is None else self.counts[agents]
        k = counts.shape[0]
        m = max(int(counts.max(initial=0)), 1)
        pos, vel = np.zeros((k, m, 3)), np.zeros((k, m, 3))
        mask = np.zeros((k, m), dtype=bool)
        ids = np.full((k, m), -1, dtype=np.intp)
        if agents is None:
            pick = np.arange(self.owner.shape[0])
            row = self.owner
        else:
            keep = np.zeros(self.counts.shape[0], dtype=np.intp) - 1
            keep[agents] = np.arange(k)
            row = keep[self.owner]
            pick = np.flatnonzero(row >= 0)
            row = row[pick]
        if pick.shape[0]:
            starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
            col = np.arange(pick.shape[0]) - starts[row]
            pos[row, col] = self.position_ned_m[pick]
            vel[row, col] = self.velocity_ned_m_s[pick]
            mask[row, col] = True
            ids[row, col] = self.ids[pick]
        return pos, vel, mask, ids


class NeighbourTable:
    """What agents heard of their neighbours: per (agent, sender id) the position, velocity and
    round of the newest message (module docstring), as arrays over the agents' rows and every
    sender id below ``MAX_VEHICLES``. ``dt_s``: the round period (s)."""

    def __init__(self, dt_s: float, max_age_rounds: int = 5) -> None:
        self.dt_s = dt_s
        self.max_age_rounds = max_age_rounds
        self._rows: dict[int, int] = {}  # agent id -> row of the arrays below
        self._agent_ids = np.zeros(0, dtype=np.intp)
        self._pos = np.zeros((0, MAX_VEHICLES, 3))
        self._vel = np.zeros((0, MAX_VEHICLES, 3))
        self._known = np.zeros((0, MAX_VEHICLES), dtype=bool)
        self._round = np.zeros((0, MAX_VEHICLES), dtype=np.int64)
        self._later: list[list[ConsensusMessage]] = []  # per row: from rounds not yet reached
        self._width = 0  # every sender id filed is below this (the columns a query looks at)

    def rows_of(self, agents: Sequence[int]) -> list[int]:
        """The rows of agents ``agents`` (new agents get new rows)."""
        rows = []
        for agent in agents:
            row = self._rows.get(agent)
            if row is None:
                row = self._rows[agent] = len(self._rows)
                grow = (1, MAX_VEHICLES)
                self._agent_ids = np.append(self._agent_ids, agent)
                self._pos = np.concatenate([self._pos, np.zeros((*grow, 3))])
                self._vel = np.concatenate([self._vel, np.zeros((*grow, 3))])
                self._known = np.concatenate([self._known, np.zeros(grow, dtype=bool)])
                self._round = np.concatenate([self._round, np.full(grow, _NEVER, np.int64)])
                self._later.append([])
            rows.append(row)
        return rows

    def hear(
        self, agents: Sequence[int], round_now: int, inboxes: Sequence[Iterable[ConsensusMessage]]
    ) -> None:
        """File what agents ``agents`` (distinct) heard up to round ``round_now``:
        ``inboxes[k]`` the messages agent ``agents[k]`` received since its last call."""
        rows = self.rows_of(agents)
        later = self._later
        senders: npt.NDArray[np.int64] | None = None
        msgs: list[ConsensusMessage]
        whole = alone(inboxes, rows, later)
        if whole is not None:  # nothing waiting: the values are the inboxes' as found for all
            msgs = whole.flat
            if not msgs:
                return
            owner = np.repeat(np.asarray(rows, dtype=np.intp), whole.counts)
            distinct, which = whole.distinct()
            senders, rounds = whole.senders_rounds()
        else:
            msgs = []
            owned: list[int] = []
            for row, inbox in zip(rows, inboxes, strict=True):
                n = len(msgs)
                if later[row]:
                    msgs += later[row]
                    later[row] = []
                msgs += inbox
                owned += [row] * (len(msgs) - n)
            if not msgs:
                return
            owner = np.array(owned, dtype=np.intp)
            # each distinct message object once (one message reaches many agents in process)
            distinct, which = distinct_messages(msgs)
        future = np.zeros(len(msgs), dtype=bool)
        motion = packed_motion(distinct)
        if motion is not None:  # from one batched step, as its arrays
            positions, velocities = motion
            has_position = known = np.ones(len(distinct), dtype=bool)
        else:
            nowhere = (0.0, 0.0, 0.0)
            has_position = np.array([m.position_ned_m is not None for m in distinct], dtype=bool)
            positions = np.array(
                [nowhere if m.position_ned_m is None else m.position_ned_m for m in distinct],
                dtype=np.float64,
            )
            velocities = np.array(
                [nowhere if m.velocity_ned_m_s is None else m.velocity_ned_m_s for m in distinct],
                dtype=np.float64,
            )
            known = np.array([m.velocity_ned_m_s is not None for m in distinct], dtype=bool)
        if senders is None:
            senders = np.array([m.sender for m in distinct], dtype=np.int64)
            rounds = np.array([m.round for m in distinct], dtype=np.int64)
        self._width = _file(
            owner,
            which,
            senders,
            rounds,
            has_position,
            positions,
            velocities,
            known,
            self._agent_ids,
            int(round_now),
            self._round,
            self._pos,
            self._vel,
            self._known,
            self._width,
            future,
        )
        for k in np.flatnonzero(future).tolist():
            later[int(owner[k])].append(msgs[k])

    def query(self, agents: Sequence[int], round_now: int) -> HeardPairs:
        """The neighbours of agents ``agents`` at round ``round_now`` (module docstring), flat."""
        rows = np.asarray(self.rows_of(agents), dtype=np.intp)
        owner, ids, pos, vel, age, known, counts = _query(
            rows, self._width, int(round_now), int(self.max_age_rounds), float(self.dt_s),
            self._round, self._pos, self._vel, self._known,
        )  # fmt: skip
        return HeardPairs(
            owner=owner,
            ids=ids,
            position_ned_m=pos,
            velocity_ned_m_s=vel,
            age_rounds=age,
            velocity_known=known,
            counts=counts,
        )


def neighbours_from_inbox(
    messages: Iterable[ConsensusMessage],
    own: int,
    round_now: int,
    dt_s: float,
    max_age_rounds: int = 5,
    extrapolate: bool = True,
) -> Neighbours:
    """The neighbours of agent ``own`` at round ``round_now`` from ``messages`` alone (any number
    per sender; the rule of :class:`NeighbourTable`, of which this is a fresh one-agent table);
    positions extrapolated by velocity x age x ``dt_s`` (the round period, s) unless
    ``extrapolate`` is False."""
    table = NeighbourTable(dt_s if extrapolate else 0.0, max_age_rounds)
    table.hear([own], round_now, [list(messages)])
    pairs = table.query([own], round_now)
    return Neighbours(
        ids=tuple(pairs.ids.tolist()),
        position_ned_m=pairs.position_ned_m,
        velocity_ned_m_s=pairs.velocity_ned_m_s,
        age_rounds=pairs.age_rounds.astype(np.intp),
        velocity_known=pairs.velocity_known,
    )


def neighbour_arrays(
    per_agent: Sequence[Neighbours],
) -> tuple[FloatArray, FloatArray, BoolArray, IntArray]:
    """K agents' neighbours as padded arrays for ``separation.filter_accelerations``: positions
    (K, M, 3), velocities (K, M, 3), mask (K, M), ids (K, M) (-1 in the padding);
    M = the largest count (at least 1)."""
    counts = np.array([len(nb) for nb in per_agent], dtype=np.intp)
    pairs = HeardPairs(
        owner=np.repeat(np.arange(len(per_agent)), counts),
        ids=np.array([j for nb in per_agent for j in nb.ids], dtype=np.intp),
        position_ned_m=np.concatenate([np.zeros((0, 3))] + [nb.position_ned_m for nb in per_agent]),
        velocity_ned_m_s=np.concatenate(
            [np.zeros((0, 3))] + [nb.velocity_ned_m_s for nb in per_agent]
        ),
        age_rounds=np.zeros(int(counts.sum()), dtype=np.intp),
        velocity_known=np.ones(int(counts.sum()), dtype=bool),
        counts=counts,
    )
    return pairs.padded()


@jit
def _query(  # type: ignore[no-untyped-def]
    rows, width, round_now, max_age, dt_s, round_table, pos_table, vel_table, known_table
):
    """:meth:`NeighbourTable.query` in two passes over the rows' first ``width`` slots (it was
    a dozen numpy calls, 6 % of a 25-drone ``swarm simulate`` tick): the pairs heard within
    ``max_age`` rounds, by (row, id); each position extrapolated as numpy did, ``p + v * (age *
    dt_s)`` term by term."""
    k = rows.shape[0]
    counts = np.zeros(k, dtype=np.intp)
    for a in range(k):
        r = rows[a]
        for j in range(width):
            age = round_now - round_table[r, j]
            if age >= 0 and age <= max_age:
                counts[a] += 1
    total = counts.sum()
    owner = np.empty(total, dtype=np.intp)
    ids = np.empty(total, dtype=np.intp)
    pos = np.empty((total, 3))
    vel = np.empty((total, 3))
    ages = np.empty(total, dtype=np.int64)
    known = np.empty(total, dtype=np.bool_)
    t = 0
    for a in range(k):
        r = rows[a]
        for j in range(width):
            age = round_now - round_table[r, j]
            if age >= 0 and age <= max_age:
                owner[t], ids[t], ages[t], known[t] = a, j, age, known_table[r, j]
                scale = age * dt_s
                for c in range(3):
                    v = vel_table[r, j, c]
                    vel[t, c] = v
                    pos[t, c] = pos_table[r, j, c] + v * scale
                t += 1
    return owner, ids, pos, vel, ages, known, counts


@jit
def _file(  # type: ignore[no-untyped-def]
    owner,
    which,
    sender,
    rounds,
    has_position,
    positions,
    velocities,
    known,
    agent_ids,
    round_now,
    round_table,
    pos_table,
    vel_table,
    known_table,
    width,
    future,
):
    """:meth:`NeighbourTable.hear`'s filing, value by value in arrival order (message
    ``which[t]`` of the distinct ones, heard by row ``owner[t]``): a message with a position,
    from another drone below ``MAX_VEHICLES``, is filed where its round is newer than the
    slot's (so per (row, sender) the first copy of the highest round stays); one from a round
    after ``round_now`` is flagged in ``future`` (it waits). Returns the new width."""
    for t in range(owner.shape[0]):
        r, u = owner[t], which[t]
        j, q = sender[u], rounds[u]
        if not has_position[u] or j < 0 or j >= MAX_VEHICLES or j == agent_ids[r]:
            continue
        if q > round_now:
            future[t] = True
            continue
        if q <= round_table[r, j]:
            continue
        round_table[r, j] = q
        for i in range(3):
            pos_table[r, j, i] = positions[u, i]
            vel_table[r, j, i] = velocities[u, i]
        known_table[r, j] = known[u]
        width = max(width, j + 1)
    return width
