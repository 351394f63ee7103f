"""The setpoint checks of sitl_sim/vehicle/setpoint.py over many vehicles at once (numba).

:func:`validate_attitude_targets` runs :func:`sitl_sim.vehicle.setpoint.checked_setpoint` (and the
:func:`protocols.model.frames.zyx_from_wxyz` it calls) compiled from their own code, not from a
copy: the rule has one implementation, read by the simulator's vehicles one message at a time and by
``swarm simulate``'s hundred vehicles in one call. The same floating point operations in the
same order (no ``fastmath``; ``math``'s functions are the C library's, as CPython's), so the
values are those of the plain functions to the last bit. Compiled on first use and cached beside
the plain functions' files. This module imports the plain one, never the reverse.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from protocols.model.frames import yaw_from_wxyz, zyx_from_wxyz
from protocols.runtime.compiled import jit
from sitl_sim.vehicle import setpoint

# each compiled from the plain function's own code, the functions it calls by name bound to
# compiled ones (protocols/runtime/compiled.py)
_yaw = jit(yaw_from_wxyz, inline="always")
_zyx = jit(zyx_from_wxyz, calls={"yaw_from_wxyz": _yaw}, inline="always")
_checked = jit(setpoint.checked_setpoint, calls={"zyx_from_wxyz": _zyx}, inline="always")


def validate_attitude_targets(
    quats_wxyz: npt.ArrayLike, thrusts: npt.ArrayLike
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """:func:`sitl_sim.vehicle.setpoint.validate_attitude_target` (type mask 0) of K setpoints at
    once, quaternions (K, 4) and thrusts (K,): each one's code (K,; 0 valid, else the index of its
    :data:`~sitl_sim.vehicle.setpoint.REJECTIONS`), normalised quaternion (K, 4) and ZYX angles (K,
    3) as ``(roll, pitch, yaw)`` rad (:class:`~sitl_sim.vehicle.setpoint.AttitudeSetpoint`'s layout;
    zeros where rejected)."""
    q = np.ascontiguousarray(quats_wxyz, dtype=np.float64).reshape(-1, 4)
    t = np.ascontiguousarray(thrusts, dtype=np.float64).reshape(-1)
    codes = np.zeros(t.shape[0], dtype=np.int64)
    unit, euler = np.zeros((t.shape[0], 4)), np.zeros((t.shape[0], 3))
    check_all(q, t, codes, unit, euler)
    return codes, unit, euler


@jit
def check_all(quats, thrusts, codes, unit, euler):  # type: ignore[no-untyped-def]
    """:func:`validate_attitude_targets` into ``codes`` (K,), ``unit`` (K, 4) and ``euler``
    (K, 3)."""
    for k in range(thrusts.shape[0]):
        code, qw, qx, qy, qz, roll, pitch, yaw = _checked(
            quats[k, 0], quats[k, 1], quats[k, 2], quats[k, 3], thrusts[k]
        )
        codes[k] = code
        if code == 0:
            unit[k, 0], unit[k, 1], unit[k, 2], unit[k, 3] = qw, qx, qy, qz
            euler[k, 0], euler[k, 1], euler[k, 2] = roll, pitch, yaw
