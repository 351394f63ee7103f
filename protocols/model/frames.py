"""Frames, rotations and quaternions: the one place that defines them.

Conventions (SPEC.md):
- World frame NED (x north, y east, z down), metres, seconds, radians.
- Body frame FRD. ``R_b = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` maps body vectors to world.
- Quaternions are ``(w, x, y, z)`` (MAVLink order), body FRD -> world NED.
- ZYX angles go in and come out in one order everywhere here: ``(yaw, pitch, roll)``, the order
  the rotations compose in. (Arrays that *store* the three, as the simulator's ``euler_rad``
  rows and the descriptor vector, keep MAVLink ATTITUDE's ``(roll, pitch, yaw)``: a layout, read
  by the callers, e.g. ``quat_from_zyx(e[2], e[1], e[0])``.)
- Gravity is ``+G_M_S2 * E3`` in NED.

Each quaternion formula is written once, on plain floats with :mod:`math`'s functions
(:func:`zyx_from_wxyz`, :func:`yaw_from_wxyz`, :func:`wxyz_from_zyx`): the C library's, which
CPython and numba both call, so numba compiles them as they are (sitl_sim/vehicle/setpoint_jit.py)
and the compiled values are the plain ones to the last bit. The numpy versions
(:func:`quat_from_zyx`, :func:`zyx_from_quat`, :func:`zyx_from_quat_batch`,
:func:`yaw_from_quat_batch`) run the same code with numpy's functions bound in place of math's
(:func:`~protocols.runtime.same_code.same_code`), operation for operation. Their values can still
differ from the float versions' in the last bit (numpy's ``arctan2`` and ``arcsin`` use SIMD code on
some CPUs), so where two runs are compared bit for bit (``swarm simulate`` against the lockstep
flight) both sides convert with the same version.
"""

from __future__ import annotations

import math
import types

import numpy as np
import numpy.typing as npt

from protocols.runtime.same_code import same_code

FloatArray = npt.NDArray[np.float64]

G_M_S2 = 9.81
E3: FloatArray = np.array([0.0, 0.0, 1.0])


# -- rotation matrices --------------------------------------------------------------------------


def rot_zyx(yaw: float, pitch: float, roll: float) -> FloatArray:
    """Rotation matrix (3, 3) body -> world, ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    out: FloatArray = rot_zyx_batch(np.array([yaw]), np.array([pitch]), np.array([roll]))[0]
    return out


def rot_zyx_batch(yaw: FloatArray, pitch: FloatArray, roll: FloatArray) -> FloatArray:
    """Rotation matrices (N, 3, 3) body -> world for arrays of ZYX angles (N,), radians."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    out = np.empty((np.shape(yaw)[0], 3, 3))
    out[:, 0, 0] = cy * cp
    out[:, 0, 1] = cy * sp * sr - sy * cr
    out[:, 0, 2] = cy * sp * cr + sy * sr
    out[:, 1, 0] = sy * cp
    out[:, 1, 1] = sy * sp * sr + cy * cr
    out[:, 1, 2] = sy * sp * cr - cy * sr
    out[:, 2, 0] = -sp
    out[:, 2, 1] = cp * sr
    out[:, 2, 2] = cp * cr
    return out


def zyx_from_rot(r: FloatArray) -> tuple[float, float, float]:
    """ZYX angles ``(yaw, pitch, roll)`` in radians of a rotation matrix (3, 3) body -> world."""
    yaw, pitch, roll = zyx_from_rot_batch(np.asarray(r)[None])
    return float(yaw[0]), float(pitch[0]), float(roll[0])


def zyx_from_rot_batch(r: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`zyx_from_rot` of rotation matrices (N, 3, 3): ``(yaw, pitch, roll)``, (N,) each."""
    pitch = np.arcsin(np.minimum(np.maximum(-r[:, 2, 0], -1.0), 1.0))  # np.clip's, cheaper
    yaw = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    roll = np.arctan2(r[:, 2, 1], r[:, 2, 2])
    return yaw, pitch, roll


# -- quaternions: the formulas, on plain floats (numba compiles them as they are) ---------------


def wxyz_from_zyx(yaw: float, pitch: float, roll: float) -> tuple[float, float, float, float]:
    """Quaternion ``(w, x, y, z)`` body FRD -> world NED of ZYX angles (rad); plain floats."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def yaw_from_wxyz(w: float, x: float, y: float, z: float) -> float:
    """The yaw (rad) of :func:`zyx_from_wxyz`, alone."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def zyx_from_wxyz(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """ZYX angles ``(yaw, pitch, roll)`` rad of a unit quaternion ``(w, x, y, z)``; plain floats
    (one vehicle: cheaper than the numpy versions). Pitch is clamped to +-pi/2 (round-off)."""
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    return yaw_from_wxyz(w, x, y, z), pitch, roll


# -- the same formulas over numpy arrays ---------------------------------------------------------

#: numpy's functions under math's names, for :func:`~protocols.runtime.same_code.same_code`.
_NUMPY_MATH = types.SimpleNamespace(cos=np.cos, sin=np.sin, atan2=np.arctan2, asin=np.arcsin)
_wxyz_from_zyx_np = same_code(wxyz_from_zyx, math=_NUMPY_MATH)
_yaw_from_wxyz_np = same_code(yaw_from_wxyz, math=_NUMPY_MATH)
_zyx_from_wxyz_np = same_code(
    zyx_from_wxyz,
    math=_NUMPY_MATH,
    max=np.maximum,
    min=np.minimum,
    yaw_from_wxyz=_yaw_from_wxyz_np,
)


def quat_from_zyx(
    yaw: FloatArray | float, pitch: FloatArray | float, roll: FloatArray | float
) -> FloatArray:
    """Quaternion ``(w, x, y, z)`` (4,) body -> world of ZYX angles in radians, or quaternions
    (4, N) of angle arrays (N,): :func:`wxyz_from_zyx` with numpy's functions."""
    return np.array(_wxyz_from_zyx_np(yaw, pitch, roll))


def zyx_from_quat(q: FloatArray) -> tuple[float, float, float]:
    """ZYX angles ``(yaw, pitch, roll)`` in radians of a quaternion ``(w, x, y, z)`` (4,):
    :func:`zyx_from_wxyz` with numpy's functions."""
    w, x, y, z = (float(v) for v in q)
    yaw, pitch, roll = _zyx_from_wxyz_np(w, x, y, z)
    return float(yaw), float(pitch), float(roll)


def zyx_from_quat_batch(q: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`zyx_from_quat` of quaternions (4, N): ``(yaw, pitch, roll)``, (N,) each."""
    yaw, pitch, roll = _zyx_from_wxyz_np(q[0], q[1], q[2], q[3])
    return yaw, pitch, roll


def yaw_from_quat_batch(q: FloatArray) -> FloatArray:
    """The yaw (N,) rad of :func:`zyx_from_quat_batch`, alone."""
    out: FloatArray = _yaw_from_wxyz_np(q[0], q[1], q[2], q[3])
    return out


def wrap_pi(angle: FloatArray | float) -> FloatArray | float:
    """Wrap angles to ``[-pi, pi)``."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi
