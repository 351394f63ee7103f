"""The consensus estimator of K agents at once, as array operations
(drone_agent/core/consensus/scalar.py has the maths and the rules;
:class:`~drone_agent.core.consensus.scalar.ConsensusEstimator` is one row of this; its messages are
made in packing.py, its loops compiled in kernels.py).

Per step, what must look at each message is Python (listing the distinct message objects, their
senders and rounds, the ``Q_ji`` they carry for a plain mapping); everything else, the filing of
the values (validity, membership, duplicates, the newest message per peer, rounds kept for later)
and every pairing rule with the tanh increments, is array operations over all the (agent,
neighbour, round) values of the step. A usual step (every value valid, due, of the incarnation
known, in order, from one step's arrays: every steady tick of ``swarm simulate``) is filed by one
compiled pass instead (kernels.receive_common), which leaves any other step to the numpy filing
untouched; the heard-sets, the estimates with their history and the edges a message carries are
compiled passes too. Pure and I/O-free.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from itertools import chain, pairwise
from typing import Any

import numpy as np
import numpy.typing as npt

from drone_agent.core.consensus.kernels import (
    any_dead,
    edge_rows,
    heard_now,
    pair_increments,
    pair_rounds,
    receive_common,
    settle,
)
from drone_agent.core.consensus.packing import (
    Outgoing,
    Pack,
    PackedIncarnations,
    PackedSums,
    packed_of,
    sums_for,
)
from drone_agent.core.consensus.params import ConsensusOutput, ConsensusParams
from drone_agent.core.inboxes import alone, distinct_messages
from drone_agent.core.jit_math import f64
from drone_agent.core.moments import N_CHANNELS
from protocols.mavlink.conventions import MAX_VEHICLES
from protocols.model.frames import FloatArray
from protocols.runtime.fast_dataclass import frozen_factory
from protocols.wire.consensus_message import ConsensusMessage

#: Round tag of an empty history slot (no real round is this old).
_NO_ROUND = -(2**62)
#: No membership view, for :func:`receive_common`.
_NO_MASK = np.zeros((0, 0), dtype=bool)


@dataclass
class _Mail:
    """The messages of one step: ``messages`` the distinct message objects and ``senders`` (U,)
    theirs (and ``rounds``, when known); ``which`` (n,) the message of each (row, message)
    value, rows in turn, ``counts`` values per row, ``carried`` positions of values filed again
    (waiting from earlier steps)."""

    messages: list[ConsensusMessage]
    senders: npt.NDArray[np.intp]
    which: npt.NDArray[np.intp]
    counts: list[int]
    carried: list[int]
    packed: tuple[Pack, npt.NDArray[np.intp]] | None = None
    rounds: npt.NDArray[np.int64] | None = None  # of ``messages``, if found already


@dataclass
class _Due:
    """The (agent, neighbour, round) values due for pairing in one step, deduplicated (the last
    copy of a (sender, round) wins) and ordered by (agent, neighbour, round): ``pos`` the agent's
    position in the step's batch, ``sender``, ``round`` and ``msg`` (index into ``messages``, the
    distinct message objects of the step), all (T,)."""

    pos: npt.NDArray[np.intp]
    sender: npt.NDArray[np.intp]
    round: npt.NDArray[np.int64]
    msg: npt.NDArray[np.intp]
    messages: list[ConsensusMessage]
    packed: tuple[Pack, npt.NDArray[np.intp]] | None = None


def _flat(a: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """``a`` (K, M, ...), C-contiguous, as a view (K M, ...): ``a[r, j]`` is
    ``_flat(a)[r * M + j]``, an index on one axis, several times cheaper than numpy's index on
    two (and ``take`` cheaper still). Raises rather than copy."""
    v = a.view()
    v.shape = (a.shape[0] * a.shape[1], *a.shape[2:])
    return v


def _after_true(flags: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """``[True, *flags]``."""
    out = np.empty(flags.shape[0] + 1, dtype=bool)
    out[0] = True
    out[1:] = flags
    return out


def _before_true(flags: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """``[*flags, True]``."""
    out = np.empty(flags.shape[0] + 1, dtype=bool)
    out[-1] = True
    out[:-1] = flags
    return out


_new_output = frozen_factory(ConsensusOutput)


class BatchConsensus:
    """The consensus state of K agents, one row each (ids ``agent_ids``), advanced together.

    Each row is exactly one :class:`ConsensusEstimator`: it uses only its own inbox, own channels,
    own membership view and own state; rows never read each other. The state is held as arrays
    over (row, neighbour id): running sums ``Q_ij`` (``_q_own``, ``_q_recv``, (K, M, 18)), whether
    an edge exists and the last round it integrated, the newest round heard from each peer and the
    ``Q_ji`` it sent, and a ring of the last ``history_ticks`` rounds of the row's own gamma,
    degree and heard-set (slot ``round % history_ticks``, tagged with its round), the row's own
    incarnation (the round of its first step) and the newest incarnation heard of each peer (the
    incarnation rules of drone_agent/core/consensus/scalar.py). M grows with the
    largest neighbour id seen (ids are drone indices, below 1000 for a scenario; the memory is
    about 3 K M 18 doubles). Only what must look at each message (validity, the newest message
    per peer, duplicates, rounds from the future kept for later) is Python; every pairing rule of
    the module docstring and the tanh increments are array operations over all the (agent,
    neighbour, round) values of the step at once.
    """

    def __init__(self, agent_ids: Sequence[int], params: ConsensusParams) -> None:
        params.validate()
        self.params = params
        self.agent_ids = tuple(int(i) for i in agent_ids)
        self._ids = np.array(self.agent_ids, dtype=np.intp)
        if len(set(self.agent_ids)) != len(self.agent_ids):
            raise ValueError(f"agent ids must be distinct, got {self.agent_ids}")
        k, h = len(self.agent_ids), params.history_ticks
        self._m = 0
        self._q_own = np.zeros((k, 0, N_CHANNELS))
        self._q_recv = np.zeros((k, 0, N_CHANNELS))
        self._edge = np.zeros((k, 0), dtype=bool)
        self._edge_round = np.zeros((k, 0), dtype=np.int64)
        self._peer = np.zeros((k, 0), dtype=bool)
        self._latest = np.zeros((k, 0), dtype=np.int64)
        #: the step (round) at which a message of the peer last arrived: "heard" is by arrival,
        #: so a link that delivers every round, however late (up to the history), is heard
        self._arrived = np.zeros((k, 0), dtype=np.int64)
        self._q_for_me = np.zeros((k, 0, N_CHANNELS))
        self._has_q_for_me = np.zeros((k, 0), dtype=bool)
        self._inc = np.zeros((k, 0), dtype=np.int64)  # newest incarnation heard per peer, -1 none
        self._own_inc = np.full(k, -1, dtype=np.int64)  # -1: not started
        #: rows that only listen (set_observing): they say they hear nobody
        self.observing = np.zeros(k, dtype=bool)
        self._hist_round = np.full((k, h), _NO_ROUND, dtype=np.int64)
        self._hist_gamma = np.zeros((k, h, N_CHANNELS))
        self._hist_largest = np.zeros((k, h))  # max |gamma| of the round
        self._hist_degree = np.zeros((k, h), dtype=np.int64)
        self._hist_heard = np.zeros((k, h, 0), dtype=bool)
        # rounds not yet integrable (from the future), per row: (sender, round) -> message
        self._later: list[dict[tuple[int, int], ConsensusMessage]] = [{} for _ in range(k)]
        self._last_round: list[int | None] = [None] * k
        self.dropped_messages = [0] * k
        self.stale_messages = [0] * k
        self._masks: dict[int, tuple[frozenset[int], npt.NDArray[np.bool_]]] = {}
        #: per row, the ids it heard at its last step (K, M) and their set (_heard_sets)
        self._heard_prev = np.zeros((k, 0), dtype=bool)
        self._heard_set: list[frozenset[int]] = [frozenset()] * k
        self._scales = np.ascontiguousarray(params.channel_scales, dtype=np.float64)
        self._grow(max(self.agent_ids, default=0) + 1)

    # -- inspection ----------------------------------------------------------------------------
    def edges(self, row: int) -> tuple[int, ...]:
        """Neighbours of row ``row`` with edge state (integrating or frozen), sorted."""
        return tuple(int(j) for j in np.flatnonzero(self._edge[row]))

    def edge_sum(self, row: int, neighbour: int) -> FloatArray:
        """``eta_ij`` (18,) row ``row`` uses for the edge to ``neighbour`` (zeros if none)."""
        if neighbour >= self._m or not self._edge[row, neighbour]:
            return np.zeros(N_CHANNELS)
        out: FloatArray = 0.5 * (self._q_own[row, neighbour] - self._q_recv[row, neighbour])
        return out

    def incarnation(self, row: int) -> int | None:
        """Row ``row``'s incarnation: the round of its first step (None before it)."""
        value = int(self._own_inc[row])
        return None if value < 0 else value

    def restart(self, row: int) -> None:
        """Row ``row``'s agent starts a new life (an agent restarted in its process): every state
        of the row is dropped, and its next step starts a new incarnation (that round), so its
        neighbours drop their edges to the old one (the incarnation rules of consensus.py)."""
        self._forget(np.full(self._m, row, dtype=np.intp), np.arange(self._m), history=True)
        self._inc[row] = -1
        self._own_inc[row] = -1
        self._hist_round[row] = _NO_ROUND
        self._hist_gamma[row] = 0.0
        self._hist_largest[row] = 0.0
        self._hist_degree[row] = 0
        self._hist_heard[row] = False
        self._later[row] = {}
        self._last_round[row] = None
        self.observing[row] = False

    def set_observing(self, row: int, observing: bool) -> None:
        """Row ``row`` only listens (True) or takes part again (False). A listening row's
        messages say it hears nobody and carry no running sums, so by rule 3 no neighbour
        integrates an edge with it (its channels do not count in anyone's average), while it
        integrates its edges one-sidedly: its estimate follows its neighbours' estimate of the
        swarm without it. Used by a returning agent until its vehicle is back near the formation
        (drone_agent/process/hosted_agent.py); :meth:`restart` it when it takes part again."""
        self.observing[row] = observing

    # -- the step ------------------------------------------------------------------------------
    def step(
        self,
        rows: Sequence[int],
        round_: int,
        zeta: FloatArray,
        inboxes: Sequence[Iterable[ConsensusMessage]],
        members: Sequence[frozenset[int] | None],
        motion: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, list[ConsensusOutput]]:
        """Advance rows ``rows`` (distinct) to round ``round_``: ``zeta`` (len(rows), 18) their
        channels, ``inboxes[k]`` the messages row ``rows[k]`` received since its last step,
        ``members[k]`` its liveliness view (None keeps every partner); ``motion``: the rows'
        positions and velocities (len(rows), 3) NED, put on their messages for the neighbours'
        separation layer. Returns the estimates (len(rows), 18) and one output per row (whose
        estimate is its row of them)."""
        gamma, messages, active, disagreement = self.step_messages(
            rows, round_, zeta, inboxes, members, motion
        )
        return gamma, [
            _new_output(message.gamma, message, neighbours, dis)
            for message, neighbours, dis in zip(
                messages, active, disagreement.tolist(), strict=True
            )
        ]

    def step_messages(
        self,
        rows: Sequence[int],
        round_: int,
        zeta: FloatArray,
        inboxes: Sequence[Iterable[ConsensusMessage]],
        members: Sequence[frozenset[int] | None],
        motion: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, list[ConsensusMessage], list[tuple[int, ...]], FloatArray]:
        """:meth:`step` without the output objects: the estimates (len(rows), 18), and per row
        its message, its active neighbours and its disagreement (len(rows),)."""
        gamma, outgoing, active, disagreement = self.step_outgoing(
            rows, round_, zeta, inboxes, members, motion
        )
        return gamma, outgoing.messages(), active, disagreement

    def step_outgoing(
        self,
        rows: Sequence[int],
        round_: int,
        zeta: FloatArray,
        inboxes: Sequence[Iterable[ConsensusMessage]],
        members: Sequence[frozenset[int] | None],
        motion: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, Outgoing, list[tuple[int, ...]], FloatArray]:
        """:meth:`step_messages` with the rows' messages still to be made
        (:meth:`Outgoing.messages`, with their settled levels when the caller knows them)."""
        rows_arr = np.asarray(rows, dtype=np.intp).reshape(-1)
        for row in rows_arr.tolist():
            last = self._last_round[row]
            if last is not None and round_ <= last:
                raise ValueError(f"round {round_} is not after round {last}")
            self._last_round[row] = round_
            if self._own_inc[row] < 0:  # its first step: a new incarnation
                self._own_inc[row] = round_
        mail = self._gather(rows_arr, inboxes)
        if mail is not None and int(mail.senders.max()) >= self._m:
            self._grow(int(mail.senders.max()) + 1)
        member_mask = self._member_mask(members)
        due = None if mail is None else self._receive(rows_arr, round_, mail, member_mask)
        if member_mask is not None and any_dead(rows_arr, self._peer, self._edge, member_mask):
            self._discard_dead(rows_arr, member_mask)
        n_rows = rows_arr.shape[0]
        heard = np.empty((n_rows, self._m), dtype=bool)
        degree = np.empty(n_rows, dtype=np.int64)
        oldest = round_ - self.params.heard_timeout_ticks
        heard_now(rows_arr, self._peer, self._arrived, oldest, heard, degree)
        active, disagreement = self._integrate(rows_arr, round_, due)
        gamma = np.zeros((n_rows, N_CHANNELS))
        settle(
            rows_arr, round_, self.params.f * 0.5, f64(zeta), self._edge, self._has_q_for_me,
            self._q_for_me, self._q_own, self._q_recv, heard, degree, self._hist_round,
            self._hist_gamma, self._hist_largest, self._hist_degree, self._hist_heard, gamma,
        )  # fmt: skip
        outgoing = self._outputs(rows_arr, round_, gamma, heard, motion)
        return gamma, outgoing, active, disagreement

    def _grow(self, m: int) -> None:
        """Make room for neighbour ids below ``m`` (at least doubling)."""
        m = max(m, 2 * self._m)
        pad = m - self._m

        def wider(a: npt.NDArray[Any], axis: int, fill: float | bool = 0) -> npt.NDArray[Any]:
            shape = list(a.shape)
            shape[axis] = pad
            return np.concatenate([a, np.full(shape, fill, dtype=a.dtype)], axis=axis)

        self._q_own, self._q_recv = wider(self._q_own, 1), wider(self._q_recv, 1)
        self._q_for_me = wider(self._q_for_me, 1)
        self._edge, self._peer = wider(self._edge, 1, False), wider(self._peer, 1, False)
        self._has_q_for_me = wider(self._has_q_for_me, 1, False)
        self._inc = wider(self._inc, 1, -1)
        self._edge_round, self._latest = wider(self._edge_round, 1, -1), wider(self._latest, 1, -1)
        self._arrived = wider(self._arrived, 1, -1)
        self._hist_heard = wider(self._hist_heard, 2, False)
        self._m = m

    def _gather(
        self, rows: npt.NDArray[np.intp], inboxes: Sequence[Iterable[ConsensusMessage]]
    ) -> _Mail | None:
        """The step's messages, row by row, each row's waiting values first (filed again as if
        they had just arrived), as indices into the distinct message objects (one message
        reaches many rows in process)."""
        whole = alone(inboxes, rows.tolist(), self._later)
        if whole is not None:  # nothing waiting: the values are the inboxes' as found for all
            if not whole.flat:
                return None
            messages, which = whole.distinct()
            senders, rounds = whole.senders_rounds()
            if senders.min() >= 0 and senders.max() < MAX_VEHICLES:
                return _Mail(messages, senders.astype(np.intp, copy=False), which,
                             whole.counts, [], packed_of(messages), rounds)  # fmt: skip
        segments: list[tuple[list[ConsensusMessage], list[ConsensusMessage]]] = []
        for row, inbox in zip(rows.tolist(), inboxes, strict=True):
            waiting = self._later[row]
            again: list[ConsensusMessage] = []
            if waiting:
                again = list(waiting.values())
                waiting.clear()
            segments.append((again, inbox if isinstance(inbox, list) else list(inbox)))
        mail = self._file(rows, segments, checked=False)
        if mail is not None and (mail.senders.min() < 0 or mail.senders.max() >= MAX_VEHICLES):
            mail = self._file(rows, segments, checked=True)
        return mail

    def _file(
        self,
        rows: npt.NDArray[np.intp],
        segments: list[tuple[list[ConsensusMessage], list[ConsensusMessage]]],
        checked: bool,
    ) -> _Mail | None:
        """:meth:`_gather`'s values from each row's (waiting, inbox) messages; with ``checked``
        the inbox messages of senders beyond any swarm are dropped (counted), which would make
        every edge array huge (without, the caller checks the senders and files again)."""
        msgs: list[ConsensusMessage] = []
        counts: list[int] = []
        carried: list[int] = []  # positions in msgs of values filed again
        for row, (again, inbox) in zip(rows.tolist(), segments, strict=True):
            n = len(msgs)
            if again:
                carried += range(n, n + len(again))
                msgs += again
            if not checked:
                msgs += inbox
            else:
                for msg in inbox:
                    if 0 <= msg.sender < MAX_VEHICLES:
                        msgs.append(msg)
                    else:
                        self.dropped_messages[row] += 1
            counts.append(len(msgs) - n)
        if not msgs:
            return None
        messages, which = distinct_messages(msgs)
        senders = np.array([m.sender for m in messages], dtype=np.intp)
        return _Mail(messages, senders, which, counts, carried, packed_of(messages))

    def _receive(
        self,
        rows: npt.NDArray[np.intp],
        round_: int,
        mail: _Mail,
        member_mask: npt.NDArray[np.bool_] | None,
    ) -> _Due | None:
        """File each message: drop own and too-old ones (counted) and those of partners the
        row's membership view does not list; keep the newest message per peer (the first copy of
        its highest round) for the heard-set and the ``Q_ji`` it carries; return the values due
        for pairing (rounds before ``round_``; the last copy of a (sender, round) wins) and keep
        the later rounds waiting."""
        messages, which, carried = mail.messages, mail.which, mail.carried
        j = mail.senders[which]
        rounds = mail.rounds
        if rounds is None:
            rounds = np.array([m.round for m in messages], dtype=np.int64)
        q = rounds[which]
        pos = np.repeat(np.arange(rows.shape[0]), mail.counts)
        incarnations = np.array([m.incarnation for m in messages], dtype=np.int64)
        if mail.packed is not None and not carried:
            pack, at = mail.packed
            if receive_common(
                rows, pos, j, q, which, incarnations, at, pack.keys, pack.span, pack.sums,
                pack.tags, self._ids, self._own_inc, self._inc,
                _NO_MASK if member_mask is None else member_mask, round_,
                self.params.history_ticks, self._peer, self._arrived, self._latest,
                self._has_q_for_me, self._q_for_me,
            ):  # fmt: skip
                return _Due(pos, j, q, which, messages, mail.packed)
        me = self._ids[rows][pos]
        valid = (j != me) & (q >= round_ - self.params.history_ticks) & (j >= 0)
        if carried:
            valid[carried] = True
        if not valid.all():
            dropped = np.bincount(pos[~valid], minlength=rows.shape[0])
            for p in np.flatnonzero(dropped).tolist():
                self.dropped_messages[int(rows[p])] += int(dropped[p])
        if member_mask is not None:
            valid &= member_mask[pos, j]
        if not valid.all():
            sel = np.flatnonzero(valid)
            if sel.shape[0] == 0:
                return None
            pos, j, q, which = pos[sel], j[sel], q[sel], which[sel]
        fresh = self._incarnations(rows, pos, j, incarnations[which])
        if fresh is not None:
            if fresh.shape[0] == 0:
                return None
            pos, j, q, which = pos[fresh], j[fresh], q[fresh], which[fresh]
        order, same_pair, same_value = self._sorted(pos, j, q, rows.shape[0])
        if order is not None:
            pos, j, q, which = pos[order], j[order], q[order], which[order]
        row = rows[pos]
        pair = row * self._m + j
        _flat(self._peer)[pair] = True
        _flat(self._arrived)[pair] = round_
        # newest per (row, peer): the first copy of the highest round
        ends = np.flatnonzero(_before_true(~same_pair))
        duplicates = bool(same_value.any())
        if duplicates:
            first_copy = _after_true(~same_value)
            copy_start = np.maximum.accumulate(np.where(first_copy, np.arange(q.shape[0]), 0))
            newest = copy_start[ends]
        else:
            newest = ends
        newer = newest[q[newest] > _flat(self._latest).take(pair[newest])]
        self._note_newest(row[newer], j[newer], q[newer], which[newer], messages, mail.packed)
        if duplicates:  # the last copy of a (sender, round) is the one paired
            last_copy = np.flatnonzero(_before_true(~same_value))
            pos, j, q, which, row = (
                pos[last_copy],
                j[last_copy],
                q[last_copy],
                which[last_copy],
                row[last_copy],
            )
        is_due = q < round_
        if not is_due.all():
            for k in np.flatnonzero(~is_due).tolist():
                self._later[int(row[k])][(int(j[k]), int(q[k]))] = messages[which[k]]
            pos, j, q, which = pos[is_due], j[is_due], q[is_due], which[is_due]
        return _Due(pos, j, q, which, messages, mail.packed)

    def _incarnations(
        self,
        rows: npt.NDArray[np.intp],
        pos: npt.NDArray[np.intp],
        j: npt.NDArray[np.intp],
        incs: npt.NDArray[np.int64],
    ) -> npt.NDArray[np.intp] | None:
        """The incarnation rules (consensus.py) over the values (``incs`` the incarnation each
        carries): a newer incarnation of a peer drops every state towards it first; values of an
        older one are stale (counted). Returns the positions of the values kept, None if all
        are."""
        row = rows[pos]
        known = self._inc[row, j]
        if (incs == known).all():  # the usual case
            return None
        newer = incs > known
        if newer.any():
            self._forget(row[newer], j[newer], history=True)
            np.maximum.at(self._inc, (row[newer], j[newer]), incs[newer])
            known = self._inc[row, j]
        stale = incs < known
        if not stale.any():
            return None
        counts = np.bincount(pos[stale], minlength=rows.shape[0])
        for p in np.flatnonzero(counts).tolist():
            self.stale_messages[int(rows[p])] += int(counts[p])
            self.dropped_messages[int(rows[p])] += int(counts[p])
        return np.flatnonzero(~stale)

    def _forget(
        self, rows: npt.NDArray[np.intp], ids: npt.NDArray[np.intp], history: bool = False
    ) -> None:
        """Drop every state of row ``rows[k]`` towards peer ``ids[k]``: running sums, edge,
        heard rounds (and, with ``history``, that the row heard it in its past rounds)."""
        self._q_own[rows, ids] = 0.0
        self._q_recv[rows, ids] = 0.0
        self._q_for_me[rows, ids] = 0.0
        self._edge[rows, ids] = False
        self._edge_round[rows, ids] = -1
        self._peer[rows, ids] = False
        self._latest[rows, ids] = -1
        self._arrived[rows, ids] = -1
        self._has_q_for_me[rows, ids] = False
        if history:
            self._hist_heard[rows, :, ids] = False

    def _sorted(
        self,
        pos: npt.NDArray[np.intp],
        j: npt.NDArray[np.intp],
        q: npt.NDArray[np.int64],
        n_rows: int,
    ) -> tuple[npt.NDArray[np.intp] | None, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """The stable order by (agent, sender, round) (arrival order among equals; None if the
        values are in that order already), and whether each value in that order has the same
        (agent, sender) / (agent, sender, round) as the next one."""
        q_lo = int(q.min())
        span = int(q.max()) - q_lo + 1
        if span * self._m * n_rows >= 2**62:  # rounds too far apart for one key
            by_key = np.lexsort((q, j, pos))
            pos, j, q = pos[by_key], j[by_key], q[by_key]
            same_pair = (pos[1:] == pos[:-1]) & (j[1:] == j[:-1])
            return by_key, same_pair, same_pair & (q[1:] == q[:-1])
        pair = pos * self._m + j
        key = pair * span + (q - q_lo)
        order: npt.NDArray[np.intp] | None = None
        if not (key[1:] > key[:-1]).all():  # inboxes usually arrive in order already
            order = np.argsort(key, kind="stable")
            key, pair = key[order], pair[order]
        return order, pair[1:] == pair[:-1], key[1:] == key[:-1]

    def _note_newest(
        self,
        rows: npt.NDArray[np.intp],
        ids: npt.NDArray[np.intp],
        rounds: npt.NDArray[np.int64],
        which: npt.NDArray[np.intp],
        messages: list[ConsensusMessage],
        packed: tuple[Pack, npt.NDArray[np.intp]] | None = None,
    ) -> None:
        """Peer ``ids[k]``'s newest message to row ``rows[k]`` is ``messages[which[k]]`` of
        round ``rounds[k]``: the round it was last heard in, and the ``Q_ji`` it carries."""
        pair = rows * self._m + ids
        _flat(self._latest)[pair] = rounds
        has, values, tags = sums_for(self._ids[rows], which, messages, packed)
        mine = (tags < 0) | (tags == self._own_inc[rows[has]])  # made with this incarnation
        if not mine.all():
            has[np.flatnonzero(has)[~mine]] = False
            values = values[mine]
        _flat(self._has_q_for_me)[pair] = has
        _flat(self._q_for_me)[pair[has]] = values

    def _member_mask(
        self, members: Sequence[frozenset[int] | None]
    ) -> npt.NDArray[np.bool_] | None:
        """(len(rows), M) True where the row's membership view lists the id; None if no row has
        a view."""
        if all(m is None for m in members):
            return None
        out = np.ones((len(members), self._m), dtype=bool)
        first = members[0]
        if first is not None and all(view is first for view in members):
            out[:] = self._mask_of(first)
            return out
        for pos, view in enumerate(members):
            if view is not None:
                out[pos] = self._mask_of(view)
        return out

    def _mask_of(self, view: frozenset[int]) -> npt.NDArray[np.bool_]:
        """(M,) True for the ids in ``view``; remembered for the same view object (agents hand
        over one view for many ticks)."""
        cached = self._masks.get(id(view))
        if cached is not None and cached[0] is view and cached[1].shape[0] == self._m:
            return cached[1]
        mask = np.zeros(self._m, dtype=bool)
        mask[[j for j in view if 0 <= j < self._m]] = True
        if len(self._masks) >= 64:
            self._masks.clear()
        self._masks[id(view)] = (view, mask)
        return mask

    def _discard_dead(self, rows: npt.NDArray[np.intp], member_mask: npt.NDArray[np.bool_]) -> None:
        """Rule 5: drop every state towards partners the row's membership view no longer lists."""
        dead = (self._peer[rows] | self._edge[rows]) & ~member_mask
        if not dead.any():
            return
        pos, ids = np.nonzero(dead)
        self._forget(rows[pos], ids)

    def _integrate(
        self, rows: npt.NDArray[np.intp], round_: int, due: _Due | None
    ) -> tuple[list[tuple[int, ...]], FloatArray]:
        """Rules 2, 3 and 6 and the delay-scaled gain over every due (agent, neighbour, round):
        integrate those whose own value of that round is still in the history, newer than the
        edge's last integrated round, and where both ends heard each other in that round.
        Returns the active neighbours per row and the disagreement per row. The arithmetic is
        compiled loops over the due values (:func:`pair_rounds`, :func:`pair_increments`) around
        numpy's tanh."""
        n_rows = rows.shape[0]
        disagreement = np.zeros(n_rows)
        active: list[tuple[int, ...]] = [()] * n_rows
        if due is None:
            return active, disagreement
        p = self.params
        n_due = due.pos.shape[0]
        heads = np.zeros(n_due, dtype=np.bool_)
        integrated = np.zeros(n_due, dtype=np.bool_)
        steps = np.empty(n_due)
        args = np.empty((n_due, N_CHANNELS))
        n_ok = pair_rounds(
            rows,
            due.pos,
            due.sender,
            due.round,
            due.msg,
            self._ids,
            int(round_),
            self._hist_round,
            self._hist_heard,
            self._hist_gamma,
            self._hist_degree,
            self._hist_largest,
            self._edge,
            self._edge_round,
            self._heard_by(due),
            (
                np.array([m.gamma for m in due.messages], dtype=np.float64)
                if due.packed is None
                else due.packed[0].gamma[due.packed[1]]
            ),
            np.array([m.degree for m in due.messages], dtype=np.int64),
            (float(p.rho), float(p.rho_cap), float(p.dt_s), float(p.c), bool(p.degree_normalised)),
            self._scales,
            disagreement,
            integrated,
            heads,
            steps,
            args,
        )
        if n_ok == 0:
            return active, disagreement
        # numpy's tanh over the whole step (vectorised: several times faster than one by one)
        np.tanh(args[:n_ok], out=args[:n_ok])
        pair_increments(
            rows,
            due.pos,
            due.sender,
            due.round,
            integrated,
            steps,
            args,
            self._scales,
            self._q_own,
            self._edge,
            self._edge_round,
        )
        if not heads.any():
            return active, disagreement
        pos, ids = due.pos[heads], due.sender[heads].tolist()
        bounds = np.searchsorted(pos, np.arange(n_rows + 1))
        for k in np.flatnonzero(np.diff(bounds)).tolist():
            active[k] = tuple(ids[bounds[k] : bounds[k + 1]])
        return active, disagreement

    def _heard_by(self, due: _Due) -> npt.NDArray[np.bool_]:
        """(messages, M) True where the message's heard-set lists the id."""
        heard = np.zeros((len(due.messages), self._m), dtype=bool)
        if due.packed is not None:
            pack, at = due.packed
            width = min(pack.span, self._m)
            heard[:, :width] = pack.heard[at, :width]
            return heard
        sizes = [len(m.heard) for m in due.messages]
        total = sum(sizes)
        if total:
            owner = np.repeat(np.arange(len(due.messages)), sizes)
            ids = np.fromiter(chain.from_iterable(m.heard for m in due.messages), np.intp, total)
            keep = (ids >= 0) & (ids < self._m)
            heard[owner[keep], ids[keep]] = True
        return heard

    def _heard_sets(
        self, rows: npt.NDArray[np.intp], heard: npt.NDArray[np.bool_]
    ) -> list[frozenset[int]]:
        """The ids each row hears (``heard`` (len(rows), M)) as sets; a row's set object of its
        last step again when it hears the same ids (a heard-set changes seldom)."""
        prev = self._heard_prev
        if prev.shape[1] != heard.shape[1]:
            prev = self._heard_prev = np.zeros((len(self.agent_ids), heard.shape[1]), dtype=bool)
            self._heard_set = [frozenset()] * len(self.agent_ids)
        known = self._heard_set
        changed = np.flatnonzero((prev[rows] != heard).any(axis=1))
        if changed.shape[0]:
            now = heard[changed]
            prev[rows[changed]] = now
            at, ids = np.nonzero(now)
            bounds = np.searchsorted(at, np.arange(changed.shape[0] + 1)).tolist()
            listed = ids.tolist()
            for row, (lo, hi) in zip(rows[changed].tolist(), pairwise(bounds), strict=True):
                known[row] = frozenset(listed[lo:hi])
        return [known[row] for row in rows.tolist()]

    def _outputs(
        self,
        rows: npt.NDArray[np.intp],
        round_: int,
        gamma: FloatArray,
        heard: npt.NDArray[np.bool_],
        motion: tuple[FloatArray, FloatArray] | None = None,
    ) -> Outgoing:
        """What makes each row's message of this step."""
        n_rows = rows.shape[0]
        moved: tuple[FloatArray, FloatArray] | None = None
        if motion is None:
            positions: list[FloatArray | None] = [None] * n_rows
            velocities: list[FloatArray | None] = [None] * n_rows
        else:
            moved = (
                np.array(motion[0], dtype=float).reshape(-1, 3),
                np.array(motion[1], dtype=float).reshape(-1, 3),
            )
            positions, velocities = list(moved[0]), list(moved[1])
        listening = self.observing[rows]
        if listening.any():  # a listening row says it hears nobody, sends no sums
            heard = heard & ~listening[:, None]
        ids, keys, sums, tags, bounds = edge_rows(
            rows, self._edge, self.observing, self._q_own, self._inc
        )
        sums.flags.writeable = False  # shared by the messages' EdgeSums
        tags.flags.writeable = False
        ids.flags.writeable = False
        heard_sets = self._heard_sets(rows, heard)
        heard.flags.writeable = False
        pack = Pack(keys, ids, bounds.tolist(), self._m, sums, tags, gamma, heard)
        pack.heard_sets = heard_sets
        if moved is not None:
            pack.positions, pack.velocities = moved
            pack.where, pack.how_fast = positions, velocities
        places = range(n_rows)
        return Outgoing(
            [self.agent_ids[row] for row in rows.tolist()],
            round_,
            pack,
            [PackedSums(pack, p) for p in places],
            [PackedIncarnations(pack, p) for p in places],
            positions,
            velocities,
            self._own_inc[rows].tolist(),
        )
