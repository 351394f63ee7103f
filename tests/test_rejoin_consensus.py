"""Rejoin: the incarnation rules of the consensus estimator (drone_agent/core/consensus/scalar.py).

A restarted agent (same drone id, a new estimator) must be taken as a new member with fresh edge
state on both ends of each edge, even when its neighbours' liveliness view never dropped it: its
new running sums are never mixed with its old life's. Checked on the messages themselves: with
channels far apart the old life's running sums are large, while a sum made of k new rounds is
at most k increments (each at most ``rho dt s_k`` per channel, the tanh bound); so every sum a
neighbour sends towards the new life, and the new agent's estimate, stay within the bound of the
rounds since the restart. Without incarnations (an older sender: incarnation 0, no edge
incarnations) the old sums are kept and the bound fails: the check can fail.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from drone_agent.core.consensus.estimator import BatchConsensus
from drone_agent.core.consensus.scalar import ConsensusEstimator, ConsensusParams
from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import decode_consensus, encode_consensus

pytestmark = pytest.mark.timeout(120)

N = 4
RESTARTED = 2
KILL_AT, BACK_AT, END = 60, 100, 300  # rounds
CHECKED = 4  # rounds after the restart whose sums are bounded
PARAMS = ConsensusParams()
#: the largest increment of one round on one edge, per channel
STEP = PARAMS.rho * PARAMS.dt_s * PARAMS.channel_scales


def _zeta(seed: int = 1) -> FloatArray:
    return np.random.default_rng(seed).normal(size=(N, 18)) * 300.0


@dataclass
class _Flight:
    estimates: dict[tuple[int, int], FloatArray]
    messages: list[ConsensusMessage]
    agents: dict[int, ConsensusEstimator]


def _fly(*, legacy: bool = False, wire: bool = False, zombie: bool = False) -> _Flight:
    """Four estimators, full graph, one-tick delay. Drone 2's agent dies at KILL_AT and a new one
    (a fresh estimator) starts at BACK_AT; the others' membership always lists it (their
    liveliness view has not noticed). ``legacy``: messages without incarnations; ``wire``: every
    message through the wire codec; ``zombie``: the old life sends one more message after the
    restart (a hung process that woke up)."""
    zeta = _zeta()
    agents = {i: ConsensusEstimator(i, PARAMS) for i in range(N)}
    inbox: dict[int, list[ConsensusMessage]] = {i: [] for i in range(N)}
    flight = _Flight({}, [], agents)
    everyone = frozenset(range(N))
    last_old: ConsensusMessage | None = None
    for r in range(END):
        if r == BACK_AT:
            agents[RESTARTED] = ConsensusEstimator(RESTARTED, PARAMS)
        live = [i for i in range(N) if not (i == RESTARTED and KILL_AT <= r < BACK_AT)]
        sent = []
        for i in live:
            out = agents[i].step(r, zeta[i], inbox[i], everyone)
            inbox[i] = []
            flight.estimates[(r, i)] = out.estimate
            msg = out.message
            if legacy:
                msg = replace(msg, incarnation=0, edge_incarnations=None)
            if wire:
                msg = decode_consensus(encode_consensus(msg, (0.0, 0.0, 0.0), "s"), "s").message
            if i == RESTARTED and r == KILL_AT - 1:
                last_old = msg
            sent.append(msg)
        if zombie and r == BACK_AT + 2 and last_old is not None:
            sent.append(replace(last_old, round=r))
        flight.messages += sent
        for msg in sent:
            for j in live:
                if j != msg.sender:
                    inbox[j].append(msg)
    return flight


def _fresh(flight: _Flight) -> bool:
    """Every sum towards the new life (a sum that says it was made with the old life is not
    one: the new agent does not take it), and the new agent's estimate, within the bound of the
    rounds since the restart (the module doc)."""
    zeta = _zeta()
    for msg in flight.messages:
        k = msg.round - BACK_AT
        if not 0 <= k <= CHECKED or msg.sender == RESTARTED or RESTARTED not in msg.edge_sums:
            continue
        tags = msg.edge_incarnations or {}
        if tags.get(RESTARTED, BACK_AT) != BACK_AT:  # made with the old life, and says so
            continue
        if (np.abs(msg.edge_sums[RESTARTED]) > k * STEP + 1e-9).any():
            return False
    for k in range(CHECKED + 1):
        moved = np.abs(flight.estimates[(BACK_AT + k, RESTARTED)] - zeta[RESTARTED])
        if (moved > PARAMS.f * (N - 1) * k * STEP + 1e-9).any():
            return False
    return True


def test_a_restarted_agent_gets_fresh_edges_on_both_ends_without_a_membership_change() -> None:
    flight = _fly()
    assert _fresh(flight)
    # the old sums were large: the bound means something
    old = [m for m in flight.messages if m.round == KILL_AT - 1 and m.sender != RESTARTED]
    assert all((np.abs(m.edge_sums[RESTARTED]) > 5 * CHECKED * STEP).any() for m in old)
    # and it settles: every estimate at the channel average again
    mean = _zeta().mean(axis=0)
    for i in range(N):
        assert np.abs(flight.estimates[(END - 1, i)] - mean).max() < 0.02 * np.abs(mean).max()
    assert flight.agents[RESTARTED].incarnation == BACK_AT
    assert flight.agents[0].incarnation == 0
    neighbours = [m for m in flight.messages if m.round == END - 1 and m.sender != RESTARTED]
    assert all(m.edge_incarnations is not None for m in neighbours)
    assert all(m.edge_incarnations[RESTARTED] == BACK_AT for m in neighbours)  # type: ignore[index]


def test_without_incarnations_old_sums_are_mixed_into_the_new_ones() -> None:
    """The control: messages of an older build (no incarnations) keep the old edge state."""
    assert not _fresh(_fly(legacy=True))


def test_incarnations_cross_the_wire() -> None:
    assert _fresh(_fly(wire=True))


def test_a_message_of_the_old_life_is_stale() -> None:
    """A message of the old life arriving after the restart is dropped (counted as stale) and
    changes nothing."""
    clean, zombie = _fly(), _fly(zombie=True)
    assert all(np.array_equal(clean.estimates[k], zombie.estimates[k]) for k in clean.estimates)
    for i in range(N):
        if i != RESTARTED:
            assert zombie.agents[i].stale_messages == 1
            assert zombie.agents[i].dropped_messages == 1
    assert zombie.agents[RESTARTED].stale_messages == 0


def test_a_running_sum_made_with_another_incarnation_is_not_taken() -> None:
    """A neighbour's ``Q_ji`` made with another life of the receiver is not used; one made with
    its own life is; one that does not say is (an older sender)."""
    est = ConsensusEstimator(0, PARAMS)
    zeta = np.zeros(18)
    est.step(10, zeta, [])  # incarnation 10

    def from_1(round_: int, q: float, tag: int | None) -> ConsensusMessage:
        return ConsensusMessage(
            sender=1,
            round=round_,
            gamma=np.zeros(18),
            edge_sums={0: np.full(18, q)},
            heard=frozenset({0}),
            degree=1,
            incarnation=3,
            edge_incarnations=None if tag is None else {0: tag},
        )

    est.step(11, zeta, [from_1(10, 0.0, 10)])  # heard: from round 11 on, both heard each other
    est.step(12, zeta, [from_1(11, 0.0, 10)])  # the edge integrates (equal gammas: adds 0)
    assert est.edges == (1,)
    est.step(13, zeta, [from_1(12, 5.0, 4)])  # made with incarnation 4 of drone 0: not taken
    assert np.allclose(est.edge_sum(1), 0.0)
    est.step(14, zeta, [from_1(13, 5.0, 10)])  # made with this life: taken
    assert np.allclose(est.edge_sum(1), -2.5)
    est.step(15, zeta, [from_1(14, 7.0, None)])  # not said: taken (own sum moved a little)
    assert -3.5 < est.edge_sum(1).max() < -3.3


def test_batch_restart_of_a_row_is_a_fresh_estimator() -> None:
    """An agent restarted inside its process (BatchConsensus.restart) is, from then on, exactly
    a new estimator of its own, and the other rows of the batch do not notice."""
    zeta = _zeta()
    batch = BatchConsensus(tuple(range(N)), PARAMS)
    alone = {i: ConsensusEstimator(i, PARAMS) for i in range(N)}
    inbox_b: dict[int, list[ConsensusMessage]] = {i: [] for i in range(N)}
    inbox_a: dict[int, list[ConsensusMessage]] = {i: [] for i in range(N)}
    for r in range(150):
        if r == 80:
            batch.restart(RESTARTED)
            alone[RESTARTED] = ConsensusEstimator(RESTARTED, PARAMS)
        gamma, outs = batch.step(
            list(range(N)), r, zeta, [inbox_b[i] for i in range(N)], [None] * N
        )
        single = [alone[i].step(r, zeta[i], inbox_a[i]) for i in range(N)]
        for i in range(N):
            assert np.array_equal(gamma[i], single[i].estimate), (r, i)
            assert outs[i].message.incarnation == single[i].message.incarnation
        for inboxes, msgs in (
            (inbox_b, [o.message for o in outs]),
            (inbox_a, [o.message for o in single]),
        ):
            for i in range(N):
                inboxes[i] = [m for m in msgs if m.sender != i]
    assert batch.incarnation(RESTARTED) == 80
    assert batch.incarnation(0) == 0


def test_an_observing_row_follows_its_neighbours_without_counting() -> None:
    """A listening row (a returning agent still climbing back) says it hears nobody and sends no
    sums: no neighbour integrates an edge with it, so the others' average is their own, and its
    estimate follows theirs; restarted, it is a member like any other."""
    zeta = _zeta() / 100.0  # a few m: away from the tanh saturation
    batch = BatchConsensus(tuple(range(N)), PARAMS)
    batch.set_observing(RESTARTED, True)
    inbox: dict[int, list[ConsensusMessage]] = {i: [] for i in range(N)}
    others = [i for i in range(N) if i != RESTARTED]
    gamma = np.zeros((N, 18))
    for r in range(300):
        if r == 200:
            batch.restart(RESTARTED)  # a member from now on
        gamma, outs = batch.step(list(range(N)), r, zeta, [inbox[i] for i in range(N)], [None] * N)
        msgs = [o.message for o in outs]
        if r < 200:
            mine = msgs[RESTARTED]
            assert mine.heard == frozenset() and len(mine.edge_sums) == 0 and mine.degree == 0
            assert all(RESTARTED not in m.edge_sums for m in msgs)
            assert all(RESTARTED in m.heard for m in msgs if m.sender != RESTARTED and r > 1)
        if r == 199:
            own_mean = zeta[others].mean(axis=0)
            scale = np.abs(own_mean).max()
            assert np.abs(gamma[others] - own_mean).max() < 1e-3 * scale
            assert np.abs(gamma[RESTARTED] - own_mean).max() < 1e-3 * scale
        for i in range(N):
            inbox[i] = [m for m in msgs if m.sender != i]
    mean = zeta.mean(axis=0)
    assert np.abs(gamma - mean).max() < 0.02 * np.abs(mean).max()
    assert batch.incarnation(RESTARTED) == 200
