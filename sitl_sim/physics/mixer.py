"""Mixer: collective thrust and body moments -> rotor speeds, inverting paper eq. 3-4.

With ``F_i = c w_i^2`` and ``M_i = k F_i`` (``k = a D / c``, m), eq. 3 inverts to

    F1 = T/4 + y + l/(2D),  F3 = T/4 + y - l/(2D),
    F2 = T/4 - y + m/(2D),  F4 = T/4 - y - m/(2D),   with y = n / (4k).

Saturation, per vehicle, keeping roll and pitch authority first:

1. non-finite demands count as zero; thrust is limited to ``[4 F_min, 4 F_max]`` and each moment
   to the largest the rotors could ever produce;
2. the yaw share ``y`` is scaled down (towards 0) just enough for every rotor force to fit in
   ``[F_min, F_max] = [c w_min^2, c w_max^2]``, if that is possible;
3. each rotor force is clipped to ``[F_min, F_max]`` (this trims roll/pitch and thrust only when
   they alone do not fit).

Returns ``w_i = sqrt(F_i / c)``, always finite and within the rotor-speed limits. The rule is
written once, for one vehicle, in :func:`sitl_sim.physics.rules.mix` (compiled); :func:`mix` is
it over N vehicles.

:func:`wrench_from_rotor_forces` is the forward map (forces -> thrust and moments), e.g. for a
ground station that receives the rotor forces (ACTUATOR_OUTPUT_STATUS).

Rotor order (from the signs of eq. 3 in body FRD): rotor 1 left (-y), 2 front (+x), 3 right
(+y), 4 back (-x); rotors 1 and 3 give a positive reaction yaw moment, 2 and 4 a negative one.
"""

from __future__ import annotations

import numpy as np

from protocols.model.frames import FloatArray
from protocols.runtime.compiled import compiled
from sitl_sim.physics import rules as physics_rules
from sitl_sim.physics.rules import constants
from sitl_sim.physics.vehicle_params import VehicleParams

#: Sign of the yaw share ``y`` in each rotor's force (paper eq. 3: n = M1 - M2 + M3 - M4).
_YAW_SIGN = np.array([1.0, -1.0, 1.0, -1.0])[:, None]


def mix(thrust_n: FloatArray, moments_nm: FloatArray, params: VehicleParams) -> FloatArray:
    """Rotor speeds (4, N) rad/s realising thrust (N,) N and moments (3, N) N m where possible."""
    thrust = np.ascontiguousarray(thrust_n, dtype=np.float64).reshape(-1)
    moments = np.ascontiguousarray(moments_nm, dtype=np.float64).reshape(3, -1)
    out = np.empty((4, thrust.shape[0]))
    compiled(physics_rules.mix_rows)(thrust, moments, constants(params, 0.0), out)
    return out


def rotor_forces_from_wrench(
    thrust_n: FloatArray, moments_nm: FloatArray, params: VehicleParams
) -> FloatArray:
    """Unsaturated rotor forces (4, N) N that give thrust (N,) N and moments (3, N) N m exactly."""
    base, yaw = _shares(
        np.asarray(thrust_n, dtype=np.float64), np.asarray(moments_nm, dtype=np.float64), params
    )
    return base + yaw


def wrench_from_rotor_forces(
    forces_n: FloatArray, params: VehicleParams
) -> tuple[FloatArray, FloatArray]:
    """Thrust (N,) N and body moments (3, N) N m of rotor forces (4, N) N: the allocation that
    :func:`mix` inverts (paper eq. 3), ``T = F1+F2+F3+F4``, ``l = D(F1-F3)``, ``m = D(F2-F4)``,
    ``n = k(F1-F2+F3-F4)`` with ``k = params.yaw_moment_per_thrust_m``."""
    f = np.asarray(forces_n, dtype=np.float64)
    thrust = f[0] + f[1] + f[2] + f[3]
    moments = np.stack(
        [
            params.arm_m * (f[0] - f[2]),
            params.arm_m * (f[1] - f[3]),
            params.yaw_moment_per_thrust_m * (f[0] - f[1] + f[2] - f[3]),
        ]
    )
    return thrust, moments


def _shares(
    thrust: FloatArray, moments: FloatArray, params: VehicleParams
) -> tuple[FloatArray, FloatArray]:
    """Rotor forces (4, N) N split into thrust + roll/pitch shares and yaw shares."""
    half_arm_inv = 0.5 / params.arm_m
    base = np.empty((4, thrust.shape[0]))
    base[:] = 0.25 * thrust
    base[0] += half_arm_inv * moments[0]
    base[2] -= half_arm_inv * moments[0]
    base[1] += half_arm_inv * moments[1]
    base[3] -= half_arm_inv * moments[1]
    yaw = _YAW_SIGN * (moments[2] * (0.25 / params.yaw_moment_per_thrust_m))
    return base, yaw
