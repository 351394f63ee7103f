"""The consensus step's compiled parts are the general code bit for bit: the filing of the usual
step (kernels.receive_common) leaves every state and output exactly as the general filing does,
over random radios that delay, lose, duplicate and reorder messages, membership views that change,
restarted and listening rows, rows that skip a round and messages rebuilt outside their step (read
one by one); the end of a step (heard-sets, rule 5's check, estimates, history) is numpy's
formula."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drone_agent.core.consensus import estimator
from drone_agent.core.consensus.estimator import BatchConsensus
from drone_agent.core.consensus.scalar import ConsensusParams
from protocols.wire.consensus_message import ConsensusMessage

N = 7
STATE = (
    "_q_own", "_q_recv", "_edge", "_edge_round", "_peer", "_latest", "_arrived", "_q_for_me",
    "_has_q_for_me", "_inc", "_own_inc", "_hist_round", "_hist_gamma", "_hist_largest",
    "_hist_degree", "_hist_heard",
)  # fmt: skip


#: The agents' processes: drone 0 alone (as one process per drone), the others together.
GROUPS = ((0,), tuple(range(1, N)))


class _Twin:
    """The batches of :data:`GROUPS` and the messages in flight to their rows (arrival round ->
    per drone, its messages)."""

    def __init__(self, params: ConsensusParams) -> None:
        self.batches = [BatchConsensus(ids, params) for ids in GROUPS]
        self.flight: dict[int, list[list[ConsensusMessage]]] = {}

    def of(self, drone: int) -> tuple[BatchConsensus, int]:
        """The batch of ``drone`` and its row there."""
        group = 0 if drone in GROUPS[0] else 1
        return self.batches[group], GROUPS[group].index(drone)

    def step(
        self, rows: list[int], r: int, zeta: np.ndarray, members: frozenset[int] | None
    ) -> tuple[np.ndarray, list[ConsensusMessage], list[tuple[int, ...]], np.ndarray]:
        """Step drones ``rows`` (ascending) in their batches; the outputs in drone order."""
        boxes = self.flight.pop(r, [[] for _ in range(N)])
        for i in range(N):  # a drone that skips the round gets its mail next time
            if i not in rows:
                self.flight.setdefault(r + 1, [[] for _ in range(N)])[i][:0] = boxes[i]
        gammas, messages, active, dis = [], [], [], []
        for group, batch in zip(GROUPS, self.batches, strict=True):
            mine = [i for i in rows if i in group]
            if not mine:
                continue
            g, m, a, d = batch.step_messages(
                [group.index(i) for i in mine], r, zeta[mine] + 0.01 * r,
                [boxes[i] for i in mine], [members] * len(mine),
            )  # fmt: skip
            gammas.append(g)
            messages += m
            active += a
            dis.append(d)
        return np.concatenate(gammas), messages, active, np.concatenate(dis)


def _general(*_args: object) -> bool:
    return False


def _run(seed: int, monkeypatch: pytest.MonkeyPatch) -> tuple[int, int]:
    rng = np.random.default_rng(seed)
    params = ConsensusParams(history_ticks=6, heard_timeout_ticks=3)
    fast, slow = _Twin(params), _Twin(params)
    fast_calls = [0, 0]  # (usual steps, steps filed the general way)
    kernel = estimator.receive_common

    def counted(*args: object) -> bool:
        took: bool = kernel(*args)
        fast_calls[0 if took else 1] += 1
        return took

    zeta = rng.normal(size=(N, 18)) * 3.0
    members: frozenset[int] | None = None
    blackout: set[int] = set()  # rounds whose messages are all lost
    for r in range(200):
        if rng.random() < (0.3 if members is not None and len(members) < N else 0.03):
            members = (
                frozenset(range(N))
                if rng.random() < 0.5
                else frozenset(rng.choice(N, size=N - 1, replace=False).tolist())
            )
        # (drone 0 alone in its batch hears its neighbours' sums of its old life)
        restarted = int(rng.integers(2) * rng.integers(N)) if rng.random() < 0.05 else None
        listening = int(rng.integers(N)) if rng.random() < 0.01 else None
        on = bool(rng.random() < 0.5)
        for twin in (fast, slow):
            if restarted is not None:
                batch, row = twin.of(restarted)
                batch.restart(row)
            if listening is not None:
                batch, row = twin.of(listening)
                batch.set_observing(row, on)
        rows = [i for i in range(N) if rng.random() > 0.01]
        outs = []
        for twin, patched in ((fast, counted), (slow, _general)):
            monkeypatch.setattr(estimator, "receive_common", patched)
            outs.append(twin.step(rows, r, zeta, members))
        (g_fast, m_fast, a_fast, d_fast), (g_slow, m_slow, a_slow, d_slow) = outs
        assert np.array_equal(g_fast, g_slow), r
        assert a_fast == a_slow and np.array_equal(d_fast, d_slow), r
        for b_fast, b_slow in zip(fast.batches, slow.batches, strict=True):
            for name in STATE:
                assert np.array_equal(getattr(b_fast, name), getattr(b_slow, name)), (r, name)
            assert b_fast.dropped_messages == b_slow.dropped_messages, r
            assert b_fast.stale_messages == b_slow.stale_messages, r
        # the radio: per (message, receiver), lost, delayed, sent twice, or rebuilt (in one
        # round of ten; else every message arrives once, the next round); now and then a whole
        # round arrives late, alone (the round before its arrival lost): older than what its
        # receivers heard since, or older than their history
        noisy = rng.random() < 0.1
        if r in blackout:
            continue
        late = 1
        if rng.random() < 0.08:
            late = int(rng.integers(3, 10))
            blackout.add(r + late - 1)
        for k in range(len(rows)):
            for i in range(N):
                if i == rows[k] and not (noisy and rng.random() < 0.05):  # own, back
                    continue
                if noisy and rng.random() < 0.1:
                    continue  # lost
                delay = int(rng.integers(0, 9)) if noisy and rng.random() < 0.2 else late
                copies = 2 if noisy and rng.random() < 0.05 else 1
                rebuilt = noisy and rng.random() < 0.05
                for twin, msgs in ((fast, m_fast), (slow, m_slow)):
                    m = msgs[k]
                    if rebuilt:  # not its step's own objects: read one by one
                        m = dataclasses.replace(m, gamma=np.array(m.gamma))
                    box = twin.flight.setdefault(r + delay, [[] for _ in range(N)])[i]
                    box.extend([m] * copies)
        if rng.random() < 0.05:  # a reordered inbox
            for twin in (fast, slow):
                boxes = twin.flight.get(r + 1)
                if boxes:
                    twin.flight[r + 1] = [box[::-1] for box in boxes]
    return fast_calls[0], fast_calls[1]


@pytest.mark.parametrize("seed", range(6))
def test_the_usual_step_is_filed_as_the_general_way_files_it(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    usual, general = _run(seed, monkeypatch)
    assert usual > 30 and general > 5, (usual, general)  # both ways were taken


def test_the_step_settles_as_numpy_would() -> None:
    """The compiled end of a step (heard-sets, rule 5's check, the estimates and the history) is
    numpy's formula bit for bit, NaN included."""
    from drone_agent.core.consensus.kernels import any_dead, edge_sums, heard_now, settle

    rng = np.random.default_rng(3)
    k, m, h, ch = 6, 9, 5, 18
    rows = np.array([4, 0, 2, 5], dtype=np.intp)
    peer, edge = rng.random((k, m)) < 0.5, rng.random((k, m)) < 0.5
    arrived = rng.integers(0, 20, size=(k, m))
    mask = rng.random((rows.shape[0], m)) < 0.8
    assert any_dead(rows, peer, edge, mask) == bool(((peer[rows] | edge[rows]) & ~mask).any())
    assert not any_dead(rows, peer, edge, np.ones_like(mask))
    heard, degree = np.empty((rows.shape[0], m), dtype=bool), np.empty(rows.shape[0], np.int64)
    heard_now(rows, peer, arrived, 12, heard, degree)
    expected = peer[rows] & (arrived[rows] >= 12)
    assert np.array_equal(heard, expected) and np.array_equal(degree, expected.sum(axis=1))
    q = [rng.normal(size=(k, m, ch)) for _ in range(3)]
    has = rng.random((k, m)) < 0.5
    zeta = rng.normal(size=(rows.shape[0], ch))
    zeta[1, 3] = np.nan
    hist = [np.zeros((k, h), np.int64), np.zeros((k, h, ch)), np.zeros((k, h)),
            np.zeros((k, h), np.int64), np.zeros((k, h, m), bool)]  # fmt: skip
    total = np.zeros((rows.shape[0], ch))
    recv = q[2].copy()
    edge_sums(rows, edge, has, q[0], q[1], recv, total)
    gamma = np.zeros((rows.shape[0], ch))
    settle(rows, 17, 0.7 * 0.5, zeta, edge, has, q[0], q[1], q[2], heard, degree, *hist, gamma)
    assert np.array_equal(gamma, 0.7 * 0.5 * total + zeta, equal_nan=True)
    assert np.array_equal(q[2], recv)  # the Q_ji refreshed (rule 1)
    slot = 17 % h
    assert (hist[0][rows, slot] == 17).all()
    assert np.array_equal(hist[1][rows, slot], gamma, equal_nan=True)
    assert np.array_equal(hist[2][rows, slot], np.abs(gamma).max(axis=1), equal_nan=True)
    assert np.isnan(hist[2][rows[1], slot])
    assert np.array_equal(hist[3][rows, slot], degree)
    assert np.array_equal(hist[4][rows, slot], heard)
