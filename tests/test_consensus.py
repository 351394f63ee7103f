"""The consensus estimator over an in-memory radio: conservation, convergence, drop-outs, and
no lasting bias under delay, loss, one-way links and cuts (ALGORITHM.md §3)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drone_agent.core.consensus.estimator import BatchConsensus
from drone_agent.core.consensus.scalar import ConsensusEstimator, ConsensusParams
from gcs.reference.network import InProcessNetwork
from protocols.model.frames import FloatArray

Signal = Callable[[int], FloatArray]


def _ring_plus(n: int, extra: list[tuple[int, int]]) -> FloatArray:
    adj = np.zeros((n, n), dtype=bool)
    for i in range(n):
        adj[i, (i + 1) % n] = adj[(i + 1) % n, i] = True
    for i, j in extra:
        adj[i, j] = adj[j, i] = True
    return adj


class Harness:
    """N estimators on an in-memory radio with a fixed topology (``adj``): one batch of N rows,
    as an agent process hosts its drones (each row steps as a ConsensusEstimator of its own
    would, bit for bit: tests/test_batch_core.py), ~9x fewer calls than N estimators."""

    def __init__(self, adj: FloatArray, params: ConsensusParams | None = None, seed: int = 0):
        self.adj = adj
        self.n = adj.shape[0]
        self.params = params or ConsensusParams()
        self.batch = BatchConsensus(tuple(range(self.n)), self.params)
        self.net = InProcessNetwork(self.n, 1.0, np.random.default_rng(seed))
        self.round = 0

    def step(
        self, zeta: FloatArray, members: frozenset[int] | None = None
    ) -> dict[int, FloatArray]:
        inboxes = self.net.receive(self.round)
        live = list(range(self.n)) if members is None else sorted(members)
        _, outs = self.batch.step(
            live, self.round, zeta[live], [inboxes[i] for i in live], [members] * len(live)
        )
        self.net.send(self.round, [o.message for o in outs], self.adj)
        self.round += 1
        return {i: o.estimate for i, o in zip(live, outs, strict=True)}

    def run(
        self, signal: Signal, rounds: int, members: frozenset[int] | None = None
    ) -> dict[int, FloatArray]:
        est: dict[int, FloatArray] = {}
        for _ in range(rounds):
            est = self.step(signal(self.round), members)
        return est


def _static(n: int, seed: int = 0) -> tuple[FloatArray, Signal]:
    zeta = np.random.default_rng(seed).normal(size=(n, 18)) * 3.0
    return zeta, lambda _r: zeta


def _max_error(est: dict[int, FloatArray], target: FloatArray) -> float:
    return max(float(np.abs(e - target).max()) for e in est.values())


#: Rounds an estimate must stay within a convergence bar before a run stops early.
STAY_ROUNDS = 100


def _converge(
    h: Harness,
    signal: Signal,
    target: FloatArray,
    tol: float,
    rounds: int,
    members: frozenset[int] | None = None,
) -> dict[int, FloatArray]:
    """Run at most ``rounds`` rounds, stopping once every estimate has stayed within ``tol`` of
    ``target`` for STAY_ROUNDS rounds in a row (the bar is the caller's assertion; this only
    saves the rounds after it is met and held)."""
    est: dict[int, FloatArray] = {}
    held = 0
    for _ in range(rounds):
        est = h.step(signal(h.round), members)
        held = held + 1 if _max_error(est, target) < tol else 0
        if held >= STAY_ROUNDS:
            break
    return est


@st.composite
def _connected_graphs(draw: st.DrawFn) -> FloatArray:
    n = draw(st.integers(min_value=2, max_value=9))
    extra = draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), max_size=12))
    adj = _ring_plus(n, [(i, j) for i, j in extra if i != j])
    return adj


@settings(max_examples=40, deadline=None)
@given(adj=_connected_graphs(), seed=st.integers(0, 10_000))
def test_sum_is_conserved_on_every_tick(adj: FloatArray, seed: int) -> None:
    """Lossless radio with the one-tick delay: sum of estimates == sum of inputs, every tick,
    while the inputs change."""
    n = adj.shape[0]
    rng = np.random.default_rng(seed)
    h = Harness(adj)
    base = rng.normal(size=(n, 18)) * 5.0
    for r in range(120):
        zeta = base + np.sin(0.05 * r + np.arange(18)) * rng.normal(size=(n, 1))
        est = h.step(zeta)
        total = np.sum(list(est.values()), axis=0)
        np.testing.assert_allclose(total, zeta.sum(axis=0), rtol=0, atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(
    adj=_connected_graphs(),
    seed=st.integers(0, 10_000),
    loss=st.floats(0.0, 0.5),
    delay=st.integers(0, 3),
)
def test_no_lasting_bias_after_loss_and_delay(
    adj: FloatArray, seed: int, loss: float, delay: int
) -> None:
    """Whatever is lost or delayed, once the radio is clean again the estimates converge to the
    exact average: loss costs only in-flight mass, never accumulated bias."""
    n = adj.shape[0]
    zeta, signal = _static(n, seed)
    h = Harness(adj, seed=seed)
    h.net.conditions.loss = loss
    h.net.conditions.extra_delay_ticks = delay
    h.run(signal, 150)
    h.net.conditions.loss = 0.0
    h.net.conditions.extra_delay_ticks = 0
    est = _converge(h, signal, zeta.mean(axis=0), 1e-6, 1500)
    assert _max_error(est, zeta.mean(axis=0)) < 1e-6


@pytest.mark.parametrize("adj", [_ring_plus(9, []), ~np.eye(9, dtype=bool)], ids=["ring", "full"])
def test_converges_on_static_signals(adj: FloatArray) -> None:
    zeta, signal = _static(9)
    est = _converge(Harness(adj), signal, zeta.mean(axis=0), 1e-9, 2500)
    assert _max_error(est, zeta.mean(axis=0)) < 1e-9


def test_tracks_moving_signals() -> None:
    """Inputs moving at up to ~0.5 units/s: every estimate stays within 0.05 of the average."""
    n = 9
    rng = np.random.default_rng(3)
    base = rng.normal(size=(n, 18)) * 3.0
    amp = rng.normal(size=(n, 1))

    def signal(r: int) -> FloatArray:
        return base + amp * np.sin(0.2 * r * 0.02 + np.arange(18))

    h = Harness(_ring_plus(n, [(0, 4), (2, 7), (3, 6)]))
    worst = 0.0
    for _ in range(3000):
        zeta = signal(h.round)
        est = h.step(zeta)
        if h.round > 1000:
            worst = max(worst, _max_error(est, zeta.mean(axis=0)))
    assert worst < 0.05


def test_drop_out_converges_to_the_survivors_average() -> None:
    n = 9
    zeta, signal = _static(n, 5)
    h = Harness(~np.eye(n, dtype=bool))
    h.run(signal, 500)
    survivors = frozenset(range(n)) - {1}
    target = zeta[sorted(survivors)].mean(axis=0)
    est = _converge(h, signal, target, 1e-9, 2000, members=survivors)
    assert set(est) == set(survivors)
    assert _max_error(est, target) < 1e-9


def test_delay_loss_and_one_way_link_leave_no_bias() -> None:
    """One-tick delay + 1 extra tick, 5 % loss and a one-way link, on a moving signal: the error
    stays at the tracking lag (the broken prototype figures were 0.29-0.47 of bias)."""
    n = 9
    rng = np.random.default_rng(7)
    base = rng.normal(size=(n, 18)) * 3.0
    h = Harness(_ring_plus(n, [(0, 4), (2, 7), (3, 6), (1, 5)]), seed=7)
    h.net.conditions.loss = 0.05
    h.net.conditions.extra_delay_ticks = 1
    h.net.conditions.cut.add((2, 3))  # 2 -> 3 is cut, 3 -> 2 still delivers: one-way
    errors = []
    for _ in range(4000):
        zeta = base + np.sin(0.004 * h.round + np.arange(18))[None, :]
        est = h.step(zeta)
        errors.append(_max_error(est, zeta.mean(axis=0)))
    late = np.array(errors[2000:])
    assert late.max() < 0.02
    # and no drift: the second half is no worse than the first half of the settled window
    assert late[1000:].mean() < 2.0 * late[:1000].mean() + 1e-3


def test_link_cut_freezes_and_resumes_without_jump() -> None:
    n = 6
    zeta, signal = _static(n, 9)
    h = Harness(~np.eye(n, dtype=bool))
    h.run(signal, 800)
    h.net.conditions.cut |= {(0, 1), (1, 0)}
    est = _converge(h, signal, zeta.mean(axis=0), 1e-6, 800)
    assert _max_error(est, zeta.mean(axis=0)) < 1e-6
    h.net.conditions.cut.clear()
    est = _converge(h, signal, zeta.mean(axis=0), 1e-9, 800)
    assert _max_error(est, zeta.mean(axis=0)) < 1e-9


def test_one_way_link_is_down_for_both_ends() -> None:
    """Only 1 -> 0 delivers: neither end integrates on that edge."""
    adj = np.zeros((3, 3), dtype=bool)
    adj[1, 0] = True
    adj[1, 2] = adj[2, 1] = True
    h = Harness(adj)
    _, signal = _static(3)
    h.run(signal, 50)
    assert h.batch.edges(0) == ()
    assert 0 not in h.batch.edges(1)


def test_rounds_must_increase() -> None:
    est = ConsensusEstimator(0, ConsensusParams())
    est.step(5, np.zeros(18), [])
    with pytest.raises(ValueError, match="not after"):
        est.step(5, np.zeros(18), [])


def test_step_bound() -> None:
    params = ConsensusParams(rho=2.0, c=1.0, f=2.0, dt_s=0.02)
    assert params.within_step_bound(8.0)
    paper = ConsensusParams(rho=7.29, c=2.0, f=2.0, dt_s=0.02)
    assert not paper.within_step_bound(8.0)
    assert ConsensusParams(rho=8.0, degree_normalised=True).within_step_bound(40.0)


@pytest.mark.parametrize("extra", [1, 2, 3, 5, 8])
def test_converges_under_longer_delays(extra: int) -> None:
    """20-160 ms of extra delay at 50 Hz on a full graph of 9: the delay-scaled gain keeps the
    estimator converging (a fixed gain oscillates from 2 extra ticks on); from 5 extra ticks every
    message is older than the heard-set timeout when it arrives, and the link is still heard
    (by arrival), so the estimates still meet."""
    n = 9
    zeta, signal = _static(n, 3)
    h = Harness(~np.eye(n, dtype=bool))
    h.net.conditions.extra_delay_ticks = extra
    # the lag-scaled gain is slower
    est = _converge(h, signal, zeta.mean(axis=0), 1e-9, 600 if extra <= 3 else 2000)
    assert _max_error(est, zeta.mean(axis=0)) < 1e-9
