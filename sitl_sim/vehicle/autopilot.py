"""The simulated autopilot of N vehicles: modes, arming, offboard-loss failsafe, crash. Pure.

One state machine per vehicle, stored as arrays with one entry per vehicle so the physics loop
reads them without Python loops. No clock and no I/O: every call takes the simulated time
``t_s`` (s); what happened comes back as :class:`VehicleEvent` (a STATUSTEXT for the links).

Modes (PX4 custom modes, protocols/mavlink/conventions.py):

- ``HOLD`` (AUTO.LOITER): level, hold the altitude at which the mode was entered; on the ground,
  armed, the motors idle. Disarming (by command or on touchdown) returns a vehicle to HOLD.
- ``OFFBOARD``: fly the last valid SET_ATTITUDE_TARGET (attitude + normalised thrust). Entered only
  while setpoints are fresh (younger than the offboard timeout), as on PX4.
- ``LAND`` (AUTO.LAND): level, descend at the land speed, disarm on touchdown.

Offboard-loss failsafe: armed in OFFBOARD and no valid setpoint for ``offboard_timeout_s`` ->
HOLD (level, altitude held) for ``hold_s`` -> LAND -> disarm on touchdown, each step reported.
A crash (all motors off) disarms, the vehicle falls; once it rests on the ground it is a wreck and
goes silent (the links stop sending and answering). A touchdown faster than
``hard_landing_m_s`` destroys an intact vehicle the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray
from sitl_sim.vehicle.failsafe import FailsafeConfig
from sitl_sim.vehicle.setpoint import AttitudeSetpoint

BoolArray = npt.NDArray[np.bool_]

#: A vehicle at or below this altitude (m) with contact is on the ground (contact puts z = 0).
LANDED_ALTITUDE_M = 1e-3
#: MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm in flight (MAVLink convention).
FORCE_DISARM_MAGIC = 21196.0


class Mode(IntEnum):
    """The flight modes of the simulated autopilot."""

    HOLD = 0
    OFFBOARD = 1
    LAND = 2


class Severity(IntEnum):
    """MAV_SEVERITY values used in STATUSTEXT."""

    EMERGENCY = 0
    CRITICAL = 2
    WARNING = 4
    NOTICE = 5
    INFO = 6


class Result(IntEnum):
    """MAV_RESULT values of a COMMAND_ACK."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4


@dataclass(frozen=True)
class VehicleEvent:
    """Something vehicle ``vehicle`` (0-based) reports as a STATUSTEXT; ``kind`` says what, for
    a log (:data:`EVENT_KINDS`; ``text`` for anything else)."""

    vehicle: int
    severity: Severity
    text: str
    kind: str = "text"


#: The kinds of :class:`VehicleEvent` this autopilot reports: armed, disarmed (on a command or on
#: touchdown), a mode entered on a command, a failsafe step, a motor failure injected or cleared,
#: a touchdown too fast (a vehicle destroyed, or a wreck hitting the ground).
EVENT_KINDS = ("armed", "disarmed", "mode", "failsafe", "motor_failure", "hard_landing")


@dataclass(frozen=True)
class Outcome:
    """The answer to a command: a MAV_RESULT and, when not accepted, why."""

    result: Result
    reason: str = ""


ACCEPTED = Outcome(Result.ACCEPTED)


@dataclass(frozen=True)
class AutopilotConfig:
    """Defaults of every vehicle's tunables (per-vehicle copies live in :class:`Autopilot`).

    ``failsafe``: timeout, hold time (s), land speed (m/s), vertical-speed gain (1/s);
    ``altitude_gain_per_s``: altitude-hold gain (1/s) and ``max_climb_m_s`` its speed limit;
    ``hard_landing_m_s``: touchdown speed that destroys a vehicle; ``failure_injection``: whether
    MAV_CMD_INJECT_FAILURE is honoured (PX4's SYS_FAILURE_EN).
    """

    failsafe: FailsafeConfig = field(default_factory=FailsafeConfig)
    altitude_gain_per_s: float = 1.0
    max_climb_m_s: float = 1.0
    hard_landing_m_s: float = 2.0
    failure_injection: bool = True


