"""Frames, rotations and quaternions: the one place that defines them.

Conventions (SPEC.md):
- World frame NED (x north, y east, z down), metres, seconds, radians.
- Body frame FRD. ``R_b = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` maps body vectors to world.
- Quaternions are ``(w, x, y, z)`` (MAVLink order), body FRD -> world NED.
- Gravity is ``+G_M_S2 * E3`` in NED.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

G_M_S2 = 9.81
E3: FloatArray = np.array([0.0, 0.0, 1.0])


def rot_zyx(yaw: float, pitch: float, roll: float) -> FloatArray:
    """Rotation matrix (3, 3) body -> world, ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


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
    pitch = float(np.arcsin(np.clip(-r[2, 0], -1.0, 1.0)))
    yaw = float(np.arctan2(r[1, 0], r[0, 0]))
    roll = float(np.arctan2(r[2, 1], r[2, 2]))
    return yaw, pitch, roll


def zyx_from_rot_batch(r: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`zyx_from_rot` of rotation matrices (N, 3, 3): ``(yaw, pitch, roll)``, (N,) each."""
    pitch = np.arcsin(np.minimum(np.maximum(-r[:, 2, 0], -1.0), 1.0))  # np.clip's, cheaper
    yaw = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    roll = np.arctan2(r[:, 2, 1], r[:, 2, 2])
    return yaw, pitch, roll


def quat_from_zyx(yaw: float, pitch: float, roll: float) -> FloatArray:
    """Quaternion ``(w, x, y, z)`` body -> world of ZYX angles in radians."""
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def zyx_from_quat(q: FloatArray) -> tuple[float, float, float]:
    """ZYX angles ``(yaw, pitch, roll)`` in radians of a quaternion ``(w, x, y, z)``."""
    w, x, y, z = (float(v) for v in q)
    roll = float(np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)))
    pitch = float(np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0)))
    yaw = float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    return yaw, pitch, roll


def wrap_pi(angle: FloatArray | float) -> FloatArray | float:
    """Wrap angles to ``[-pi, pi)``."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi
