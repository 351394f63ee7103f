"""The MAVLink messages a simulated vehicle sends, built from the world's state.

pymavlink is used only as a codec: these functions return pymavlink message objects (a message
type plus its fields, no socket), and :class:`sitl_sim.mavlink_edge.channel.Channel` encodes them.

Identity (the PX4 dialect; ArduCopter's own messages are in
sitl_sim/mavlink_edge/copter_messages.py): HEARTBEAT says MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4, PX4
custom modes (protocols/mavlink/conventions.py), base_mode CUSTOM_MODE_ENABLED (+ SAFETY_ARMED when
armed), system_status STANDBY / ACTIVE / CRITICAL (failsafe) / EMERGENCY (crashed).

SYS_STATUS carries the vehicle's receive counters so that a peer can watch them:
``errors_comm`` = every rejected frame, ``errors_count1`` = malformed (bad CRC, bad prefix,
truncated), ``errors_count2`` = rejected setpoints (NaN/inf/out of range), ``errors_count3`` =
signature failures, ``errors_count4`` = wrong target system; ``drop_rate_comm`` the rejected share
(c%), ``load`` the simulator's busy share of wall time (d%). Counters saturate at 65535. Its battery
fields are the vehicle's simulated battery (sitl_sim/vehicle/battery.py): voltage (mV), current
(cA), remaining (%); GPS and battery are among the sensors present, enabled and healthy.

NAMED_VALUE_FLOAT ``agt_intime`` and ``agt_lag_ms`` (realtime only, to the GCS, once per status
interval, per vehicle whose agent answered in it): the share of control ticks its agent answered
in time and its worst lag (ms), see :mod:`sitl_sim.vehicle.tick_answers`.

ACTUATOR_OUTPUT_STATUS carries the rotor outputs (protocols/mavlink/conventions.py): the force
(N) of rotors 1..4 in ``actuator[0..3]`` in the mixer's order (sitl_sim/physics/mixer.py),
``active`` = 0b1111, ``time_usec`` the simulated time (µs) of the tick, as ``time_boot_ms`` is in
ms. The forces are those applied in the last physics step before the tick: zero when disarmed and
for a stopped motor.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import common as mavlink

from protocols.mavlink.conventions import (
    ACTUATOR_ROTORS,
    ACTUATOR_ROTORS_ACTIVE,
    MODE_HOLD,
    MODE_LAND,
    MODE_OFFBOARD,
    SYS_STATUS_PREARM_CHECK,
    truth_odometry_fields,
)
from protocols.mavlink.fast import packed
from protocols.model.frames import FloatArray, wxyz_from_zyx
from protocols.runtime.compiled import jit
from sitl_sim.physics.dynamics import POS, QUAT, RATES, VEL
from sitl_sim.vehicle.autopilot import Autopilot, Mode
from sitl_sim.vehicle.battery import Battery
from sitl_sim.vehicle.world import Snapshot, World

CUSTOM_MODE = {Mode.HOLD: MODE_HOLD, Mode.OFFBOARD: MODE_OFFBOARD, Mode.LAND: MODE_LAND}
_AUTO_FLAGS = (
    mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
    | mavlink.MAV_MODE_FLAG_AUTO_ENABLED
)
_SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
)
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
)
#: quadswarm 0.1.0, a development build (PX4's packing: major, minor, patch, type).
SOFTWARE_VERSION = (0 << 24) | (1 << 16) | (0 << 8) | mavlink.FIRMWARE_VERSION_TYPE_DEV
STATUSTEXT_LEN = 50
_U16 = 0xFFFF
#: SET_ATTITUDE_TARGET / ATTITUDE_TARGET type_mask: body rates ignored.
IGNORE_BODY_RATES = 0b0000_0111


@dataclass
class RxCounters:
    """What one vehicle received: accepted messages and rejected frames by reason."""

    rx: int = 0
    malformed: int = 0
    setpoint_rejected: int = 0
    signature_rejected: int = 0
    wrong_target: int = 0

    @property
    def rejected(self) -> int:
        """Every frame not acted on."""
        return self.malformed + self.setpoint_rejected + self.signature_rejected + self.wrong_target


def heartbeat(ap: Autopilot, i: int) -> Any:
    """HEARTBEAT of vehicle ``i``."""
    base_mode = _AUTO_FLAGS
    if ap.armed[i]:
        base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR,
        mavlink.MAV_AUTOPILOT_PX4,
        base_mode,
        CUSTOM_MODE[Mode(int(ap.mode[i]))],
        system_status(ap, i),
        3,
    )


def system_status(ap: Autopilot, i: int) -> int:
    """HEARTBEAT's MAV_STATE of vehicle ``i``: EMERGENCY crashed, CRITICAL in failsafe, ACTIVE
    armed, else STANDBY."""
    if ap.crashed[i]:
        return int(mavlink.MAV_STATE_EMERGENCY)
    if ap.failsafe[i]:
        return int(mavlink.MAV_STATE_CRITICAL)
    if ap.armed[i]:
        return int(mavlink.MAV_STATE_ACTIVE)
    return int(mavlink.MAV_STATE_STANDBY)


def sys_status(
    ap: Autopilot,
    i: int,
    counters: RxCounters,
    load: float,
    battery: Battery | None = None,
    prearm_ok: bool | None = None,
) -> Any:
    """SYS_STATUS of vehicle ``i`` with its receive counters and its battery (None: unknown);
    ``load`` is a 0..1 busy share. Absent subsystems (geofence) are reported healthy, as PX4
    does. ``prearm_ok`` (ArduPilot's MAV_SYS_STATUS_PREARM_CHECK; None: not reported, as PX4):
    the bit is present and enabled, healthy when the pre-arm checks pass; while they fail the
    GPS is reported unhealthy too (no fix)."""
    present = _SENSORS
    health = _SENSORS | mavlink.MAV_SYS_STATUS_GEOFENCE
    if not ap.motor_ok[:, i].all() or ap.crashed[i]:
        health &= ~mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    if prearm_ok is not None:
        present |= SYS_STATUS_PREARM_CHECK
        if prearm_ok:
            health |= SYS_STATUS_PREARM_CHECK
        else:
            health &= ~mavlink.MAV_SYS_STATUS_SENSOR_GPS
    total = counters.rx + counters.rejected
    drop = round(10_000 * counters.rejected / total) if total else 0
    return mavlink.MAVLink_sys_status_message(
        present,
        present,
        health,
        min(1000, round(1000 * load)),
        *_battery_fields(battery, i),
        min(drop, 10_000),
        min(counters.rejected, _U16),
        min(counters.malformed, _U16),
        min(counters.setpoint_rejected, _U16),
        min(counters.signature_rejected, _U16),
        min(counters.wrong_target, _U16),
    )


def _battery_fields(battery: Battery | None, i: int) -> tuple[int, int, int]:
    """SYS_STATUS's voltage (mV), current (cA) and remaining (%) of vehicle ``i``."""
    if battery is None:
        return _U16, -1, -1
    voltage_v, current_a, remaining = battery.reading(i)
    voltage_mv = min(_U16 - 1, max(0, round(1000.0 * voltage_v)))
    return voltage_mv, min(32767, max(0, round(100.0 * current_a))), round(100.0 * remaining)


#: A message's payloads for every vehicle at once: (N, payload size) bytes, each row what the
#: vehicle's one-by-one builder packs (the same bytes); None where some value would not pack as
#: struct packs it (a non-finite or too large float: the one-by-one builder is used then)
Rows = npt.NDArray[np.uint8] | None
_TIME_AND_SIX = np.dtype([("t", "<u4"), ("v", "<f4", (6,))])  # ATTITUDE, LOCAL_POSITION_NED
_ACTUATOR_OUTPUT = np.dtype([("t", "<u8"), ("active", "<u4"), ("v", "<f4", (32,))])


def _float32(values: FloatArray) -> npt.NDArray[np.float32] | None:
    """``values`` as struct's ``f`` packs each (C's conversion); None if one is not finite or
    too large for a float32 (struct refuses it: the one-by-one builder raises as before)."""
    with np.errstate(over="ignore"):
        out = values.astype(np.float32)
    return out if np.isfinite(out).all() else None


def _time_and_six(time_value: int, first: FloatArray, second: FloatArray) -> Rows:
    """Rows of ``<Iffffff``: a time, then the three values of ``first`` and ``second``."""
    six = _float32(np.concatenate((first, second), axis=1))
    if six is None or not 0 <= time_value < 2**32:
        return None
    rows = np.empty(six.shape[0], dtype=_TIME_AND_SIX)
    rows["t"] = time_value
    rows["v"] = six
    return rows.view(np.uint8).reshape(six.shape[0], _TIME_AND_SIX.itemsize)


def attitude_rows(snap: Snapshot) -> Rows:
    """:func:`attitude` of every vehicle (:data:`Rows`)."""
    _, _, euler, rates = snap.columns()
    return _time_and_six(snap.time_boot_ms, euler, rates)


def local_position_ned_rows(snap: Snapshot) -> Rows:
    """:func:`local_position_ned` of every vehicle (:data:`Rows`)."""
    position, velocity, _, _ = snap.columns()
    return _time_and_six(snap.time_boot_ms, position, velocity)


def actuator_output_status_rows(t_usec: int, forces_n: FloatArray) -> Rows:
    """:func:`actuator_output_status` of every vehicle (``forces_n`` (4, N); :data:`Rows`)."""
    forces = _float32(np.asarray(forces_n, dtype=np.float64)[:ACTUATOR_ROTORS].T)
    if forces is None or not 0 <= t_usec < 2**64:
        return None
    rows = np.zeros(forces.shape[0], dtype=_ACTUATOR_OUTPUT)
    rows["t"] = t_usec
    rows["active"] = ACTUATOR_ROTORS_ACTIVE
    rows["v"][:, :ACTUATOR_ROTORS] = forces
    return rows.view(np.uint8).reshape(forces.shape[0], _ACTUATOR_OUTPUT.itemsize)


_ATTITUDE_TARGET = np.dtype(
    [("t", "<u4"), ("q", "<f4", (4,)), ("rates", "<f4", (3,)), ("thrust", "<f4"), ("mask", "u1")]
)


@jit(calls={"wxyz_from_zyx": wxyz_from_zyx})
def _quaternions(euler, out):  # type: ignore[no-untyped-def]
    """:func:`wxyz_from_zyx` of each vehicle's ``euler`` (3, N) (roll, pitch, yaw) into ``out``
    (N, 4): compiled as it is (the C library's functions: the same bits)."""
    for i in range(euler.shape[1]):
        w, x, y, z = wxyz_from_zyx(euler[2, i], euler[1, i], euler[0, i])
        out[i, 0] = w
        out[i, 1] = x
        out[i, 2] = y
        out[i, 3] = z


def quaternions(euler: FloatArray) -> FloatArray:
    """(N, 4) :func:`wxyz_from_zyx` of each vehicle's (roll, pitch, yaw) ``euler`` (3, N)."""
    euler = np.ascontiguousarray(euler, dtype=np.float64)
    q = np.empty((euler.shape[1], 4))
    _quaternions(euler, q)
    return q


def attitude_target_rows(world: World) -> Rows:
    """:func:`attitude_target` of every vehicle (:data:`Rows`)."""
    euler, thrust = world.commanded()
    q = quaternions(euler)
    flown = np.where(world.autopilot.armed, np.asarray(thrust, dtype=np.float64), 0.0)
    values = _float32(np.concatenate((q, flown[:, None]), axis=1))
    t = world.time_boot_ms()
    if values is None or not 0 <= t < 2**32:
        return None
    rows = np.zeros(values.shape[0], dtype=_ATTITUDE_TARGET)
    rows["t"] = t
    rows["q"] = values[:, :4]
    rows["thrust"] = values[:, 4]
    rows["mask"] = IGNORE_BODY_RATES
    return rows.view(np.uint8).reshape(values.shape[0], _ATTITUDE_TARGET.itemsize)


def attitude(snap: Snapshot, i: int) -> Any:
    """ATTITUDE: (roll, pitch, yaw) rad and body rates rad/s at the snapshot's time."""
    roll, pitch, yaw = snap.euler_rad[i]
    p, q, r = snap.rates_rad_s[i]
    return packed(mavlink.MAVLink_attitude_message, snap.time_boot_ms, roll, pitch, yaw, p, q, r)


def local_position_ned(snap: Snapshot, i: int) -> Any:
    """LOCAL_POSITION_NED: position (m) and velocity (m/s) in the world NED frame."""
    x, y, z = snap.position_ned_m[i]
    vx, vy, vz = snap.velocity_ned_m_s[i]
    return packed(
        mavlink.MAVLink_local_position_ned_message, snap.time_boot_ms, x, y, z, vx, vy, vz
    )


def truth_odometry(world: World, i: int) -> Any:
    """ODOMETRY with vehicle ``i``'s true state (protocols/mavlink/conventions.py
    ``truth_odometry_fields``)."""
    s = world.state
    return mavlink.MAVLink_odometry_message(
        *truth_odometry_fields(
            time_usec(world), s[POS, i].tolist(), s[VEL, i].tolist(), s[QUAT, i].tolist(),
            s[RATES, i].tolist(),
        )
    )  # fmt: skip


def attitude_target(world: World, i: int) -> Any:
    """ATTITUDE_TARGET: the attitude (quaternion w, x, y, z) and normalised thrust the
    autopilot last gave vehicle ``i``'s inner loop (zero thrust when disarmed)."""
    euler, thrust = world.commanded()
    q = wxyz_from_zyx(float(euler[2, i]), float(euler[1, i]), float(euler[0, i]))
    flown = float(thrust[i]) if world.autopilot.armed[i] else 0.0
    return mavlink.MAVLink_attitude_target_message(
        world.time_boot_ms(), IGNORE_BODY_RATES, q, 0.0, 0.0, 0.0, flown
    )


def rotor_forces_n(world: World) -> FloatArray:
    """Rotor forces (4, N) N of every vehicle, rotors 1..4 in the mixer's order, as applied in the
    last physics step (0 if disarmed or stopped)."""
    speed = world.rotor_speed_rad_s
    return world.params.thrust_coeff * (speed * speed)


def time_usec(world: World) -> int:
    """The simulated time (µs) of the current tick (``time_boot_ms`` * 1000 up to rounding)."""
    return round(world.tick * 1_000_000 / world.config.control_hz)


def actuator_output_status(t_usec: int, forces_n: FloatArray) -> Any:
    """ACTUATOR_OUTPUT_STATUS: the forces (N) of rotors 1..4 (``forces_n`` (4,)) at simulated
    time ``t_usec`` (µs); the other 28 actuators are 0 and not active."""
    actuator = [float(f) for f in forces_n[:ACTUATOR_ROTORS]]
    actuator += [0.0] * (32 - len(actuator))
    return packed(
        mavlink.MAVLink_actuator_output_status_message, t_usec, ACTUATOR_ROTORS_ACTIVE, actuator
    )


#: NAMED_VALUE_FLOAT names of an agent's timing, sent to the GCS once per status interval in
#: realtime: the share of control ticks answered in time (0..1) and the worst lag (ms).
AGENT_IN_TIME = "agt_intime"
AGENT_LAG_MS = "agt_lag_ms"


def named_value(time_boot_ms: int, name: str, value: float) -> Any:
    """NAMED_VALUE_FLOAT ``name`` (at most 10 characters) = ``value`` at ``time_boot_ms``."""
    return mavlink.MAVLink_named_value_float_message(time_boot_ms, name.encode("ascii"), value)


def statustext(severity: int, text: str) -> Any:
    """STATUSTEXT, cut to the 50 bytes of one message."""
    return mavlink.MAVLink_statustext_message(severity, text.encode("utf-8")[:STATUSTEXT_LEN], 0, 0)


def autopilot_version(sysid: int) -> Any:
    """AUTOPILOT_VERSION: capabilities, software version, uid = system id."""
    custom = list(b"quadswrm")
    return mavlink.MAVLink_autopilot_version_message(
        CAPABILITIES, SOFTWARE_VERSION, 0, 0, 0, custom, [0] * 8, [0] * 8, 0, 0, sysid, [0] * 18
    )


def command_ack(command: int, result: int, target_system: int, target_component: int) -> Any:
    """COMMAND_ACK of ``command`` with a MAV_RESULT, addressed to the sender."""
    return mavlink.MAVLink_command_ack_message(
        command, result, 0, 0, target_system, target_component
    )


def param_value(
    name: str,
    value: float,
    index: int,
    count: int,
    param_type: int = mavlink.MAV_PARAM_TYPE_REAL32,
) -> Any:
    """PARAM_VALUE of a parameter of MAV_PARAM_TYPE ``param_type`` (REAL32 by default); the value
    travels as a float (an integer parameter as the float of its value, as ArduPilot sends it)."""
    encoded = name.encode("ascii")
    return mavlink.MAVLink_param_value_message(encoded, value, param_type, count, index)


def timesync(tc1: int, ts1: int) -> Any:
    """TIMESYNC reply: ``tc1`` our time (ns), ``ts1`` the request's."""
    return mavlink.MAVLink_timesync_message(tc1, ts1)


def message_interval(msg_id: int, interval_us: int) -> Any:
    """MESSAGE_INTERVAL: the interval (µs; -1 off, 0 not available) of ``msg_id``."""
    return mavlink.MAVLink_message_interval_message(msg_id, interval_us)
