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

import numpy as np
import numpy.typing as npt

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


def validate_attitude_targets(
    quats_wxyz: npt.ArrayLike, thrusts: npt.ArrayLike
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """:func:`validate_attitude_target` (type mask 0) of K setpoints at once, quaternions
    (K, 4) and thrusts (K,): each one's code (K,; 0 valid, else the index of its
    :data:`REJECTIONS`), normalised quaternion (K, 4) and ZYX angles (K, 3) rad (zeros where
    rejected). The same rule (:func:`checked_setpoint`), compiled (sitl_sim/setpoint_jit.py:
    numba is imported on the first call)."""
    from sitl_sim import setpoint_jit

    q = np.ascontiguousarray(quats_wxyz, dtype=np.float64).reshape(-1, 4)
    t = np.ascontiguousarray(thrusts, dtype=np.float64).reshape(-1)
    codes = np.zeros(t.shape[0], dtype=np.int64)
    unit, euler = np.zeros((t.shape[0], 4)), np.zeros((t.shape[0], 3))
    setpoint_jit.check_all(q, t, codes, unit, euler)
    return codes, unit, euler


#: The rejections of :func:`checked_setpoint` by code (0: none, the setpoint may be flown).
REJECTIONS = {1: Rejection.NOT_FINITE, 2: Rejection.QUAT_NORM, 3: Rejection.THRUST_RANGE}


def checked_setpoint(
    w: float, x: float, y: float, z: float, thrust: float
) -> tuple[int, float, float, float, float, float, float, float]:
    """The checks of a setpoint's quaternion ``(w, x, y, z)`` and thrust (floats): ``(0, the
    unit quaternion, roll, pitch, yaw)`` if it may be flown, else ``(code, 0.0, ...)``
    (:data:`REJECTIONS`). Plain arithmetic that numba compiles as it is (setpoint_jit.py)."""
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
    roll, pitch, yaw = euler_zyx(qw, qx, qy, qz)
    return 0, qw, qx, qy, qz, roll, pitch, yaw


def euler_from_quat(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """ZYX angles ``(roll, pitch, yaw)`` rad of a unit quaternion ``(w, x, y, z)``; plain floats
    (one vehicle: cheaper than the numpy batch version)."""
    w, x, y, z = q
    return euler_zyx(w, x, y, z)


def euler_zyx(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """:func:`euler_from_quat` of the quaternion's four floats (numba compiles it too)."""
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
