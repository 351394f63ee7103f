"""Edge-based dynamic average consensus as a per-agent state machine (ALGORITHM.md §3).

Each tick (round ``r``, the control-tick number of the vehicles' common simulated time) an agent
takes its own channels ``zeta_i`` and the neighbour messages that arrived, and returns its estimate
``gamma_i`` of the swarm average of the channels and its outgoing message. Per channel and edge::

    eta_ij += -rho_e tanh(c (gamma_i - gamma_j)) dt,     gamma_i = f sum_j eta_ij + zeta_i

made safe for a real network by the rules of ALGORITHM.md §3:

1. *Antisymmetry by construction*: the agent keeps the running sum ``Q_ij`` of its own increments
   on each edge, sends it, and uses ``eta_ij = (Q_ij - Q_ji_received) / 2``.
2. *Paired values*: the increment for round q uses ``gamma_i`` and ``gamma_j`` of that same round q
   (messages carry their round; the agent keeps a short history of its own values). A round whose
   partner value never arrives is skipped on that edge.
3. *Both ends hear each other*: a round is integrated only if, in that round, each end listed the
   other in its heard-set (heard within ``heard_timeout_ticks``). A one-way link is down for both.
4. *Link lost: freeze*: edge state is kept while a link is down and resumes when it returns.
5. *Partner dead: discard*: edge state to a partner is dropped once the membership view (liveliness)
   no longer lists it.
6. The discrete-time step bound ``f rho c dt lambda_max(L) <= 0.7``, or a degree-normalised gain
   ``rho_e = rho / max(d_i, d_j)`` (both ends use the degrees advertised for the round).

Not in ALGORITHM.md: *a step cap that scales*. Linearised, one round maps ``gamma`` to
``(I - f c dt L_rho) gamma`` (``L_rho``: the Laplacian weighted by the edge gains), which diverges
once ``f c dt lambda_max(L_rho) > 2``. A fixed ``rho`` meets rule 6 on the paper's 9 drones but not
on a larger, denser radio graph: measured (bench/settling.py, 2.5 m grid, rho = 2), at range 6 m
(degree up to 20, step gain 1.87) N = 100 settles in 5 s only because it sits just under 2, and at
range 10 m (degree 44, step gain 3.8) N = 49 and N = 100 never settle. So each edge's gain is
capped: ``rho_e = min(rho, rho_cap / max(d_i, d_j))`` with ``rho_cap = max_step_gain / (2 f c dt)``.
Every row of ``L_rho`` then sums to at most ``rho_cap``, so by Gershgorin ``f c dt lambda_max <=
max_step_gain`` (default 1.4, 30 % inside the stability limit) on any graph. The cap binds only
where the degree exceeds ``rho_cap / rho`` (8.75 at the defaults: never on the paper's 9 drones,
whose gains are unchanged); where it binds, the cap is the largest gain the bound allows.

Not in ALGORITHM.md: *delay-scaled gain*. The increment for round q made at round r is divided by
the lag ``r - q`` (1 with the normal one-tick delay). A message delay lengthens the feedback loop
and the fixed gain then oscillates (measured on 9 drones, full graph: unstable from 40 ms extra
delay at 50 Hz); dividing by the lag keeps it converging up to the heard-set timeout. The two ends
may then integrate different amounts on an edge, which rule 1 makes harmless: ``eta_ij`` is the
average of both ends' sums, antisymmetric whatever each end added.

Pure and I/O-free: no clock, no transport; time enters only as the round number.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from drone_agent.moments import N_CHANNELS
from protocols.frames import FloatArray

STEP_BOUND = 0.7


@dataclass(frozen=True)
class ConsensusParams:
    """Gains and timing of the estimator. ``dt_s`` is the round period (control tick)."""

    rho: float = 2.0
    c: float = 1.0
    f: float = 2.0
    dt_s: float = 0.02
    degree_normalised: bool = False
    heard_timeout_ticks: int = 5
    history_ticks: int = 25
    max_step_gain: float = 1.4

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        for name in ("rho", "c", "f", "dt_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"consensus.{name} must be a positive number, got {value!r}")
        if not (np.isfinite(self.max_step_gain) and 0 <= self.max_step_gain < 2):
            raise ValueError(
                f"consensus.max_step_gain must be in [0, 2), got {self.max_step_gain!r}"
            )
        if self.heard_timeout_ticks < 1:
            raise ValueError("consensus.heard_timeout_ticks must be at least 1")
        if self.history_ticks < self.heard_timeout_ticks:
            raise ValueError("consensus.history_ticks must be at least heard_timeout_ticks")

    @property
    def rho_cap(self) -> float:
        """``rho_e * max(d_i, d_j)`` never exceeds this (the step cap of the module doc); inf
        without a cap (``max_step_gain`` 0)."""
        if self.max_step_gain <= 0:
            return float("inf")
        return self.max_step_gain / (2.0 * self.f * self.c * self.dt_s)

    def step_gain(self, lambda_max: float) -> float:
        """``f rho c dt lambda_max(L)`` of the fixed-gain update on a graph with that largest
        Laplacian eigenvalue; keep it at or below :data:`STEP_BOUND` on the worst graph."""
        return self.f * self.rho * self.c * self.dt_s * lambda_max

    def within_step_bound(self, lambda_max: float) -> bool:
        """The discrete-time step bound of ALGORITHM.md §3 rule 6.

        Degree-normalised gain: rho c <= 8."""
        if self.degree_normalised:
            return self.rho * self.c <= 8.0
        return self.step_gain(lambda_max) <= STEP_BOUND


@dataclass(frozen=True)
class ConsensusMessage:
    """What an agent sends every round.

    ``gamma`` (18,): the sender's estimate in this round; ``edge_sums``: the running sums
    ``Q_sender,j`` of the sender's increments per neighbour j; ``heard``: who the sender heard
    recently (as of this round); ``degree``: ``len(heard)``, for the degree-normalised gain;
    ``ready_hops``: the sender's settled level (drone_agent.flight_phase.SwarmSettled).
    ``position_ned_m`` (3,) and ``velocity_ned_m_s`` (3,): where the sender was and how fast it
    moved in this round (NED), for the receivers' separation layer (drone_agent/separation.py);
    None when not known (set by the wire decoder; the estimator does not use them).
    """

    sender: int
    round: int
    gamma: FloatArray
    edge_sums: Mapping[int, FloatArray]
    heard: frozenset[int]
    degree: int
    ready_hops: int = 0
    position_ned_m: FloatArray | None = None
    velocity_ned_m_s: FloatArray | None = None


@dataclass
class _Edge:
    q_own: FloatArray = field(default_factory=lambda: np.zeros(N_CHANNELS))
    q_received: FloatArray = field(default_factory=lambda: np.zeros(N_CHANNELS))
    last_round: int = -1


@dataclass
class _Peer:
    latest_round: int = -1
    q_for_me: FloatArray | None = None
    # round -> (gamma_j, degree_j, j heard me in that round)
    pending: dict[int, tuple[FloatArray, int, bool]] = field(default_factory=dict)


@dataclass(frozen=True)
class ConsensusOutput:
    """Result of one round: the estimate (18,) of the channel averages, the message to send, the
    neighbours whose edge integrated in this round (sorted), and the relative disagreement: the
    largest ``|gamma_i - gamma_j| / (1 + max(|gamma_i|, |gamma_j|))`` over the channels and the
    pairs integrated in this round (0 if none), small once the estimator has settled."""

    estimate: FloatArray
    message: ConsensusMessage
    active_neighbours: tuple[int, ...]
    disagreement: float = 0.0


class ConsensusEstimator:
    """The consensus state of one agent. Call :meth:`step` once per round, rounds increasing."""

    def __init__(self, agent_id: int, params: ConsensusParams) -> None:
        params.validate()
        self.agent_id = agent_id
        self.params = params
        self._edges: dict[int, _Edge] = {}
        self._peers: dict[int, _Peer] = {}
        # round -> (gamma_i, degree_i, heard_i)
        self._history: dict[int, tuple[FloatArray, int, frozenset[int]]] = {}
        self._last_round: int | None = None
        self._disagreement = 0.0
        self.dropped_messages = 0

    @property
    def edges(self) -> tuple[int, ...]:
        """Neighbours with edge state (integrating or frozen), sorted."""
        return tuple(sorted(self._edges))

    def edge_sum(self, neighbour: int) -> FloatArray:
        """``eta_ij`` (18,) currently used for the edge to ``neighbour`` (zeros if none)."""
        edge = self._edges.get(neighbour)
        if edge is None:
            return np.zeros(N_CHANNELS)
        return 0.5 * (edge.q_own - edge.q_received)

    def step(
        self,
        round_: int,
        zeta: FloatArray,
        inbox: Iterable[ConsensusMessage],
        members: frozenset[int] | None = None,
    ) -> ConsensusOutput:
        """Advance to round ``round_`` with own channels ``zeta`` (18,) and the messages received
        since the last call. ``members``: the live agents (liveliness view); partners not in it
        are discarded (rule 5). None keeps every partner."""
        if self._last_round is not None and round_ <= self._last_round:
            raise ValueError(f"round {round_} is not after round {self._last_round}")
        self._last_round = round_
        for msg in sorted(inbox, key=lambda m: (m.sender, m.round)):
            self._receive(msg, round_)
        if members is not None:
            for j in [j for j in set(self._peers) | set(self._edges) if j not in members]:
                self._edges.pop(j, None)
                self._peers.pop(j, None)
        timeout = self.params.heard_timeout_ticks
        heard = frozenset(
            j for j, peer in self._peers.items() if peer.latest_round >= round_ - timeout
        )
        self._disagreement = 0.0
        active = tuple(j for j in sorted(self._peers) if self._integrate(j, round_))
        eta_total = np.zeros(N_CHANNELS)
        for j, edge in self._edges.items():
            peer = self._peers.get(j)
            if peer is not None and peer.q_for_me is not None:
                edge.q_received = peer.q_for_me
            eta_total += edge.q_own - edge.q_received
        gamma = self.params.f * 0.5 * eta_total + np.asarray(zeta, dtype=float)
        self._history[round_] = (gamma, len(heard), heard)
        self._history.pop(round_ - self.params.history_ticks, None)
        message = ConsensusMessage(
            sender=self.agent_id,
            round=round_,
            gamma=gamma,
            edge_sums={j: e.q_own.copy() for j, e in sorted(self._edges.items())},
            heard=heard,
            degree=len(heard),
        )
        return ConsensusOutput(gamma, message, active, self._disagreement)

    def _receive(self, msg: ConsensusMessage, round_: int) -> None:
        if msg.sender == self.agent_id or msg.round < round_ - self.params.history_ticks:
            self.dropped_messages += 1
            return
        peer = self._peers.setdefault(msg.sender, _Peer())
        peer.pending[msg.round] = (msg.gamma, msg.degree, self.agent_id in msg.heard)
        if msg.round > peer.latest_round:
            peer.latest_round = msg.round
            q = msg.edge_sums.get(self.agent_id)
            peer.q_for_me = None if q is None else np.asarray(q, dtype=float)

    def _integrate(self, j: int, round_: int) -> bool:
        """Integrate every pending round of peer j that can be paired; True if any was."""
        peer = self._peers[j]
        edge = self._edges.get(j)
        done = False
        for q in sorted(peer.pending):
            if q >= round_:
                continue
            gamma_j, degree_j, j_heard_me = peer.pending.pop(q)
            own = self._history.get(q)
            if own is None or (edge is not None and q <= edge.last_round):
                continue
            gamma_i, degree_i, heard_i = own
            if not (j_heard_me and j in heard_i):
                continue
            if edge is None:
                edge = self._edges[j] = _Edge()
            rho = self.params.rho
            if self.params.degree_normalised:
                rho = rho / max(degree_i, degree_j, 1)
            rho = min(rho, self.params.rho_cap / max(degree_i, degree_j, 1))
            rho = rho / max(round_ - q, 1)  # delay-scaled gain (module doc)
            diff = gamma_i - gamma_j
            scale = 1.0 + max(float(np.abs(gamma_i).max()), float(np.abs(gamma_j).max()))
            self._disagreement = max(self._disagreement, float(np.abs(diff).max()) / scale)
            edge.q_own = edge.q_own - rho * self.params.dt_s * np.tanh(self.params.c * diff)
            edge.last_round = q
            done = True
        return done
