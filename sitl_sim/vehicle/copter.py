"""The ArduCopter dialect's flight core: modes, arming readiness, GUIDED_NOGPS setpoints. Pure.

What an ArduCopter 4.6 vehicle does differently from the simulator's PX4 autopilot
(:mod:`sitl_sim.vehicle.autopilot`, whose state machine and arrays it keeps; the MAVLink side is
sitl_sim/mavlink_edge/dialect.py). Modes keep the simulator's three
(:class:`~sitl_sim.vehicle.autopilot.Mode`), named as ArduCopter numbers them (:data:`COPTER_MODE`):
OFFBOARD is GUIDED_NOGPS, HOLD is BRAKE, LAND is LAND.

- Readiness: for ``ekf_ready_s`` of simulated time after start the EKF has not initialised and
  the GPS has no fix (:attr:`CopterAutopilot.ready` False); arming is refused meanwhile (FAILED,
  with ArduCopter's pre-arm texts, :data:`PREARM_TEXTS`) and BRAKE cannot be entered ("requires
  position"). Once ready, :data:`READY_TEXT` is reported once.
- Arming only in GUIDED_NOGPS (BRAKE and LAND are not armable: "Arm: Mode not armable"), on the
  ground, without a setpoint stream. Disarming (by command, on touchdown in LAND, on a crash)
  keeps the mode, as ArduCopter does.
- GUIDED_NOGPS is entered without setpoints: it starts level at the current yaw holding its
  altitude (ArduCopter's ``angle_control_start``). Each SET_ATTITUDE_TARGET's thrust (clamped to
  0..1) is read per the vehicle's GUID_OPTIONS *when it arrives*: without bit 3
  (:data:`~protocols.mavlink.conventions.GUID_OPTIONS_THRUST`) it is a climb rate
  (:func:`climb_rate_m_s`), flown by the altitude controller (:class:`CopterGuidance`); with it,
  the motors' linearised throttle, divided by the cosine of the current tilt (angle boost).
  Armed on the ground, a setpoint that neither climbs nor has positive thrust keeps the motors at
  ground idle (ArduCopter's land-complete rule); a positive one takes off.

Failsafes: the real firmware's, not the simulator's PX4 offboard-loss failsafe (hold, then land),
so that what an agent meets here is what it meets on an ArduCopter:

- GUID_TIMEOUT: no new SET_ATTITUDE_TARGET for ``GUID_TIMEOUT`` seconds (3 by default) -> level at
  the current yaw and hold the altitude, *staying in GUIDED_NOGPS* (a thrust setpoint falls back
  to the climb-rate controller), silently, as ArduCopter does. Alone, a vehicle whose companion
  computer died hovers on.
- The GCS heartbeat failsafe, which is what lands such a vehicle on an ArduCopter (the project's
  agents configure it: drone_agent/process/dialects.py): once a HEARTBEAT from system SYSID_MYGCS
  (any component, on any link) has been seen, none for FS_GCS_TIMEOUT (5 s) of *simulated* time with
  FS_GCS_ENABLE set -> "GCS Failsafe" (WARNING), HEARTBEAT state CRITICAL; on the ground it
  disarms ("GCS Failsafe - Disarming"), in the air it lands (FS_GCS_ENABLE 5, and 1-4, 6, whose
  RTL and SmartRTL this simulator does not fly) or brakes (7, "Brake or Land"). A heartbeat again
  clears it ("GCS Failsafe Cleared"; the mode stays). FS_GCS_ENABLE is 0 by default: no failsafe.

The simulator's own ``COM_OF_LOSS_T``/``COM_FS_HOLD_T`` do not exist in this dialect's table.
Parameters added (:func:`copter_params`, ArduCopter 4.6 names): GUID_OPTIONS (INT32, settable),
MOT_THST_HOVER (read-only: the hover fraction of the maximum thrust, ``1 / thrust_to_weight``),
WPNAV_SPEED_UP and WPNAV_SPEED_DN (cm/s), GUID_TIMEOUT (s), SYSID_THISMAV (INT16, read-only),
SYSID_MYGCS (INT16, 255), FS_GCS_ENABLE (INT8, 0) and FS_GCS_TIMEOUT (s, 5).

Deliberate simplifications: the altitude controller is the simulator's (a proportional altitude
loop feeding the vertical-speed loop of HOLD/LAND, about the hover thrust, the same thrust then
angle-boosted), not ArduCopter's PID with its acceleration limits; the take-off is immediate (no
spool-up); the timeout's and the entry's level attitude keep the current yaw.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from protocols.mavlink.conventions import (
    GUID_OPTIONS_THRUST,
    GUID_TIMEOUT_S,
    WPNAV_SPEED_DN_CM_S,
    WPNAV_SPEED_UP_CM_S,
    CopterMode,
)
from protocols.model.frames import FloatArray
from sitl_sim.physics.attitude_control import yaw_from_quat_batch
from sitl_sim.physics.dynamics import QUAT
from sitl_sim.vehicle.autopilot import (
    ACCEPTED,
    Autopilot,
    AutopilotConfig,
    Mode,
    Outcome,
    Result,
    Severity,
    VehicleEvent,
)
from sitl_sim.vehicle.failsafe import vertical_speed_hold
from sitl_sim.vehicle.guidance import Guidance
from sitl_sim.vehicle.setpoint import AttitudeSetpoint
from sitl_sim.vehicle.tunables import PARAM_INT8, PARAM_INT16, PARAM_INT32, ParamSpec, array_spec

#: The ArduCopter mode number each simulator mode is reported as.
COPTER_MODE = {
    Mode.OFFBOARD: CopterMode.GUIDED_NOGPS,
    Mode.HOLD: CopterMode.BRAKE,
    Mode.LAND: CopterMode.LAND,
}
#: What ArduCopter says when arming is refused before its EKF and GPS are ready (CRITICAL).
PREARM_TEXTS = ("PreArm: EKF attitude is bad", "PreArm: GPS 1: Bad fix")
#: ... when the mode is not armable (CRITICAL), and once the EKF is ready (INFO).
NOT_ARMABLE_TEXT = "Arm: Mode not armable"
READY_TEXT = "EKF3 IMU0 is using GPS"
#: The cosine of the tilt the angle boost divides by is never taken below this (ArduCopter).
MIN_BOOST_COS = 0.1
#: How far (m) the climb-rate controller's altitude target may run ahead of the vehicle.
ALTITUDE_LEASH_M = 1.0
#: Parameters of the simulator's PX4 failsafe, absent from this dialect's table.
PX4_FAILSAFE_PARAMS = ("COM_OF_LOSS_T", "COM_FS_HOLD_T")
#: The GCS failsafe's defaults: SYSID_MYGCS, FS_GCS_TIMEOUT (s); FS_GCS_ENABLE's "brake or land".
DEFAULT_GCS_SYSID = 255
DEFAULT_GCS_TIMEOUT_S = 5.0
FS_GCS_BRAKE_OR_LAND = 7


def climb_rate_m_s(
    thrust: FloatArray, speed_up_cm_s: FloatArray, speed_dn_cm_s: FloatArray
) -> FloatArray:
    """ArduCopter's reading of SET_ATTITUDE_TARGET's thrust (N,) as a climb rate (N,) m/s, up
    positive: clamped to 0..1; 0.5 holds, 1 climbs at WPNAV_SPEED_UP, 0 descends at
    WPNAV_SPEED_DN (cm/s, (N,) or scalars), linear in between."""
    t = np.clip(np.asarray(thrust, dtype=float), 0.0, 1.0)
    up = (t - 0.5) * 2.0 * np.asarray(speed_up_cm_s) / 100.0
    down = (0.5 - t) * 2.0 * np.abs(np.asarray(speed_dn_cm_s)) / 100.0
    out: FloatArray = np.where(t > 0.5, up, np.where(t < 0.5, -down, 0.0))
    return out


def angle_boost(thrust: FloatArray, quat: FloatArray) -> FloatArray:
    """Normalised thrust (N,) for a level-flight thrust (N,) at attitudes ``quat`` (4, N)
    (w, x, y, z): divided by ``cos(roll) cos(pitch)`` (``1 - 2 (x² + y²)``), taken at least
    :data:`MIN_BOOST_COS`; clipped to 0..1."""
    cos_tilt = 1.0 - 2.0 * (quat[1] * quat[1] + quat[2] * quat[2])
    out: FloatArray = np.clip(thrust / np.maximum(cos_tilt, MIN_BOOST_COS), 0.0, 1.0)
    return out


class CopterAutopilot(Autopilot):
    """The autopilots of ``n`` ArduCopter vehicles (module doc). ``hover_throttle``: the
    normalised thrust that hovers (MOT_THST_HOVER); ``ekf_ready_s``: simulated seconds after
    start before the EKF and GPS are ready."""

    def __init__(
        self,
        n: int,
        config: AutopilotConfig,
        yaw_rad: FloatArray,
        hover_throttle: float,
        ekf_ready_s: float,
    ) -> None:
        super().__init__(n, config, yaw_rad)
        self.offboard_timeout_s[:] = GUID_TIMEOUT_S  # GUID_TIMEOUT
        self.guid_options = np.zeros(n)
        self.speed_up_cm_s = np.full(n, WPNAV_SPEED_UP_CM_S)
        self.speed_dn_cm_s = np.full(n, WPNAV_SPEED_DN_CM_S)
        self.hover_throttle = np.full(n, hover_throttle)
        #: the last setpoint's thrust is a thrust (GUID_OPTIONS bit 3 when it came), not a climb
        self.sp_use_thrust: npt.NDArray[np.bool_] = np.zeros(n, dtype=bool)
        #: GUIDED_NOGPS without an attitude target (just entered, or GUID_TIMEOUT): level, hold
        self.no_target: npt.NDArray[np.bool_] = np.ones(n, dtype=bool)
        self.ready_at_s = np.full(n, float(ekf_ready_s))
        #: the EKF and GPS are ready (pre-arm checks pass)
        self.ready: npt.NDArray[np.bool_] = np.zeros(n, dtype=bool)
        self._all_ready = False
        # the GCS heartbeat failsafe (module doc); ``failsafe`` says it is on
        self.gcs_sysid = np.full(n, float(DEFAULT_GCS_SYSID))
        self.fs_gcs_enable = np.zeros(n)
        self.fs_gcs_timeout_s = np.full(n, DEFAULT_GCS_TIMEOUT_S)
        #: when a HEARTBEAT of system SYSID_MYGCS was last seen (s; -inf: never)
        self.gcs_seen_s = np.full(n, -np.inf)
        self.sp_thrust[:] = 0.5  # a climb rate of 0

    # -- commands ------------------------------------------------------------------------------
    def arm(self, i: int, t_s: float) -> tuple[Outcome, list[VehicleEvent]]:
        """Arm: pre-arm checks (EKF, GPS), an armable mode (GUIDED_NOGPS), motors, on the
        ground; no setpoint stream needed."""
        if self.crashed[i]:
            return Outcome(Result.FAILED, "Arming denied: vehicle crashed"), []
        if self.armed[i]:
            return ACCEPTED, []
        if not self.ready[i]:
            return Outcome(Result.FAILED), [
                VehicleEvent(i, Severity.CRITICAL, text) for text in PREARM_TEXTS
            ]
        if self.mode[i] != Mode.OFFBOARD:
            return Outcome(Result.FAILED), [VehicleEvent(i, Severity.CRITICAL, NOT_ARMABLE_TEXT)]
        if not self.motor_ok[:, i].all():
            return Outcome(Result.FAILED, "Arming denied: motor failure"), []
        if not self.landed[i]:
            return Outcome(Result.DENIED, "Arming denied: not landed"), []
        self.armed[i] = True
        return ACCEPTED, [VehicleEvent(i, Severity.INFO, "Armed")]

    def set_mode(self, i: int, mode: Mode, t_s: float) -> tuple[Outcome, list[VehicleEvent]]:
        """Switch to ``mode``: GUIDED_NOGPS needs no setpoints (it starts level, holding its
        altitude); BRAKE needs a position estimate (the EKF ready)."""
        if self.crashed[i]:
            return Outcome(Result.FAILED, "Mode change denied: vehicle crashed"), []
        if self.mode[i] == mode:
            return ACCEPTED, []
        name = COPTER_MODE[mode].name
        if mode == Mode.HOLD and not self.ready[i]:
            return Outcome(Result.FAILED, f"Mode change to {name} failed: requires position"), []
        self._enter(i, mode)
        if mode == Mode.OFFBOARD:
            self.no_target[i] = True
            self.sp_use_thrust[i] = False
            self.sp_thrust[i] = 0.5
            self.last_setpoint_s[i] = t_s
        return ACCEPTED, [VehicleEvent(i, Severity.INFO, f"Mode {name}")]

    def setpoint(self, i: int, sp: AttitudeSetpoint, t_s: float) -> None:
        """A validated SET_ATTITUDE_TARGET (thrust already clamped to 0..1), read as a thrust or
        a climb rate per GUID_OPTIONS now."""
        super().setpoint(i, sp, t_s)
        self.sp_use_thrust[i] = bool(int(self.guid_options[i]) & GUID_OPTIONS_THRUST)
        self.no_target[i] = False

    def heartbeat_from(self, sysid: int, t_s: float, vehicle: int | None = None) -> None:
        """A HEARTBEAT of system ``sysid`` reached ``vehicle`` (None: every vehicle) at ``t_s``:
        the GCS of those whose SYSID_MYGCS it is was seen."""
        if vehicle is None:
            self.gcs_seen_s[self.gcs_sysid == sysid] = t_s
        elif self.gcs_sysid[vehicle] == sysid:
            self.gcs_seen_s[vehicle] = t_s

    # -- time ----------------------------------------------------------------------------------
    def update(
        self, t_s: float, altitude_z_m: FloatArray, impact_m_s: FloatArray
    ) -> list[VehicleEvent]:
        """As :meth:`Autopilot.update`, plus the EKF becoming ready."""
        events = super().update(t_s, altitude_z_m, impact_m_s)
        if not self._all_ready:
            for i in np.flatnonzero(~self.ready & (t_s >= self.ready_at_s - 1e-9)):
                self.ready[i] = True
                events.append(VehicleEvent(int(i), Severity.INFO, READY_TEXT))
            self._all_ready = bool(self.ready.all())
        return events

    def _failsafes(self, t_s: float, events: list[VehicleEvent]) -> None:
        """GUID_TIMEOUT (level and hold the altitude, in GUIDED_NOGPS) and the GCS heartbeat
        failsafe (module doc)."""
        stale = (self.mode == Mode.OFFBOARD) & ~self.no_target
        stale &= t_s - self.last_setpoint_s > self.offboard_timeout_s
        self.no_target |= stale
        watched = (self.fs_gcs_enable > 0) & np.isfinite(self.gcs_seen_s)
        if not (watched.any() or self.failsafe.any()):
            return
        late = t_s - self.gcs_seen_s > self.fs_gcs_timeout_s
        for i in np.flatnonzero(self.failsafe & ~late):
            self.failsafe[i] = False
            events.append(VehicleEvent(int(i), Severity.WARNING, "GCS Failsafe Cleared"))
        for i in np.flatnonzero(watched & late & ~self.failsafe):
            events += self._gcs_lost(int(i), t_s)

    def _gcs_lost(self, i: int, t_s: float) -> list[VehicleEvent]:
        """The GCS failsafe's action (module doc)."""
        self.failsafe[i], self.failsafe_since_s[i] = True, t_s
        if not self.armed[i]:
            return [VehicleEvent(i, Severity.WARNING, "GCS Failsafe")]
        if self.landed[i]:
            self._disarm(i)
            return [VehicleEvent(i, Severity.WARNING, "GCS Failsafe - Disarming")]
        brake = int(self.fs_gcs_enable[i]) == FS_GCS_BRAKE_OR_LAND and self.ready[i]
        mode = Mode.HOLD if brake else Mode.LAND
        events = [VehicleEvent(i, Severity.WARNING, "GCS Failsafe")]
        if self.mode[i] != mode:
            self._enter(i, mode)
            events.append(VehicleEvent(i, Severity.INFO, f"Mode {COPTER_MODE[mode].name}"))
        return events

    def _disarm(self, i: int) -> None:
        """Disarm, keeping the mode (ArduCopter stays in LAND after landing) and any failsafe
        (it clears when the GCS is heard again)."""
        self.armed[i] = False
        self.hold_z_m[i] = np.nan