class Autopilot:
    """Modes, arming and failsafes of ``n`` vehicles (index 0..n-1)."""

    def __init__(self, n: int, config: AutopilotConfig, yaw_rad: FloatArray) -> None:
        fs = config.failsafe
        self.n = n
        self.config = config
        self.armed: BoolArray = np.zeros(n, dtype=bool)
        self.mode = np.full(n, int(Mode.HOLD), dtype=np.int8)
        self.failsafe: BoolArray = np.zeros(n, dtype=bool)
        self.failsafe_since_s = np.zeros(n)
        self.crashed: BoolArray = np.zeros(n, dtype=bool)
        self.silent: BoolArray = np.zeros(n, dtype=bool)
        self._wrecked: BoolArray = np.zeros(n, dtype=bool)
        self.landed: BoolArray = np.ones(n, dtype=bool)
        self.motor_ok: BoolArray = np.ones((4, n), dtype=bool)
        self.hold_z_m = np.full(n, np.nan)
        # the last valid offboard setpoint
        self.last_setpoint_s = np.full(n, -np.inf)
        self.sp_euler_rad = np.zeros((3, n))
        self.sp_euler_rad[2] = yaw_rad
        self.sp_quat = np.zeros((4, n))
        self.sp_quat[0] = np.cos(0.5 * np.asarray(yaw_rad))
        self.sp_quat[3] = np.sin(0.5 * np.asarray(yaw_rad))
        self.sp_thrust = np.zeros(n)
        # per-vehicle tunables (parameters)
        self.offboard_timeout_s = np.full(n, fs.offboard_timeout_s)
        self.failsafe_hold_s = np.full(n, fs.hold_s)
        self.land_speed_m_s = np.full(n, fs.descent_rate_m_s)
        self.failure_injection: BoolArray = np.full(n, config.failure_injection, dtype=bool)

    # -- queries -------------------------------------------------------------------------------
    def setpoint_fresh(self, i: int, t_s: float) -> bool:
        """Whether vehicle ``i`` received a valid setpoint within its offboard timeout."""
        return bool(t_s - self.last_setpoint_s[i] <= self.offboard_timeout_s[i])

    @property
    def flying(self) -> BoolArray:
        """Armed and off the ground (N,)."""
        return self.armed & ~self.landed

    # -- commands ------------------------------------------------------------------------------
    def arm(self, i: int, t_s: float) -> tuple[Outcome, list[VehicleEvent]]:
        """MAV_CMD_COMPONENT_ARM_DISARM param1 = 1."""
        if self.crashed[i]:
            return Outcome(Result.FAILED, "Arming denied: vehicle crashed"), []
        if self.armed[i]:
            return ACCEPTED, []
        if not self.motor_ok[:, i].all():
            return Outcome(Result.FAILED, "Arming denied: motor failure"), []
        if not self.landed[i]:
            return Outcome(Result.DENIED, "Arming denied: not landed"), []
        if self.mode[i] == Mode.LAND:
            return Outcome(Result.DENIED, "Arming denied: in LAND mode"), []
        if self.mode[i] == Mode.OFFBOARD and not self.setpoint_fresh(i, t_s):
            return Outcome(Result.DENIED, "Arming denied: no offboard setpoints"), []
        self.armed[i] = True
        self.failsafe[i] = False
        return ACCEPTED, [VehicleEvent(i, Severity.INFO, "Armed", "armed")]

    def disarm(self, i: int, force: bool = False) -> tuple[Outcome, list[VehicleEvent]]:
        """MAV_CMD_COMPONENT_ARM_DISARM param1 = 0 (param2 = 21196 forces it in flight)."""
        if not self.armed[i]:
            return ACCEPTED, []
        if not (self.landed[i] or force):
            return Outcome(Result.DENIED, "Disarming denied: not landed"), []
        self._disarm(i)
        text = "Disarmed (forced in flight)" if not self.landed[i] else "Disarmed"
        return ACCEPTED, [VehicleEvent(i, Severity.INFO, text, "disarmed")]

    def set_mode(self, i: int, mode: Mode, t_s: float) -> tuple[Outcome, list[VehicleEvent]]:
        """Switch vehicle ``i`` to ``mode``; OFFBOARD needs fresh setpoints."""
        if self.crashed[i]:
            return Outcome(Result.FAILED, "Mode change denied: vehicle crashed"), []
        if mode == Mode.OFFBOARD and not self.setpoint_fresh(i, t_s):
            return Outcome(Result.DENIED, "Offboard denied: no setpoint stream"), []
        if self.mode[i] == mode and not self.failsafe[i]:
            return ACCEPTED, []
        self.failsafe[i] = False
        self._enter(i, mode)
        return ACCEPTED, [VehicleEvent(i, Severity.INFO, f"Mode {mode.name}", "mode")]

    def setpoint(self, i: int, sp: AttitudeSetpoint, t_s: float) -> None:
        """Store a validated offboard setpoint received at ``t_s``."""
        self.sp_euler_rad[:, i] = sp.euler_rad
        self.sp_quat[:, i] = sp.quat_wxyz
        self.sp_thrust[i] = sp.thrust
        self.last_setpoint_s[i] = t_s

    def setpoints(
        self,
        vehicles: npt.NDArray[np.intp],
        quat_wxyz: FloatArray,
        euler_rad: FloatArray,
        thrust: FloatArray,
        t_s: float,
    ) -> None:
        """:meth:`setpoint` of K validated setpoints at once, received at ``t_s``: vehicles
        (K,) distinct, unit quaternions (4, K), their ZYX angles (3, K) rad and normalised thrusts
        (K,) (an in-process swarm hands every vehicle its setpoint of the tick in one call)."""
        self.sp_quat[:, vehicles] = quat_wxyz
        self.sp_euler_rad[:, vehicles] = euler_rad
        self.sp_thrust[vehicles] = thrust
        self.last_setpoint_s[vehicles] = t_s

    def motor_failure(self, i: int, motor: int | None, off: bool) -> list[VehicleEvent]:
        """Motor ``motor`` (0..3, None: all) off (``off``) or working again. All off = crash."""
        if self.crashed[i]:
            return []
        if motor is None and off:
            self.crashed[i] = True
            self._disarm(i)
            text = "Failure injected: all motors off"
            return [VehicleEvent(i, Severity.EMERGENCY, text, "motor_failure")]
        motors = slice(None) if motor is None else slice(motor, motor + 1)
        self.motor_ok[motors, i] = not off
        which = "all motors" if motor is None else f"motor {motor + 1}"
        text = f"Failure injected: {which} off" if off else f"Failure cleared: {which}"
        severity = Severity.CRITICAL if off else Severity.NOTICE
        return [VehicleEvent(i, severity, text, "motor_failure")]

    # -- time ----------------------------------------------------------------------------------
    def update(
        self, t_s: float, altitude_z_m: FloatArray, impact_m_s: FloatArray
    ) -> list[VehicleEvent]:
        """Advance every state machine to ``t_s``, given the NED z (N,) m of each vehicle and
        the largest touchdown speed (N,) m/s since the last update."""
        # (each step's vehicles found with one reduction first: most periods have none, and an
        # empty flatnonzero costs as much as the test; swarm simulate updates every tick)
        events: list[VehicleEvent] = []
        self.landed = landed = altitude_z_m >= -LANDED_ALTITUDE_M
        if self._wrecked.any():
            self.silent |= self._wrecked
        self._impacts(impact_m_s, events)
        self._wrecked = self.crashed & landed
        self._failsafes(t_s, events)
        touched = self.armed & (self.mode == Mode.LAND) & landed
        if touched.any():
            for i in np.flatnonzero(touched):
                text = "Failsafe: landed, disarmed" if self.failsafe[i] else "Landed, disarmed"
                self._disarm(int(i))
                events.append(VehicleEvent(int(i), Severity.NOTICE, text, "disarmed"))
        return events

    def _failsafes(self, t_s: float, events: list[VehicleEvent]) -> None:
        """The offboard-loss failsafe: armed in OFFBOARD without a valid setpoint for the
        offboard timeout -> level hold for the hold time -> land (a dialect may have others:
        sitl_sim/vehicle/copter.py)."""
        lost = self.armed & (self.mode == Mode.OFFBOARD) & ~self.failsafe
        lost &= t_s - self.last_setpoint_s > self.offboard_timeout_s
        if not lost.any() and not self.failsafe.any():
            return
        for i in np.flatnonzero(lost):
            self.failsafe[i], self.failsafe_since_s[i] = True, t_s
            self._enter(int(i), Mode.HOLD)
            timeout = float(self.offboard_timeout_s[i])
            text = f"Failsafe: offboard lost ({timeout:g} s), level hold"
            events.append(VehicleEvent(int(i), Severity.CRITICAL, text, "failsafe"))
        descend = self.failsafe & (self.mode == Mode.HOLD)
        descend &= t_s - self.failsafe_since_s >= self.failsafe_hold_s
        for i in np.flatnonzero(descend):
            self._enter(int(i), Mode.LAND)
            text = "Failsafe: descending to land"
            events.append(VehicleEvent(int(i), Severity.CRITICAL, text, "failsafe"))

    def _impacts(self, impact_m_s: FloatArray, events: list[VehicleEvent]) -> None:
        hard = impact_m_s > self.config.hard_landing_m_s
        if not hard.any():
            return
        for i in np.flatnonzero(hard):
            speed = float(impact_m_s[i])
            if self.crashed[i]:
                text = f"Crashed: hit the ground at {speed:.1f} m/s"
            else:
                self.crashed[i] = True
                self._disarm(int(i))
                text = f"Hard landing at {speed:.1f} m/s: vehicle destroyed"
            events.append(VehicleEvent(int(i), Severity.EMERGENCY, text, "hard_landing"))

    def _enter(self, i: int, mode: Mode) -> None:
        self.mode[i] = int(mode)
        self.hold_z_m[i] = np.nan  # latched from the state on the next physics step

    def _disarm(self, i: int) -> None:
        self.armed[i] = False
        self.failsafe[i] = False
        self._enter(i, Mode.HOLD)
