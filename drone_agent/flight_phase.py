"""What an agent does with its vehicle each control tick: the flight phases. Pure.

From the plan's flight command, the agent's readiness, the core's setpoint and what the vehicle
reports (armed, mode, altitude), :meth:`FlightPhase.decide` returns an :class:`Order`: the agent's
mode, the setpoint to send (every tick has one: in lockstep it also acknowledges the tick) and
what to ask of the autopilot (arm and take offboard, LAND mode, HOLD mode).

Phases, by plan command (protocols/wire_plan.py):

- ``FLY``: once the estimator has settled (``converged``) and arming is allowed, fly the
  formation: arm, offboard, the core's setpoint every tick. The decision is latched
  (``committed``) until the vehicle is back on the ground.
- ``LAND``: an airborne vehicle flies the landing plan (stop, level, flatten, descend) with the
  formation until the commanded centre altitude is at or below
  :data:`~protocols.wire_plan.LAND_HANDOVER_ALTITUDE_M` (or its own altitude is below
  :data:`TOUCHDOWN_FLOOR_M`, or it has no valid setpoint), then it is handed to the autopilot's
  LAND mode: level, sink at the land speed, touchdown detector, disarm. Disarmed on the ground it
  is ``LANDED``; a ``FLY`` plan (``swarm takeoff``) arms it and flies again, also in mid-descent.
- ``GROUND``: stay on the ground; an airborne vehicle is handed to LAND at once.

Safety invariant (tested over every command, mode and vehicle state): a vehicle that is armed or
above :data:`AIRBORNE_ALTITUDE_M` is never sent a thrust below the controller's minimum
(``ThrustLimits.min_thrust_ratio`` of its weight). Zero thrust goes only to a disarmed vehicle on
the ground. The only way to stop the motors of a flying vehicle is an explicit kill (the ground
station's crash drill, MAV_CMD_INJECT_FAILURE, or a forced disarm), never an agent's setpoint.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum

from drone_agent.agent_core import AgentConfig, AgentOutput, Setpoint
from drone_agent.thrust_attitude import ThrustLimits
from protocols.consensus_message import ConsensusMessage
from protocols.frames import G_M_S2
from protocols.wire_plan import LAND_HANDOVER_ALTITUDE_M, FlightCommand
from protocols.wire_status import AgentMode

#: A vehicle above this altitude (m) is airborne whatever it says about arming.
AIRBORNE_ALTITUDE_M = 0.1
#: Under a LAND plan a vehicle this low (m) is handed to the autopilot's LAND mode at once.
TOUCHDOWN_FLOOR_M = 0.3


class Request(Enum):
    """What the agent asks of the autopilot this tick (the adapter rate-limits the asking)."""

    NONE = "none"
    ARM_OFFBOARD = "arm and offboard"
    LAND_MODE = "land mode"
    HOLD_MODE = "hold mode"


@dataclass(frozen=True)
class VehicleView:
    """What the vehicle last reported: armed, whether it flies offboard setpoints or its own
    LAND or HOLD mode, and its altitude (m, up)."""

    armed: bool
    in_offboard: bool
    in_land: bool
    in_hold: bool
    altitude_m: float

    @property
    def airborne(self) -> bool:
        """Armed, or off the ground: its motors must not be cut by a setpoint."""
        return self.armed or self.altitude_m > AIRBORNE_ALTITUDE_M


@dataclass(frozen=True)
class Order:
    """This tick's decision: the agent's mode, the setpoint to send, the autopilot request."""

    mode: AgentMode
    setpoint: Setpoint
    request: Request = Request.NONE


def idle_setpoint(yaw_rad: float) -> Setpoint:
    """Level, zero thrust: for a disarmed vehicle on the ground only."""
    return Setpoint(0.0, 0.0, yaw_rad, 0.0, False)


def hover_setpoint(limits: ThrustLimits, yaw_rad: float) -> Setpoint:
    """Level at ``yaw_rad`` with the thrust that carries the weight."""
    return Setpoint(0.0, 0.0, yaw_rad, limits.mass_kg * G_M_S2 / limits.max_thrust_n, False)


class Settling:
    """Whether an agent's estimate has settled, the condition to arm (with the plan's FLY):
    warm-up over (``AgentOutput.ready_to_fly``) and the estimator agreeing with its neighbours
    (disagreement below ``settle_tolerance``) for ``settle_ticks`` ticks in a row while the
    membership stayed the same (a drone joining or leaving restarts the count). The same rule for
    ``swarm simulate`` and every ``swarm agent``."""

    def __init__(self, config: AgentConfig) -> None:
        self.ticks = config.settle_ticks
        self.tolerance = config.settle_tolerance
        self.calm_ticks = 0
        self._members: frozenset[int] | None = None
        self.settled = False

    def update(self, out: AgentOutput, members: frozenset[int]) -> bool:
        """Take one tick's output and the membership; whether the estimate has settled."""
        # (the same view object tick after tick: identity first, before comparing the sets)
        calm = out.disagreement < self.tolerance and (
            members is self._members or members == self._members
        )
        self._members = members
        self.calm_ticks = self.calm_ticks + 1 if calm else 0
        self.settled = out.ready_to_fly and self.agrees
        return self.settled

    @property
    def agrees(self) -> bool:
        """The estimate agrees with the neighbours' (``settle_ticks`` calm ticks), warm-up or not:
        what the agent tells its neighbours (:class:`SwarmSettled`), so that word of a settled
        swarm crosses it during the warm-up instead of after."""
        return self.calm_ticks >= self.ticks


class SwarmSettled:
    """Climb together: whether every agent of the swarm has settled, known to each agent from its
    radio neighbours alone (a flood of settled levels over the consensus messages).

    Each tick an agent advertises a level on its consensus message (``ready_hops``)::

        level_i = 0                                   if i has not settled
                = min(cap, 1 + min_j level_j)         otherwise (j: neighbours heard recently)

    with ``cap`` the number of live members. ``level_i >= h`` means every agent within ``h - 1``
    hops of i had settled within the last ``h`` ticks; since no radio graph of ``cap`` drones has a
    diameter of ``cap`` hops or more, ``level_i == cap`` means the whole (connected) swarm has
    settled. Once the last agent settles, every level rises by one per tick, so all agents reach
    the cap within the graph's diameter in ticks of each other (a 10 x 10 grid at range 6 m: 6
    ticks, 0.12 s) and ``cap`` ticks after that last agent (2 s at N = 100, 50 Hz): the swarm leaves
    the ground together instead of drone by drone as each settles (measured before this rule on a
    sparse 5-drone line: the centre armed at 3.0 s, the ends at 6.2 s).

    An agent that already flies (``committed``) counts as settled, so a late joiner waits only for
    itself and is not held on the ground by a formation manoeuvring above it. An agent with no
    neighbour (alone, or cut off) reaches the cap on its own settling.
    """

    def __init__(self, heard_timeout_ticks: int) -> None:
        self.timeout = heard_timeout_ticks
        self.level = 0
        self._latest: dict[int, tuple[int, int]] = {}  # sender -> (round, level)

    def update(
        self,
        round_: int,
        settled: bool,
        inbox: Iterable[ConsensusMessage],
        members: frozenset[int],
    ) -> bool:
        """Take this tick's own settled flag, the neighbour messages that arrived and the live
        membership; whether the whole swarm has settled (this agent's new level is the cap)."""
        latest = self._latest
        for msg in inbox:
            sender, round_j = msg.sender, msg.round
            seen = latest.get(sender)
            if seen is None or round_j > seen[0]:
                latest[sender] = (round_j, msg.ready_hops)
        recent = round_ - 1 - self.timeout
        for j in [j for j, (r, _) in latest.items() if r < recent or j not in members]:
            del latest[j]
        cap = max(len(members), 1)
        if not settled:
            self.level = 0
        else:
            lowest = min([lvl for _, lvl in latest.values()], default=cap)
            self.level = min(cap, 1 + lowest)
        return self.level >= cap


class Readiness:
    """The one rule for leaving the ground, used by ``swarm simulate`` and every ``swarm agent``:
    the warm-up is over, the agent's own estimate has settled (:class:`Settling`) and so has
    every agent's (:class:`SwarmSettled`). The flood runs during the warm-up too (an agent
    advertises that it agrees with its neighbours before the warm-up ends), so a swarm that
    settled on the ground leaves it as the warm-up ends: measured on a 10 x 10 grid whose plan
    starts climbing at the end of its 5 s warm-up, waiting for the warm-up first kept it on the
    ground for 33 s, because the climbing reference then kept the estimates from agreeing to 2 %
    until the drop-outs of the scenario were over. Call :meth:`update` once per tick after the
    core; put :attr:`level` on the tick's consensus message."""

    def __init__(self, config: AgentConfig) -> None:
        self.settling = Settling(config)
        self.swarm = SwarmSettled(config.consensus.heard_timeout_ticks)
        self.ready = False

    @property
    def level(self) -> int:
        """This agent's settled level, advertised as ``ConsensusMessage.ready_hops``."""
        return self.swarm.level

    def update(
        self,
        out: AgentOutput,
        inbox: Iterable[ConsensusMessage],
        members: frozenset[int],
        committed: bool,
    ) -> bool:
        """This tick's core output, the inbox it was computed from, the live membership and
        whether the agent already flies; whether the swarm is ready to leave the ground."""
        self.settling.update(out, members)
        agrees = self.settling.agrees or committed
        swarm = self.swarm.update(out.message.round, agrees, inbox, members)
        self.ready = swarm and (out.ready_to_fly or committed)
        return self.ready


