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

Not in ALGORITHM.md: *a channel scale*. ``tanh`` caps each edge's rate at ``rho`` per channel
unit, and the second-moment channels of a large swarm are hundreds of m^2 (a 40 m grid): with the
cap above, 250 drones at range 6 m took 30 s to agree, almost all of it saturated. Each channel k
therefore runs with ``rho_k = rho s_k`` and ``c_k = c / s_k``, ``s_k = L`` for the first moments
and ``L^2`` for the second (``L = channel_scale_m``, default 10 m): the same linear gain
``f rho_k c_k`` (so the step bound and the cap are unchanged), but saturation only beyond ``L``
metres (``L^2``) of disagreement. Measured (bench/settling.py, range 6 m): N = 100 settles in
1.4 s instead of 8.3 s, N = 250 in 3.6 s instead of 30 s; the paper flight's figures do not change
(shape RMS 0.0947 -> 0.0951 m^2, the rest equal to the printed digits). The increments stay
bounded (``rho dt L^2`` per tick on a second moment), so a wild neighbour value still moves an
estimate only so fast.

Not in ALGORITHM.md: *delay-scaled gain*. The increment for round q made at round r is divided by
the lag ``r - q`` (1 with the normal one-tick delay). A message delay lengthens the feedback loop
and the fixed gain then oscillates (measured on 9 drones, full graph: unstable from 40 ms extra
delay at 50 Hz); dividing by the lag keeps it converging (slower, as the lag grows) up to the
history (``history_ticks``). The two ends may then integrate different amounts on an edge, which
rule 1 makes harmless: ``eta_ij`` is the average of both ends' sums, antisymmetric whatever each
end added.

Rule 3's "heard" is by *arrival*: a peer is heard while a message of it (of any round within the
history) arrived in the last ``heard_timeout_ticks`` rounds — not while its newest round is that
recent. A link that delivers every round but late (a 100 ms delay is 5 rounds at 50 Hz) is up,
and rule 2 pairs its late values with the own values of their round; judged by the message's
round it was down for both ends, and a swarm moving under such a delay flew on frozen edges
(issue 14's delay drill: estimates 137 % off, two drones 0.42 m apart).

Not in ALGORITHM.md: *incarnations* (issue 14, rejoin). A restarted agent (same drone id) must
never have its new running sums mixed with the old ones, on either end of an edge, even when it
comes back before its neighbours' liveliness view has dropped it. Every message carries the
sender's ``incarnation`` (the round of its agent's first step: a restarted agent starts at a later
round, so a later life has a larger number) and, per edge sum ``Q_sender,j``, the incarnation of
j that sum was made with (``edge_incarnations``). A receiver keeps the newest incarnation heard
per peer: a message of an older one is dropped (counted as stale), and one of a newer one drops
every state towards that peer first (sums, edge, heard rounds, waiting values) and starts a new
edge; a ``Q_ji`` is taken only when it was made with the receiver's own current incarnation.
A sender of an older build says neither (incarnation 0, no edge incarnations): it is heard as
before.

Pure and I/O-free: no clock, no transport; time enters only as the round number.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from drone_agent.core.consensus.estimator import BatchConsensus
from drone_agent.core.consensus.params import STEP_BOUND, ConsensusOutput, ConsensusParams
from drone_agent.core.moments import N_CHANNELS
from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage, EdgeSums

__all__ = [
    "STEP_BOUND",
    "ConsensusEstimator",
    "ConsensusMessage",
    "ConsensusOutput",
    "ConsensusParams",
    "EdgeSums",
]


class ConsensusEstimator:
    """The consensus state of one agent: a
    :class:`~drone_agent.core.consensus.estimator.BatchConsensus` of one row. Call :meth:`step`
    once per round, rounds increasing."""

    def __init__(self, agent_id: int, params: ConsensusParams) -> None:
        self.agent_id = agent_id
        self.params = params
        self._batch = BatchConsensus((agent_id,), params)

    @property
    def dropped_messages(self) -> int:
        """Messages ignored: our own, older than the history, or of an earlier incarnation of
        their sender."""
        return self._batch.dropped_messages[0]

    @property
    def stale_messages(self) -> int:
        """Messages ignored because a later incarnation of their sender was heard."""
        return self._batch.stale_messages[0]

    @property
    def incarnation(self) -> int | None:
        """This agent's incarnation (the round of its first step); None before it."""
        return self._batch.incarnation(0)

    @property
    def edges(self) -> tuple[int, ...]:
        """Neighbours with edge state (integrating or frozen), sorted."""
        return self._batch.edges(0)

    def edge_sum(self, neighbour: int) -> FloatArray:
        """``eta_ij`` (18,) currently used for the edge to ``neighbour`` (zeros if none)."""
        return self._batch.edge_sum(0, neighbour)

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
        zeta_row = np.asarray(zeta, dtype=float).reshape(1, N_CHANNELS)
        return self._batch.step((0,), round_, zeta_row, [inbox], [members])[1][0]
