"""One drone's brain, pure: consensus estimate of the swarm descriptors and the cooperative
controller, from its own state, the shared plan and the neighbour messages of this round.

The same core runs in the in-process reference flight (``swarm simulate``) and, later, inside each
agent process behind MAVLink and Zenoh adapters. No clock, no I/O: time is given by the round
number and the vehicle's simulated time.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from drone_agent.consensus import ConsensusEstimator, ConsensusMessage, ConsensusParams
from drone_agent.cooperative import CooperativeGains, virtual_acceleration
from drone_agent.moments import SwarmMoments, channels, moments_from_averages
from drone_agent.thrust_attitude import AttitudeThrust, ThrustLimits, attitude_thrust
from protocols.descriptor_vector import CENTRE, I_YAW
from protocols.descriptors import desired_axes, frame_from_moments
from protocols.frames import FloatArray
from protocols.trajectory import DescriptorTrajectory


@dataclass(frozen=True)
class AgentConfig:
    """What one agent needs to know: gains, limits, the warm-up before it may arm, and when its
    estimate counts as settled: disagreement with its neighbours (ConsensusOutput) below
    ``settle_tolerance`` for ``settle_ticks`` ticks in a row with the same membership."""

    consensus: ConsensusParams
    gains: CooperativeGains
    limits: ThrustLimits
    warmup_s: float = 3.0
    settle_ticks: int = 25
    settle_tolerance: float = 0.02


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
    ``desired`` (9,) the plan's descriptors this tick (None where not given)."""

    message: ConsensusMessage
    estimate: FloatArray
    moments: SwarmMoments
    setpoint: Setpoint | None
    active_neighbours: tuple[int, ...]
    ready_to_fly: bool
    disagreement: float = 0.0
    desired: FloatArray | None = None


class AgentCore:
    """Estimator + controller of drone ``agent_id``. Call :meth:`tick` once per control round."""

    def __init__(self, agent_id: int, config: AgentConfig) -> None:
        self.agent_id = agent_id
        self.config = config
        self.estimator = ConsensusEstimator(agent_id, config.consensus)
        self.rejected_setpoints = 0

    def tick(
        self,
        round_: int,
        t_s: float,
        position_ned_m: FloatArray,
        velocity_ned_m_s: FloatArray,
        plan: DescriptorTrajectory,
        inbox: Iterable[ConsensusMessage],
        members: frozenset[int] | None = None,
    ) -> AgentOutput:
        """Estimate and control for round ``round_`` at simulated time ``t_s``."""
        reference = plan.evaluate(t_s)
        a_d, ad_dot, _ = reference
        zeta = channels(position_ned_m, velocity_ned_m_s, a_d[CENTRE], ad_dot[CENTRE])
        out = self.estimator.step(round_, zeta, inbox, members)
        moments = moments_from_averages(out.estimate, a_d[CENTRE], ad_dot[CENTRE])
        frame = frame_from_moments(moments.centre_ned_m, moments.sigma_m2, desired_axes(a_d))
        estimate = frame.vector()
        ready = t_s >= self.config.warmup_s and bool(np.all(np.isfinite(out.estimate)))
        setpoint = None
        if ready:
            v = virtual_acceleration(
                position_ned_m, velocity_ned_m_s, moments, reference, self.config.gains
            )
            setpoint = self._setpoint(attitude_thrust(v, float(a_d[I_YAW]), self.config.limits))
        return AgentOutput(
            out.message,
            estimate,
            moments,
            setpoint,
            out.active_neighbours,
            ready,
            out.disagreement,
            a_d,
        )

    def _setpoint(self, command: AttitudeThrust) -> Setpoint | None:
        """The checked setpoint: None (and counted) if anything is not finite or out of range."""
        thrust = command.thrust_n / self.config.limits.max_thrust_n
        values = (command.roll_rad, command.pitch_rad, command.yaw_rad, thrust)
        if not all(np.isfinite(values)) or not 0.0 <= thrust <= 1.0:
            self.rejected_setpoints += 1
            return None
        return Setpoint(
            command.roll_rad, command.pitch_rad, command.yaw_rad, thrust, command.limited
        )
