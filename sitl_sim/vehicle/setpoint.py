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

from protocols.model.frames import zyx_from_wxyz

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
    code, qw, qx, qy, qz, roll, pitch, yaw = checked_setpoint(w, x, y, z, thrust)
    if code:
        return REJECTIONS[code]
    return AttitudeSetpoint((qw, qx, qy, qz), (roll, pitch, yaw), thrust)


#: The rejections of :func:`checked_setpoint` by code (0: none, the setpoint may be flown).
REJECTIONS = {1: Rejection.NOT_FINITE, 2: Rejection.QUAT_NORM, 3: Rejection.THRUST_RANGE}


def checked_setpoint(
    w: float, x: float, y: float, z: float, thrust: float
) -> tuple[int, float, float, float, float, float, float, float]:
    """The checks of a setpoint's quaternion ``(w, x, y, z)`` and thrust (floats): ``(0, the
    unit quaternion, roll, pitch, yaw)`` if it may be flown, else ``(code, 0.0, ...)``
    (:data:`REJECTIONS`). Plain arithmetic that numba compiles as it is (setpoint_jit.py), with
    :func:`protocols.model.frames.zyx_from_wxyz` compiled too."""
    if not (
        math.isfinite(w)
        and math.isfinite(x)
        and math.isfinite(y)
        and math.isfinite(z)
        and math.isfinite(thrust)
    ):
        return 1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(norm - 1.0) > QUAT_NORM_TOLERANCE:
        return 2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if not 0.0 <= thrust <= 1.0:
        return 3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    qw, qx, qy, qz = w / norm, x / norm, y / norm, z / norm
    yaw, pitch, roll = zyx_from_wxyz(qw, qx, qy, qz)
    return 0, qw, qx, qy, qz, roll, pitch, yaw
