"""One drone's brain, pure: consensus estimate of the swarm descriptors and the formation
controller, from its own state, the shared plan and the neighbour messages of this round.

The same core runs in the in-process reference flight (``swarm simulate``) and inside each agent
process behind MAVLink and Zenoh adapters. No clock, no I/O: time is given by the round number and
the vehicle's simulated time.

Batched: :class:`BatchAgentCore` holds K agents (one row each) and advances any subset of them
in one call, as array operations over the rows: plan evaluation (once per distinct plan), the
channels, the consensus step (drone_agent/core/consensus/scalar.py), moments, one stacked
eigen-decomposition with the axes assigned to each row's desired axes, the formation controller's
acceleration (drone_agent/core/controller.py; the paper's cooperative field unless the scenario
names another), the rejoin climb and the separation layer acting on it, the controller's thrust and
attitude, and the setpoint checks (a controller's failure leaves its rows without a setpoint). Rows
never mix: each uses only its own vehicle state, plan, inbox, membership view and estimator state,
so a row gives the same output whichever rows share its call. :class:`AgentCore` is one row of it
(alone, the K = 1 case): there is one implementation.
The per-drone arithmetic of those steps runs as compiled loops over the rows
(drone_agent/core/jit_math.py), loaded once per process by :func:`warm_up`.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from drone_agent.core.consensus.estimator import BatchConsensus
from drone_agent.core.consensus.packing import Outgoing
from drone_agent.core.consensus.scalar import ConsensusParams
from drone_agent.core.controller import (
    ControllerInputs,
    ControllerSetup,
    CooperativeController,
    FormationController,
    call_acceleration,
    call_thrust_attitude,
    controller_name,
)
from drone_agent.core.cooperative import (
    CooperativeGains,
    euler_rate_matrix_batch,
    virtual_acceleration_batch,
)
from drone_agent.core.inboxes import as_inboxes
from drone_agent.core.moments import SwarmMoments, channels_batch, moments_from_averages_batch
from drone_agent.core.neighbours import NeighbourTable
from drone_agent.core.separation.filter import nobody_near
from drone_agent.core.separation.layer import SeparationConfig, SeparationLayer
from drone_agent.core.thrust_attitude import ThrustLimits, attitude_thrust_batch
from protocols.model.descriptor_vector import CENTRE, I_PITCH, I_ROLL, I_YAW, ORIENTATION
from protocols.model.descriptors import align_axes_batch, desired_axes_batch, frame_vector_batch
from protocols.model.frames import FloatArray
from protocols.model.trajectory import DescriptorTrajectory, StateTriple
from protocols.runtime.fast_dataclass import frozen_factory
from protocols.wire.consensus_message import ConsensusMessage


@dataclass(frozen=True)
class AgentConfig:
    """What one agent needs to know: gains, limits, the warm-up before it may arm, and when its
    estimate counts as settled: disagreement with its neighbours (ConsensusOutput) below
    ``settle_tolerance`` (or, with ``settle_plateau``, no longer falling over two windows of
    ``settle_window_ticks``: drone_agent/core/flight_phase.py) for ``settle_ticks`` ticks in a
    row with the same membership; the
    separation layer (drone_agent/core/separation/layer.py; None: off); the formation controller
    (``controller``, built with a :class:`~drone_agent.core.controller.ControllerSetup` carrying
    ``controller_options``; drone_agent/core/controller.py)."""

    consensus: ConsensusParams
    gains: CooperativeGains
    limits: ThrustLimits
    warmup_s: float = 3.0
    settle_ticks: int = 25
    settle_tolerance: float = 0.02
    settle_plateau: bool = False
    settle_window_ticks: int = 50
    separation: SeparationConfig | None = None
    controller: Callable[[ControllerSetup], FormationController] = CooperativeController
    controller_options: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class Setpoint:
    """Attitude setpoint ZYX (rad); collective thrust normalised to the vehicle maximum (0..1)."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    thrust_normalised: float
    limited: bool


@dataclass(frozen=True)
class AgentOutput:
    """One tick's result. ``setpoint`` is None while the agent must not fly (warm-up, or a bad
    command that failed its checks); ``estimate`` (9,) is its view of the swarm descriptors;
    ``desired`` (9,) the plan's descriptors this tick (None where not given); ``separating``:
    the separation layer changed this tick's command (a neighbour, the floor or the fence)."""

    message: ConsensusMessage
    estimate: FloatArray
    moments: SwarmMoments
    setpoint: Setpoint | None
    active_neighbours: tuple[int, ...]
    ready_to_fly: bool
    disagreement: float = 0.0
    desired: FloatArray | None = None
    separating: bool = False


@dataclass(frozen=True)
class BatchOutputs:
    """One :meth:`BatchAgentCore.tick_columns` call's outputs, row ``k`` of every field the
    ``k``-th row's :class:`AgentOutput` (:meth:`outputs`): the messages still to be made
    (``outgoing``: with the settled levels, when the caller has them), ``setpoints``,
    ``active_neighbours`` and ``separating`` per row; ``estimate`` (K, 9), ``moments`` (leading
    K axis), ``ready_to_fly`` (K,), ``disagreement`` (K,) and ``desired`` (K, 9) arrays."""

    outgoing: Outgoing
    estimate: FloatArray
    moments: SwarmMoments
    setpoints: list[Setpoint | None]
    active_neighbours: list[tuple[int, ...]]
    ready_to_fly: npt.NDArray[np.bool_]
    disagreement: FloatArray
    desired: FloatArray
    separating: list[bool]

    def outputs(self) -> list[AgentOutput]:
        """One :class:`AgentOutput` per row, in order (their arrays views of these; the messages'
        settled level 0, for the adapter to put its own on)."""
        m = self.moments
        centre, rate = list(m.centre_ned_m), list(m.centre_rate_ned_m_s)
        sigma, sigma_rate = list(m.sigma_m2), list(m.sigma_rate_m2_s)
        estimates, desired = list(self.estimate), list(self.desired)
        setpoints, separating = self.setpoints, self.separating
        return [
            _new_output(
                message,
                estimates[k],
                _new_moments(centre[k], rate[k], sigma[k], sigma_rate[k]),
                setpoints[k],
                neighbours,
                flies,
                dis,
                desired[k],
                separating[k],
            )
            for k, (message, neighbours, dis, flies) in enumerate(
                zip(
                    self.outgoing.messages(),
                    self.active_neighbours,
                    self.disagreement.tolist(),
                    self.ready_to_fly.tolist(),
                    strict=True,
                )
            )
        ]


#: The rejoin climb (:meth:`BatchAgentCore.tick` ``climb_to``): vertical PD gains (1/s^2, 1/s),
#: horizontal velocity damping (1/s) and the acceleration limits (m/s^2, vertical and horizontal).
CLIMB_KP, CLIMB_KD, CLIMB_DAMP = 1.0, 1.8, 1.0
CLIMB_MAX_ACCEL = (2.0, 1.0)


def climb_acceleration(x: FloatArray, v: FloatArray, target_z_m: float) -> FloatArray:
    """The rejoin climb's acceleration (3,) NED: to altitude ``target_z_m`` (NED z) with a PD,
    holding the horizontal position's velocity at zero; limited (:data:`CLIMB_MAX_ACCEL`)."""
    vertical, horizontal = CLIMB_MAX_ACCEL
    a_z = CLIMB_KP * (target_z_m - x[2]) - CLIMB_KD * v[2]
    a_h = -CLIMB_DAMP * v[:2]
    norm = float(np.linalg.norm(a_h))
    if norm > horizontal:
        a_h = a_h * (horizontal / norm)
    return np.array([a_h[0], a_h[1], float(np.clip(a_z, -vertical, vertical))])


_warm = False


def warm_up(config: AgentConfig) -> None:
    """Load the core's compiled loops (drone_agent/core/jit_math.py) once per process, compiling
    them first if numba's cache does not have them: a first tick must not pay it (a realtime agent's
    vehicle would wait on it). Called by :class:`BatchAgentCore`."""
    global _warm
    if _warm:
        return
    plan = np.zeros((1, 9))
    plan[0, 6:] = 1.0
    x, v = np.zeros((1, 3)), np.zeros((1, 3))
    r_d = desired_axes_batch(plan)
    omega_d = euler_rate_matrix_batch(plan[:, I_ROLL], plan[:, I_PITCH])[:, :, 0]
    channels_batch(x, v, plan[:, CENTRE], v, (r_d, omega_d))
    moments = moments_from_averages_batch(np.zeros((1, 18)), x, v, (r_d, omega_d))
    axes, s = align_axes_batch(moments.sigma_m2, r_d)
    accel = virtual_acceleration_batch(
        x, v, moments, (plan, plan, plan), config.gains, (r_d, axes, s)
    )
    attitude_thrust_batch(accel, plan[:, I_YAW], config.limits)
    if config.separation is not None:
        params = config.separation.params(config.limits)
        nobody_near(x, v, accel, np.zeros(1, dtype=np.intp), x + 5.0, v, params, accel)
    pair = BatchConsensus((0, 1), config.consensus)  # two agents hearing each other: a pairing
    inboxes: list[list[ConsensusMessage]] = [[], []]
    for round_ in range(3):
        _, outs = pair.step((0, 1), round_, np.zeros((2, 18)), inboxes, (None, None))
        inboxes = [[outs[1].message], [outs[0].message]]
    NeighbourTable(config.consensus.dt_s).hear((0,), 3, inboxes[:1])
    _warm = True


def _for_every_row(plan: DescriptorTrajectory, t_s: float, n: int) -> StateTriple:
    """``plan``'s value, rate and acceleration at ``t_s``, each repeated for ``n`` rows."""
    a, a_dot, a_ddot = plan.evaluate(t_s)
    return a[None].repeat(n, 0), a_dot[None].repeat(n, 0), a_ddot[None].repeat(n, 0)


