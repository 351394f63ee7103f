"""The in-process agents' link to their vehicles: what each reads of its autopilot, asks of it and
hands it, as a ``swarm agent`` does over MAVLink. Pure: no I/O, no clock.

A ``swarm agent`` (drone_agent/process/hosted_agent.py over drone_agent/process/vehicle_link.py)
reads its vehicle's state in the telemetry's float32 (:func:`reported`) and its armed state and mode
from its HEARTBEAT, which the simulator sends again after every event that may change them
(sitl_sim/server.py: ``report``), so that at a tick the agent sees the autopilot as it is
(:meth:`AutopilotLink.views`). It asks the autopilot to arm and take offboard, to hold or to land
(:meth:`AutopilotLink.request`: the same commands, retried at most every ``command_retry_s`` of
simulated time as in lockstep), then answers the tick with its setpoint, which the vehicle
validates and keeps (:meth:`AutopilotLink.hand_setpoints`: SET_ATTITUDE_TARGET's float32 and the
simulator's checks, :func:`received`). It leaves the swarm when its vehicle is lost
(:meth:`AutopilotLink.lost`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from drone_agent.core.flight_phase import (
    ON_GROUND_UNKNOWN,
    Request,
    VehicleArrays,
    VehicleView,
)
from drone_agent.process.hosted_agent import RunOptions
from protocols.model.frames import FloatArray, quat_from_zyx
from protocols.wire.status import AgentMode
from sitl_sim.vehicle.autopilot import Mode, VehicleEvent
from sitl_sim.vehicle.setpoint_jit import validate_attitude_targets
from sitl_sim.vehicle.world import World

#: Agent modes in which the vehicle flies the agent's setpoints: disarmed under them, it is lost
#: (drone_agent/process/hosted_agent.py).
FLYING_MODES = frozenset({AgentMode.FLYING, AgentMode.HOLDING})
_OFFBOARD, _LAND, _HOLD = int(Mode.OFFBOARD), int(Mode.LAND), int(Mode.HOLD)


def reported(values: FloatArray) -> FloatArray:
    """``values`` as a vehicle reports them to its agent: LOCAL_POSITION_NED and ATTITUDE carry
    float32 (drone_agent/process/vehicle_link.py reads them back as float64). The in-process agents
    read their vehicles through this, as every ``swarm agent`` does, so the two runners compute on
    the same inputs: a square grid's orientation estimate is ill-conditioned (equal spreads: its
    axes are any), and the rounding alone turned one agent's estimated heading by 0.13 rad at the
    take-off of the 25-drone grid, which the formation then flew (up to 14 mm apart at N = 25,
    12 cm at N = 100)."""
    return np.asarray(values, dtype=np.float64).astype(np.float32).astype(np.float64)


def received(
    drones: Sequence[int], commands: Sequence[tuple[float, float, float, float]] | FloatArray
) -> tuple[npt.NDArray[np.intp], FloatArray, FloatArray, FloatArray]:
    """The setpoints ``commands`` (roll, pitch, yaw rad, normalised thrust) of ``drones`` as their
    vehicles take them from a swarm agent: the agent's quaternion
    (drone_agent/process/hosted_agent.py: ``quat_from_zyx``, the same values over an array as one by
    one), SET_ATTITUDE_TARGET's float32, the simulator's validation (sitl_sim/vehicle/setpoint.py:
    normalised, back to ZYX angles). Returns the drones whose setpoint was valid (the others keep
    their last one, as the simulator's vehicles do), their unit quaternions (4, K), attitudes (3, K)
    and thrusts (K,). A square grid's take-off turned on the last bit of a command: 1e-13 m of one
    vehicle's position flipped its agent's estimated heading by 90 degrees at N = 100. The
    simulator's checks run over all the drones at once (the same rule, compiled:
    :func:`~sitl_sim.vehicle.setpoint_jit.validate_attitude_targets`)."""
    values = np.array(commands).T
    quats = quat_from_zyx(values[2], values[1], values[0]).astype(np.float32).T
    thrusts = values[3].astype(np.float32)
    codes, unit, euler = validate_attitude_targets(quats, thrusts)  # float32's values as float64
    ok = codes == 0
    taken = np.asarray(drones, dtype=np.intp)[ok]
    return taken, unit[ok].T, euler[ok].T, thrusts[ok].astype(np.float64)


class AutopilotLink:
    """Every in-process agent's link to its vehicle in ``world`` (see the module doc);
    ``retry_s``: the least simulated time between two requests of one agent."""

    def __init__(self, world: World, retry_s: float = RunOptions.command_retry_s) -> None:
        self.world = world
        self.retry_s = retry_s
        self._last_request_s = [-1e9] * world.n

    def vehicle_arrays(self, drones: Sequence[int], altitude_m: npt.ArrayLike) -> VehicleArrays:
        """What the agents of ``drones`` know of their vehicles at this tick, for a batch of
        flight phases: armed and mode as the last HEARTBEAT said (the autopilot now),
        ``altitude_m`` (m, up) as reported."""
        ap = self.world.autopilot
        idx = np.asarray(drones, dtype=np.intp)
        mode = ap.mode[idx]
        # the land detector's word, as the simulator sends it each tick where the state estimates
        # are not the truth (EXTENDED_SYS_STATE), else none: the altitude decides
        if self.world.estimator is not None:
            on_ground = ap.landed[idx].astype(np.int64)
        else:
            on_ground = np.full(idx.shape[0], ON_GROUND_UNKNOWN, dtype=np.int64)
        return VehicleArrays(
            ap.armed[idx].astype(np.bool_),
            mode == _OFFBOARD,
            mode == _LAND,
            mode == _HOLD,
            np.asarray(altitude_m, dtype=np.float64),
            on_ground,
        )

    def request(
        self, drone: int, request: Request, view: VehicleView, t_s: float
    ) -> list[VehicleEvent]:
        """Drone ``drone``'s agent asks ``request`` of its autopilot at the tick of time ``t_s``
        (the vehicle's time_boot_ms / 1000), having seen ``view``: as a lockstep agent, at most
        every ``retry_s``, offboard before arming, each only if the vehicle did not say it
        already. The autopilot's events (arming, mode changes)."""
        if request is Request.NONE or t_s - self._last_request_s[drone] < self.retry_s:
            return []
        self._last_request_s[drone] = t_s
        ap, now = self.world.autopilot, self.world.t_s
        events: list[VehicleEvent] = []
        if request is Request.ARM_OFFBOARD:
            if not view.in_offboard:
                events += ap.set_mode(drone, Mode.OFFBOARD, now)[1]
            if not view.armed:
                events += ap.arm(drone, now)[1]
        elif request is Request.LAND_MODE:
            events += ap.set_mode(drone, Mode.LAND, now)[1]
        elif request is Request.HOLD_MODE:
            events += ap.set_mode(drone, Mode.HOLD, now)[1]
        return events

    def hand_setpoints(
        self,
        drones: Sequence[int],
        commands: Sequence[tuple[float, float, float, float]] | FloatArray,
    ) -> None:
        """The agents of ``drones`` answer the tick with ``commands`` (roll, pitch, yaw rad,
        normalised thrust): their vehicles keep the valid ones (:func:`received`), received now."""
        if not drones:
            return
        taken, quat, euler, thrust = received(drones, commands)
        self.world.autopilot.setpoints(taken, quat, euler, thrust, self.world.t_s)

    def lost(self, drone: int, agent_mode: AgentMode, handed_over: bool) -> str | None:
        """Why drone ``drone``'s agent leaves the swarm now, or None (hosted_agent's
        ``_vehicle_lost``): its vehicle crashed (an EMERGENCY text and state), or it was disarmed
        while the agent flew it (``agent_mode`` its last order's, not handed to LAND)."""
        ap = self.world.autopilot
        if ap.crashed[drone]:
            return "vehicle crashed"
        if agent_mode in FLYING_MODES and not ap.armed[drone] and not handed_over:
            return "its vehicle was disarmed in flight"
        return None
