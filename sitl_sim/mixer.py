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

Returns ``w_i = sqrt(F_i / c)``, always finite and within the rotor-speed limits.

:func:`wrench_from_rotor_forces` is the forward map (forces -> thrust and moments), e.g. for a
ground station that receives the rotor forces (ACTUATOR_OUTPUT_STATUS).

Rotor order (from the signs of eq. 3 in body FRD): rotor 1 left (-y), 2 front (+x), 3 right
(+y), 4 back (-x); rotors 1 and 3 give a positive reaction yaw moment, 2 and 4 a negative one.
"""

from __future__ import annotations

import numpy as np

from protocols.frames import FloatArray
from sitl_sim.vehicle_params import VehicleParams

#: Sign of the yaw share ``y`` in each rotor's force (paper eq. 3: n = M1 - M2 + M3 - M4).
_YAW_SIGN = np.array([1.0, -1.0, 1.0, -1.0])[:, None]


def mix(thrust_n: FloatArray, moments_nm: FloatArray, params: VehicleParams) -> FloatArray:
    """Rotor speeds (4, N) rad/s realising thrust (N,) N and moments (3, N) N m where possible."""
    f_min, f_max = params.rotor_force_min_n, params.rotor_force_max_n
    base, yaw = _shares(*_limited_demands(thrust_n, moments_nm, params), params)
    forces = base + _yaw_scale(base, yaw, f_min, f_max) * yaw
    np.clip(forces, f_min, f_max, out=forces)
    return np.sqrt(forces * (1.0 / params.thrust_coeff))


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


def _limited_demands(
    thrust_n: FloatArray, moments_nm: FloatArray, params: VehicleParams
) -> tuple[FloatArray, FloatArray]:
    """Finite thrust (N,) and moments (3, N), limited to what four rotors could ever produce."""
    f_min, f_max = params.rotor_force_min_n, params.rotor_force_max_n
    span = f_max - f_min
    thrust = np.nan_to_num(np.asarray(thrust_n, dtype=np.float64), nan=0.0, posinf=4 * f_max)
    np.clip(thrust, 4.0 * f_min, 4.0 * f_max, out=thrust)
    moments = np.nan_to_num(np.asarray(moments_nm, dtype=np.float64), nan=0.0)
    arm_limit = span * params.arm_m
    yaw_limit = 2.0 * span * params.yaw_moment_per_thrust_m
    limits = np.array([arm_limit, arm_limit, yaw_limit])[:, None]
    np.clip(moments, -limits, limits, out=moments)
    return thrust, moments


def _yaw_scale(base: FloatArray, yaw: FloatArray, f_min: float, f_max: float) -> FloatArray:
    """Largest factor (N,) in [0, 1] such that ``base + factor * yaw`` (4, N) fits the limits.

    ``base`` (4, N) holds the thrust and roll/pitch shares, ``yaw`` (4, N) the yaw shares (N).
    Forces within ``1e-9 * f_max`` of the limits count as fitting (round-off; the final clip
    removes it), and yaw shares below that are ignored. Each vehicle's factor is its own: a
    vehicle whose forces all fit keeps its whole yaw share whatever the others need.
    """
    tol = 1e-9 * f_max
    total = base + yaw
    fits = np.all((total >= f_min - tol) & (total <= f_max + tol), axis=0)
    if fits.all():
        return np.ones(base.shape[1])
    room = np.where(yaw > 0.0, f_max - base, base - f_min)
    mag = np.abs(yaw)
    safe_mag = np.where(mag > tol, mag, 1.0)
    ratio = np.where(mag > tol, room / safe_mag, np.inf)
    return np.where(fits, 1.0, np.clip(ratio.min(axis=0), 0.0, 1.0))
