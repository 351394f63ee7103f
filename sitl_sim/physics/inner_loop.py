"""The autopilot inner loop run at the physics rate: attitude controller followed by the mixer.

It turns an attitude setpoint and a normalised collective thrust into rotor speeds for N vehicles
at once, as a flight controller's attitude loop does on each vehicle. Disarmed vehicles get zero
rotor speed.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray
from sitl_sim.physics.attitude_control import AttitudeGains, attitude_moments, euler_from_quat_batch
from sitl_sim.physics.mixer import mix
from sitl_sim.physics.vehicle_params import VehicleParams

_DEFAULT_GAINS = AttitudeGains()


def inner_loop(
    state: FloatArray,
    attitude_des: FloatArray,
    thrust_normalised: FloatArray,
    params: VehicleParams,
    gains: AttitudeGains = _DEFAULT_GAINS,
    armed: npt.NDArray[np.bool_] | None = None,
) -> FloatArray:
    """Rotor speeds (4, N) rad/s tracking an attitude setpoint with a collective thrust.

    Args:
        state: vehicle states (13, N), layout of ``sitl_sim.physics.dynamics``.
        attitude_des: either quaternions (4, N) ``(w, x, y, z)`` body -> world, or ZYX Euler
            angles (3, N) ``(roll, pitch, yaw)`` in radians.
        thrust_normalised: collective thrust (N,) as a fraction of ``params.max_thrust_n``,
            clipped to [0, 1].
        params: vehicle parameters (shared by all N vehicles).
        gains: attitude PD gains.
        armed: boolean mask (N,); disarmed vehicles get zero rotor speed. None: all armed.

    Raises:
        ValueError: if ``attitude_des`` has neither 3 nor 4 rows.
    """
    euler_des = _euler_setpoint(np.asarray(attitude_des, dtype=np.float64))
    moments = attitude_moments(state, euler_des, params, gains)
    thrust_n = np.clip(np.asarray(thrust_normalised, dtype=np.float64), 0.0, 1.0)
    thrust_n = thrust_n * params.max_thrust_n
    rotor_speed = mix(thrust_n, moments, params)
    if armed is not None:
        rotor_speed[:, ~np.asarray(armed, dtype=bool)] = 0.0
    return rotor_speed


def _euler_setpoint(attitude_des: FloatArray) -> FloatArray:
    """ZYX angles (3, N) from a quaternion (4, N) or Euler (3, N) setpoint."""
    rows = attitude_des.shape[0]
    if rows == 4:
        return euler_from_quat_batch(attitude_des)
    if rows == 3:
        return attitude_des
    raise ValueError(f"attitude_des must have 3 (Euler) or 4 (quaternion) rows, got {rows}")