class FlightPhase:
    """One agent's flight phase (see the module doc). Call :meth:`decide` once per tick."""

    def __init__(self, limits: ThrustLimits) -> None:
        self.limits = limits
        #: decided to fly; latched until the vehicle is disarmed on the ground again
        self.committed = False
        #: has landed (disarmed on the ground after flying) and not flown since
        self.landed = False
        #: the vehicle was handed to the autopilot's LAND mode: its disarm is expected
        self.handed_over = False

    @property
    def min_thrust_normalised(self) -> float:
        """The least thrust (0..1 of the maximum) an airborne vehicle may be sent."""
        return self.limits.thrust_range_n[0] / self.limits.max_thrust_n

    def decide(
        self,
        command: FlightCommand,
        arm_allowed: bool,
        converged: bool,
        setpoint: Setpoint | None,
        commanded_altitude_m: float,
        vehicle: VehicleView,
        yaw_rad: float,
    ) -> Order:
        """The order of this tick.

        ``converged``: the estimator has settled (the adapter's rule); ``setpoint``: the core's
        checked setpoint, None if it has none; ``commanded_altitude_m``: the plan's centre
        altitude now (m, up); ``yaw_rad``: the vehicle's heading, for level setpoints.
        """
        order = self._decide(
            command, arm_allowed, converged, setpoint, commanded_altitude_m, vehicle, yaw_rad
        )
        return self._safe(order, vehicle, yaw_rad)

    def _decide(
        self,
        command: FlightCommand,
        arm_allowed: bool,
        converged: bool,
        setpoint: Setpoint | None,
        commanded_altitude_m: float,
        vehicle: VehicleView,
        yaw_rad: float,
    ) -> Order:
        if command == FlightCommand.FLY:
            if setpoint is not None and arm_allowed and (self.committed or converged):
                self.committed, self.landed = True, False
                if vehicle.armed and vehicle.in_offboard:
                    self.handed_over = False
                    return Order(AgentMode.FLYING, setpoint)
                # arming, or taking the vehicle back from a failsafe or from LAND
                mode = AgentMode.FLYING if vehicle.armed else AgentMode.READY
                return Order(mode, setpoint, Request.ARM_OFFBOARD)
            if vehicle.airborne:  # nothing valid to fly: the autopilot holds its altitude
                request = Request.NONE if vehicle.in_hold else Request.HOLD_MODE
                return Order(AgentMode.HOLDING, hover_setpoint(self.limits, yaw_rad), request)
        elif vehicle.airborne:  # LAND or GROUND
            if vehicle.in_land:  # handed over (or its own failsafe): it lands and disarms
                self.handed_over = True
                return Order(AgentMode.LANDING, hover_setpoint(self.limits, yaw_rad))
            handover = (
                command == FlightCommand.GROUND
                or commanded_altitude_m <= LAND_HANDOVER_ALTITUDE_M
                or vehicle.altitude_m <= TOUCHDOWN_FLOOR_M
            )
            if handover or setpoint is None:
                self.handed_over = True
                landing = setpoint or hover_setpoint(self.limits, yaw_rad)
                return Order(AgentMode.LANDING, landing, Request.LAND_MODE)
            return Order(AgentMode.LANDING, setpoint)
        # disarmed on the ground
        self.handed_over = False
        if self.committed:
            self.committed, self.landed = False, True
        if self.landed:
            return Order(AgentMode.LANDED, idle_setpoint(yaw_rad))
        return Order(AgentMode.READY if converged else AgentMode.WARMUP, idle_setpoint(yaw_rad))

    def _safe(self, order: Order, vehicle: VehicleView, yaw_rad: float) -> Order:
        """The invariant, enforced: an airborne vehicle gets at least the minimum thrust."""
        sp = order.setpoint
        if vehicle.airborne and not sp.thrust_normalised >= self.min_thrust_normalised:
            return Order(order.mode, hover_setpoint(self.limits, yaw_rad), order.request)
        return order