class BatchAgentCore:
    """Estimators + controllers of the drones ``agent_ids``, one row each. Call :meth:`tick`
    once per control round with the rows due in that round."""

    def __init__(self, agent_ids: Sequence[int], config: AgentConfig) -> None:
        warm_up(config)
        self.agent_ids = tuple(int(i) for i in agent_ids)
        self.config = config
        self.consensus = BatchConsensus(self.agent_ids, config.consensus)
        self.rejected_setpoints = [0] * len(self.agent_ids)
        self.controller = config.controller(
            ControllerSetup(
                config.gains, config.limits, config.consensus.dt_s, dict(config.controller_options)
            )
        )
        #: the controller's calls that failed (raised, wrong shape, rows not finite) and what
        #: the last one did, for the adapter to report
        self.controller_failures = 0
        self.controller_error: str | None = None
        self.separation = (
            None
            if config.separation is None
            else SeparationLayer(
                config.separation,
                config.limits,
                config.consensus.dt_s,
                config.consensus.heard_timeout_ticks,
            )
        )
        self._row = {agent: row for row, agent in enumerate(self.agent_ids)}
        self._plan_keys: weakref.WeakKeyDictionary[DescriptorTrajectory, bytes] = (
            weakref.WeakKeyDictionary()
        )

    def row_of(self, agent_id: int) -> int:
        """The row of drone ``agent_id``."""
        return self._row[agent_id]

    def restart_row(self, row: int) -> None:
        """Row ``row``'s agent starts a new life (restarted in its process): its estimator
        starts afresh with a new incarnation (BatchConsensus.restart)."""
        self.consensus.restart(row)

    def tick(
        self,
        rows: Sequence[int],
        round_: int,
        t_s: float,
        positions_ned_m: FloatArray,
        velocities_ned_m_s: FloatArray,
        plans: Sequence[DescriptorTrajectory],
        inboxes: Sequence[Iterable[ConsensusMessage]],
        members: Sequence[frozenset[int] | None],
        climb_to: Sequence[float | None] | None = None,
        plan_t_s: Sequence[float] | None = None,
    ) -> list[AgentOutput]:
        """Estimate and control rows ``rows`` (distinct) for round ``round_`` at simulated time
        ``t_s``: positions and velocities (len(rows), 3) NED of their own vehicles, and per row
        its plan, its inbox and its membership view. ``climb_to``: per row None (fly the
        formation) or the NED z a returning drone climbs to or holds (:func:`climb_acceleration`
        instead of the cooperative field, through the same separation layer and limits).
        ``plan_t_s``: per row the plan's own time to fly (protocols/model/plan_timing.py: held
        before the take-off, re-timed after it); None: ``t_s`` for every row. One output per row, in
        order (:meth:`tick_columns`' rows)."""
        if len(rows) == 0:
            return []
        return self.tick_columns(
            rows, round_, t_s, positions_ned_m, velocities_ned_m_s, plans, inboxes, members,
            climb_to, plan_t_s,
        ).outputs()  # fmt: skip

    def tick_columns(
        self,
        rows: Sequence[int],
        round_: int,
        t_s: float,
        positions_ned_m: FloatArray,
        velocities_ned_m_s: FloatArray,
        plans: Sequence[DescriptorTrajectory],
        inboxes: Sequence[Iterable[ConsensusMessage]],
        members: Sequence[frozenset[int] | None],
        climb_to: Sequence[float | None] | None = None,
        plan_t_s: Sequence[float] | None = None,
    ) -> BatchOutputs:
        """:meth:`tick`'s outputs as columns, one row per row of ``rows`` (at least one), without
        an :class:`AgentOutput` per row (what ``swarm simulate`` reads of a hundred agents)."""
        x = np.asarray(positions_ned_m, dtype=float).reshape(-1, 3)
        v = np.asarray(velocities_ned_m_s, dtype=float).reshape(-1, 3)
        inboxes = as_inboxes(inboxes)  # read once for the consensus and the separation layer
        times = [t_s] * len(plans) if plan_t_s is None else plan_t_s
        a_d, ad_dot, ad_ddot = self._references(plans, times)
        r_d = desired_axes_batch(a_d)
        # channels in the plan's turning frame (drone_agent/core/moments.py)
        omega_d = (
            euler_rate_matrix_batch(a_d[:, I_ROLL], a_d[:, I_PITCH]) @ ad_dot[:, ORIENTATION, None]
        )[:, :, 0]
        zeta = channels_batch(x, v, a_d[:, CENTRE], ad_dot[:, CENTRE], (r_d, omega_d))
        gamma, outgoing, active, disagreement = self.consensus.step_outgoing(
            rows, round_, zeta, inboxes, members, (x, v)
        )
        moments = moments_from_averages_batch(
            gamma, a_d[:, CENTRE], ad_dot[:, CENTRE], (r_d, omega_d)
        )
        axes, s = align_axes_batch(moments.sigma_m2, r_d)
        estimate = frame_vector_batch(moments.centre_ned_m, axes, s)
        n_rows = gamma.shape[0]
        ready = np.zeros(n_rows, dtype=bool)
        if t_s >= self.config.warmup_s:
            ready[:] = np.isfinite(gamma).all(axis=1)
        setpoints: list[Setpoint | None] = [None] * n_rows
        separating = [False] * n_rows
        if ready.any():
            setpoints, separating = self._setpoints(
                rows,
                ready,
                x,
                v,
                moments,
                (a_d, ad_dot, ad_ddot),
                (r_d, axes, s),
                (round_, t_s, inboxes),
                climb_to,
            )
        return BatchOutputs(
            outgoing,
            estimate,
            moments,
            setpoints,
            active,
            ready,
            disagreement,
            a_d,
            separating,
        )

    def _references(
        self, plans: Sequence[DescriptorTrajectory], times_s: Sequence[float]
    ) -> StateTriple:
        """Each row's plan value, rate and acceleration (len(plans), 9) at its plan time,
        every distinct (plan, time) evaluated once (plans with equal content, e.g. one plan
        decoded by each agent's own transport, count as one)."""
        if plans and len(plans) == len(times_s):  # one plan object and one time for all: one
            one, t0 = plans[0], times_s[0]  # evaluation (swarm simulate's usual tick)
            if all(p is one for p in plans) and times_s.count(t0) == len(times_s):
                return _for_every_row(one, t0, len(plans))
        groups: dict[tuple[bytes, float], list[int]] = {}
        first: dict[tuple[bytes, float], DescriptorTrajectory] = {}
        for k, (plan, t_s) in enumerate(zip(plans, times_s, strict=True)):
            key = self._plan_keys.get(plan)
            if key is None:
                key = b"%d|" % plan.seq + plan.t_knots_s.tobytes() + plan.coeffs.tobytes()
                self._plan_keys[plan] = key
            groups.setdefault((key, t_s), []).append(k)
            first.setdefault((key, t_s), plan)
        if len(groups) == 1:
            (((_, t_s), plan),) = first.items()
            return _for_every_row(plan, t_s, len(plans))
        out = (np.empty((len(plans), 9)), np.empty((len(plans), 9)), np.empty((len(plans), 9)))
        for (key, t_s), ks in groups.items():
            for dst, value in zip(out, first[(key, t_s)].evaluate(t_s), strict=True):
                dst[ks] = value
        return out

    def _setpoints(
        self,
        rows: Sequence[int],
        ready: npt.NDArray[np.bool_],
        x: FloatArray,
        v: FloatArray,
        moments: SwarmMoments,
        reference: StateTriple,
        frame: tuple[FloatArray, FloatArray, FloatArray],
        heard: tuple[int, float, Sequence[Iterable[ConsensusMessage]]],
        climb_to: Sequence[float | None] | None = None,
    ) -> tuple[list[Setpoint | None], list[bool]]:
        """The checked setpoints of the rows ready to fly (None for the others, and for any
        command the controller failed to give, not finite or out of range, which is counted
        against its row), and whether the separation layer changed each row's command;
        ``heard``: the round, the simulated time and the rows' inboxes (where their
        neighbours are)."""
        round_, t_s, inboxes = heard
        idx = np.flatnonzero(ready)
        if idx.shape[0] == ready.shape[0]:  # all ready (the usual case): no gathering
            xs, vs, pick, ref, fr = x, v, moments, reference, frame
        else:
            xs, vs = x[idx], v[idx]
            pick = SwarmMoments(
                moments.centre_ned_m[idx],
                moments.centre_rate_ned_m_s[idx],
                moments.sigma_m2[idx],
                moments.sigma_rate_m2_s[idx],
            )
            ref = (reference[0][idx], reference[1][idx], reference[2][idx])
            fr = (frame[0][idx], frame[1][idx], frame[2][idx])
        ids = self.agent_ids
        inputs = _new_inputs(
            tuple([ids[rows[k]] for k in idx.tolist()]),
            t_s, xs, vs, pick, fr[1], fr[2], ref[0], ref[1], ref[2], fr[0],
        )  # fmt: skip
        accel, good = self._accelerations(inputs)
        if climb_to is not None and any(z is not None for z in climb_to):
            accel = np.array(accel, dtype=float)
            for k, i in enumerate(idx.tolist()):
                target = climb_to[i]
                if target is not None:
                    accel[k] = climb_acceleration(x[i], v[i], target)
                    good[k] = True
        changed = [False] * len(ready)
        if self.separation is not None:
            filtered = self.separation.filter(
                [self.agent_ids[rows[k]] for k in idx.tolist()],
                round_,
                xs,
                vs,
                accel,
                inboxes if idx.shape[0] == len(inboxes) else [inboxes[k] for k in idx.tolist()],
                common_accel_ned_m_s2=ref[2][:, CENTRE],
            )
            accel = filtered.accel_ned_m_s2
            for k in np.flatnonzero(filtered.active & good).tolist():
                changed[int(idx[k])] = True
        command, limited, usable = self._commands(accel, inputs)
        ok = usable & good
        out: list[Setpoint | None] = [None] * len(ready)
        for k, (r, p, y, t), lim, fine in zip(
            idx.tolist(), command.T.tolist(), limited.tolist(), ok.tolist(), strict=True
        ):
            if fine:
                out[k] = _new_setpoint(r, p, y, t, lim)
            else:
                self.rejected_setpoints[rows[k]] += 1
        return out, changed

    def _accelerations(self, inputs: ControllerInputs) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
        """The controller's accelerations and the usable rows (:func:`call_acceleration`);
        a failure counted and said (:attr:`controller_error`)."""
        accel, good, error = call_acceleration(self.controller, inputs)
        if error is not None:
            self._fault(error)
        return accel, good

    def _commands(
        self, accel: FloatArray, inputs: ControllerInputs
    ) -> tuple[FloatArray, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """The controller's commands, ``limited`` and the usable ones
        (:func:`call_thrust_attitude`); a failure counted and said (:attr:`controller_error`)."""
        command, limited, usable, error = call_thrust_attitude(
            self.controller, accel, inputs, self.config.limits.max_thrust_n
        )
        if error is not None:
            self._fault(error)
        return command, limited, usable

    def _fault(self, message: str) -> None:
        self.controller_failures += 1
        self.controller_error = f"controller {controller_name(self.controller)}: {message}"


_new_output = frozen_factory(AgentOutput)
_new_moments = frozen_factory(SwarmMoments)
_new_setpoint = frozen_factory(Setpoint)
_new_inputs = frozen_factory(ControllerInputs)


class AgentCore:
    """Estimator + controller of drone ``agent_id``: its row of a :class:`BatchAgentCore` (a
    batch of its own unless ``batch`` is given). Call :meth:`tick` once per control round."""

    def __init__(
        self, agent_id: int, config: AgentConfig, batch: BatchAgentCore | None = None
    ) -> None:
        self.agent_id = agent_id
        self.config = config
        self.batch = batch if batch is not None else BatchAgentCore((agent_id,), config)
        self.row = self.batch.row_of(agent_id)

    @property
    def rejected_setpoints(self) -> int:
        """Commands that failed the setpoint checks (not finite or out of range)."""
        return self.batch.rejected_setpoints[self.row]

    def tick(
        self,
        round_: int,
        t_s: float,
        position_ned_m: FloatArray,
        velocity_ned_m_s: FloatArray,
        plan: DescriptorTrajectory,
        inbox: Iterable[ConsensusMessage],
        members: frozenset[int] | None = None,
        climb_to: float | None = None,
        plan_t_s: float | None = None,
    ) -> AgentOutput:
        """Estimate and control for round ``round_`` at simulated time ``t_s`` (``climb_to``,
        ``plan_t_s``: :meth:`BatchAgentCore.tick`; None: the plan at ``t_s``)."""
        return self.batch.tick(
            (self.row,),
            round_,
            t_s,
            np.asarray(position_ned_m, dtype=float)[None],
            np.asarray(velocity_ned_m_s, dtype=float)[None],
            (plan,),
            (inbox,),
            (members,),
            (climb_to,),
            None if plan_t_s is None else (plan_t_s,),
        )[0]