class CopterGuidance(Guidance):
    """What each ArduCopter autopilot asks of its inner loop (module doc): HOLD (BRAKE) and LAND
    as the simulator's; GUIDED_NOGPS from the setpoint's attitude with a climb-rate controller or
    an angle-boosted thrust. ``dt_s``: the physics step (s), at which :meth:`command` runs."""

    def __init__(self, autopilot: CopterAutopilot, hover_thrust: float, dt_s: float) -> None:
        super().__init__(autopilot, hover_thrust)
        self.cap = autopilot
        self.dt_s = dt_s
        n = autopilot.n
        self.target_z_m = np.zeros(n)  # the climb-rate controller's altitude target (NED z)
        self._climbing = np.zeros(n, dtype=bool)  # under it in the last period
        self._climb_idx: npt.NDArray[np.intp] = np.zeros(0, dtype=np.intp)
        self._climb_m_s = np.zeros(0)
        self._boost_idx: npt.NDArray[np.intp] = np.zeros(0, dtype=np.intp)
        self._boost_u = np.zeros(0)

    def prepare(self, state: FloatArray) -> None:
        """The base commands, then GUIDED_NOGPS's: idle, climb-rate or thrust, per vehicle."""
        super().prepare(state)
        ap = self.cap
        idx = np.flatnonzero(ap.armed & (ap.mode == Mode.OFFBOARD))
        if not idx.size:
            self._climb_idx = self._boost_idx = idx
            self._climbing[:] = False
            return
        no_target = ap.no_target[idx]
        use_thrust = ap.sp_use_thrust[idx] & ~no_target
        wire = ap.sp_thrust[idx]
        climb = climb_rate_m_s(wire, ap.speed_up_cm_s[idx], ap.speed_dn_cm_s[idx])
        climb[no_target] = 0.0
        positive = np.where(use_thrust, wire > 0.0, climb > 0.0)
        idle = ap.landed[idx] & ~positive
        level = idx[no_target | idle]
        if level.size:
            self.euler_rad[:, level] = 0.0
            self.euler_rad[2, level] = yaw_from_quat_batch(state[QUAT][:, level])
        self.thrust[idx[idle]] = 0.0
        by_climb = ~use_thrust & ~idle
        climb_idx = idx[by_climb]
        fresh = climb_idx[~self._climbing[climb_idx]]  # the altitude target starts where it is
        self.target_z_m[fresh] = state[2, fresh]
        self._climbing[:] = False
        self._climbing[climb_idx] = True
        self._climb_idx, self._climb_m_s = climb_idx, climb[by_climb]
        by_thrust = use_thrust & ~idle
        self._boost_idx, self._boost_u = idx[by_thrust], wire[by_thrust]

    def command(self, state: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Attitude (3, N) and thrust (N,) for one physics step at ``state`` (13, N)."""
        euler, thrust = super().command(state)
        idx = self._climb_idx
        if idx.size:
            ap = self.ap
            z = state[2, idx]
            target = self.target_z_m[idx] - self._climb_m_s * self.dt_s
            target = np.clip(target, z - ALTITUDE_LEASH_M, z + ALTITUDE_LEASH_M)
            self.target_z_m[idx] = target
            limit = ap.config.max_climb_m_s
            correction = np.clip(ap.config.altitude_gain_per_s * (target - z), -limit, limit)
            _, level_thrust = vertical_speed_hold(
                state[5, idx],
                euler[2, idx],
                correction - self._climb_m_s,
                self.hover_thrust,
                ap.config.failsafe.vertical_speed_gain_per_s,
            )
            thrust[idx] = angle_boost(level_thrust, state[QUAT][:, idx])
        idx = self._boost_idx
        if idx.size:
            thrust[idx] = angle_boost(self._boost_u, state[QUAT][:, idx])
        return euler, thrust


def copter_params(ap: CopterAutopilot, sysids: list[int]) -> tuple[ParamSpec, ...]:
    """The parameters ArduCopter's GUIDED_NOGPS flight depends on (module doc); ranges as
    ArduPilot documents them."""
    return (
        array_spec("GUID_OPTIONS", ap.guid_options, 0.0, float(2**31 - 1), PARAM_INT32),
        array_spec("MOT_THST_HOVER", ap.hover_throttle, 0.0, 1.0, writable=False),
        array_spec("WPNAV_SPEED_UP", ap.speed_up_cm_s, 10.0, 1000.0),
        array_spec("WPNAV_SPEED_DN", ap.speed_dn_cm_s, 10.0, 500.0),
        array_spec("GUID_TIMEOUT", ap.offboard_timeout_s, 0.1, 5.0),
        ParamSpec("SYSID_THISMAV", 1.0, 255.0, lambda i: float(sysids[i]), None, PARAM_INT16),
        array_spec("SYSID_MYGCS", ap.gcs_sysid, 1.0, 255.0, PARAM_INT16),
        array_spec("FS_GCS_ENABLE", ap.fs_gcs_enable, 0.0, 7.0, PARAM_INT8),
        array_spec("FS_GCS_TIMEOUT", ap.fs_gcs_timeout_s, 2.0, 120.0),
    )
