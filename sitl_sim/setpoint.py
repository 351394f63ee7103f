"""Validation of offboard attitude setpoints (SET_ATTITUDE_TARGET), pure and I/O-free.

A setpoint is flown only when every field the vehicle uses is sound (SPEC.md "Vehicle behaviour"):

- the attitude quaternion ``(w, x, y, z)``, body FRD -> world NED, is finite and its norm is
  within :data:`QUAT_NORM_TOLERANCE` of 1 (it is then normalised);
- the collective thrust is finite and within 0..1 of the vehicle's maximum (normalised, as PX4
  offboard);
- the type mask does not ask the vehicle to ignore the attitude or the thrust (this autopilot flies
  attitude + thrust only; body rates are always ignored).

Anything else is rejected with a :class:`Rejection` reason and counted by the caller, never flown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

#: Largest accepted deviation of the quaternion norm from 1 (sender round-off, float32 on the wire).
QUAT_NORM_TOLERANCE = 0.05
#: SET_ATTITUDE_TARGET type_mask bits (MAVLink ATTITUDE_TARGET_TYPEMASK).
TYPEMASK_THROTTLE_IGNORE = 64
TYPEMASK_ATTITUDE_IGNORE = 128


class Rejection(Enum):
    """Why a setpoint was not flown."""

    NOT_FINITE = "non-finite value"
    QUAT_NORM = "quaternion norm out of range"
    THRUST_RANGE = "thrust outside 0..1"
    UNSUPPORTED_MASK = "type_mask ignores attitude or thrust"


@dataclass(frozen=True)
class AttitudeSetpoint:
    """A validated setpoint: unit quaternion ``(w, x, y, z)`` body FRD -> world NED, the same
    attitude as ZYX angles ``(roll, pitch, yaw)`` in rad, and normalised thrust 0..1."""

    quat_wxyz: tuple[float, float, float, float]
    euler_rad: tuple[float, float, float]
    thrust: float


def validate_attitude_target(
    quat_wxyz: tuple[float, float, float, float] | list[float],
    thrust: float,
    type_mask: int = 0,
) -> AttitudeSetpoint | Rejection:
    """The setpoint to fly, or the reason it must not be flown."""
    if type_mask & (TYPEMASK_ATTITUDE_IGNORE | TYPEMASK_THROTTLE_IGNORE):
        return Rejection.UNSUPPORTED_MASK
    if len(quat_wxyz) != 4:
        return Rejection.QUAT_NORM
    w, x, y, z = float(quat_wxyz[0]), float(quat_wxyz[1]), float(quat_wxyz[2]), float(quat_wxyz[3])
    thrust = float(thrust)
    isfinite = math.isfinite
    if not (isfinite(w) and isfinite(x) and isfinite(y) and isfinite(z) and isfinite(thrust)):
        return Rejection.NOT_FINITE
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(norm - 1.0) > QUAT_NORM_TOLERANCE:
        return Rejection.QUAT_NORM
    if not 0.0 <= thrust <= 1.0:
        return Rejection.THRUST_RANGE
    q = (w / norm, x / norm, y / norm, z / norm)
    return AttitudeSetpoint(q, euler_from_quat(q), thrust)


def euler_from_quat(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """ZYX angles ``(roll, pitch, yaw)`` rad of a unit quaternion ``(w, x, y, z)``; plain floats
    (one vehicle: cheaper than the numpy batch version)."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def quat_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Quaternion ``(w, x, y, z)`` body FRD -> world NED of ZYX angles (rad)."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )
