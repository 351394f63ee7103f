"""Vectorised 6-DOF rigid-body dynamics of N quadcopters (ALGORITHM.md §1, paper eq. 3-6).

Pure numpy, no I/O and no clock: ``step(state, rotor_speeds, params, dt_s) -> state``.

State layout, a (13, N) float64 array, one column per vehicle:

- ``POS``   rows 0:3   position in world NED (m), ground at ``z = 0``, airborne means ``z < 0``;
- ``VEL``   rows 3:6   velocity in world NED (m/s);
- ``QUAT``  rows 6:10  attitude quaternion ``(w, x, y, z)``, body FRD -> world NED;
- ``RATES`` rows 10:13 body rates ``(p, q, r)`` about body FRD axes (rad/s).

Translation: ``a = g e3 - (T/m) R_b e3``. Rotation (Euler's equations, corrected eq. 6):
``p' = qr(Iyy-Izz)/Ixx + l/Ixx``, ``q' = pr(Izz-Ixx)/Iyy + m/Iyy``,
``r' = pq(Ixx-Iyy)/Izz + n/Izz``.
Rotor speeds are held constant over a step (zero-order hold).

Ground contact (after each step): a vehicle at or below the ground moving down is put on the
ground with zero velocity and body rates (inelastic, with friction); while its thrust is below
its weight it stays put and is levelled (roll = pitch = 0, yaw kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocols.frames import G_M_S2, FloatArray
from sitl_sim.vehicle_params import VehicleParams

POS = slice(0, 3)
VEL = slice(3, 6)
QUAT = slice(6, 10)
RATES = slice(10, 13)
STATE_ROWS = 13

_METHODS = ("rk4", "euler")


@dataclass(frozen=True)
class StepResult:
    """Outcome of one step: the new state (13, N) and each vehicle's touchdown speed (N,) m/s.

    ``impact_speed_m_s`` is the downward speed at which a vehicle reached the ground during the
    step, 0 for vehicles that did not touch down (or were already resting on the ground).
    """

    state: FloatArray
    impact_speed_m_s: FloatArray


def initial_state(positions_ned_m: FloatArray, yaw_rad: FloatArray | None = None) -> FloatArray:
    """State (13, N) of N vehicles at rest, level, at ``positions_ned_m`` (N, 3) m, yaw (N,) rad."""
    pos = np.asarray(positions_ned_m, dtype=np.float64).reshape(-1, 3)
    n = pos.shape[0]
    yaw = np.zeros(n) if yaw_rad is None else np.asarray(yaw_rad, dtype=np.float64).reshape(n)
    state = np.zeros((STATE_ROWS, n))
    state[POS] = pos.T
    state[6] = np.cos(0.5 * yaw)
    state[9] = np.sin(0.5 * yaw)
    return state


def wrench_from_rotor_speeds(
    rotor_speed_rad_s: FloatArray, params: VehicleParams
) -> tuple[FloatArray, FloatArray]:
    """Thrust (N,) N and body moments (3, N) N m from rotor speeds (4, N) rad/s (paper eq. 3-4).

    ``T = F1+F2+F3+F4``, ``l = D(F1-F3)``, ``m = D(F2-F4)``, ``n = M1-M2+M3-M4`` with
    ``F_i = c w_i^2`` and ``M_i = a D w_i^2``.
    """
    w = np.asarray(rotor_speed_rad_s, dtype=np.float64)
    f = params.thrust_coeff * (w * w)
    thrust = f[0] + f[1] + f[2] + f[3]
    moments = np.empty((3, f.shape[1]))
    np.multiply(f[0] - f[2], params.arm_m, out=moments[0])
    np.multiply(f[1] - f[3], params.arm_m, out=moments[1])
    np.multiply(f[0] - f[1] + f[2] - f[3], params.yaw_moment_per_thrust_m, out=moments[2])
    return thrust, moments


def derivative(
    state: FloatArray, thrust_n: FloatArray, moments_nm: FloatArray, params: VehicleParams
) -> FloatArray:
    """Time derivative (13, N) of ``state`` (13, N) under thrust (N,) N and moments (3, N) N m."""
    t_m, alpha = _specific_inputs(thrust_n, moments_nm, params)
    out = np.empty_like(state)
    _derivative_into(out, state, t_m, alpha, _euler_coeffs(params))
    return out


def step(
    state: FloatArray,
    rotor_speed_rad_s: FloatArray,
    params: VehicleParams,
    dt_s: float,
    method: str = "rk4",
) -> FloatArray:
    """Advance ``state`` (13, N) by ``dt_s`` seconds under rotor speeds (4, N) rad/s.

    ``method`` is ``"rk4"`` (classic Runge-Kutta, default) or ``"euler"`` (semi-implicit: velocity
    and rates first, then position and attitude with the new ones). The quaternion is
    re-normalised, then ground contact is applied. Returns a new (13, N) array.
    """
    thrust, moments = wrench_from_rotor_speeds(rotor_speed_rad_s, params)
    new = _integrate(state, thrust, moments, params, dt_s, method)
    _ground_contact_inplace(new, state, thrust, params.weight_n)
    return new


def step_with_contact(
    state: FloatArray,
    rotor_speed_rad_s: FloatArray,
    params: VehicleParams,
    dt_s: float,
    method: str = "rk4",
) -> StepResult:
    """As :func:`step`, also reporting each vehicle's touchdown speed (N,) m/s for this step."""
    thrust, moments = wrench_from_rotor_speeds(rotor_speed_rad_s, params)
    new = _integrate(state, thrust, moments, params, dt_s, method)
    impact = _ground_contact_inplace(new, state, thrust, params.weight_n)
    if impact is None:
        impact = np.zeros(state.shape[1])
    return StepResult(state=new, impact_speed_m_s=impact)


def ground_contact(
    state: FloatArray, prev_state: FloatArray, thrust_n: FloatArray, params: VehicleParams
) -> tuple[FloatArray, FloatArray]:
    """Apply ground contact to ``state`` (13, N) reached from ``prev_state`` (13, N).

    ``thrust_n`` (N,) is the collective thrust (N) over the step. Returns the corrected state
    (a copy) and the touchdown speed (N,) m/s of each vehicle (0 if it did not touch down).
    """
    new = np.array(state, dtype=np.float64)
    impact = _ground_contact_inplace(new, prev_state, np.asarray(thrust_n), params.weight_n)
    return new, np.zeros(new.shape[1]) if impact is None else impact


def _euler_coeffs(params: VehicleParams) -> tuple[float, float, float]:
    """Inertia ratios of Euler's equations: ``(Iyy-Izz)/Ixx, (Izz-Ixx)/Iyy, (Ixx-Iyy)/Izz``."""
    ixx, iyy, izz = params.ixx, params.iyy, params.izz
    return (iyy - izz) / ixx, (izz - ixx) / iyy, (ixx - iyy) / izz


def _specific_inputs(
    thrust_n: FloatArray, moments_nm: FloatArray, params: VehicleParams
) -> tuple[FloatArray, FloatArray]:
    """Thrust per mass (N,) m/s^2 and moments per inertia (3, N) rad/s^2."""
    t_m = np.asarray(thrust_n, dtype=np.float64) * (1.0 / params.mass_kg)
    alpha = np.asarray(moments_nm, dtype=np.float64) / params.inertia[:, None]
    return t_m, alpha


def _derivative_into(
    out: FloatArray,
    s: FloatArray,
    t_m: FloatArray,
    alpha: FloatArray,
    coeffs: tuple[float, float, float],
) -> None:
    """Write the derivative of ``s`` (13, N) into ``out`` (13, N).

    ``t_m`` (N,) is thrust per mass (m/s^2), ``alpha`` (3, N) moments per inertia (rad/s^2).
    """
    w, x, y, z = s[6], s[7], s[8], s[9]
    p, q, r = s[10], s[11], s[12]
    out[POS] = s[VEL]
    # R_b e3 = [2(xz + wy), 2(yz - wx), 1 - 2(x^2 + y^2)]
    two_t_m = t_m + t_m
    out[3] = -two_t_m * (x * z + w * y)
    out[4] = -two_t_m * (y * z - w * x)
    out[5] = G_M_S2 - t_m + two_t_m * (x * x + y * y)
    _quat_dot_into(out[QUAT], s[QUAT], p, q, r)
    out[10] = coeffs[0] * (q * r) + alpha[0]
    out[11] = coeffs[1] * (p * r) + alpha[1]
    out[12] = coeffs[2] * (p * q) + alpha[2]


def _quat_dot_into(
    out: FloatArray, quat: FloatArray, p: FloatArray, q: FloatArray, r: FloatArray
) -> None:
    """``out`` (4, N) = ``0.5 quat ⊗ (0, p, q, r)``: quaternion rate for body rates (rad/s)."""
    w, x, y, z = quat[0], quat[1], quat[2], quat[3]
    hp, hq, hr = 0.5 * p, 0.5 * q, 0.5 * r
    out[0] = -(x * hp + y * hq + z * hr)
    out[1] = w * hp + y * hr - z * hq
    out[2] = w * hq + z * hp - x * hr
    out[3] = w * hr + x * hq - y * hp


def _integrate(
    state: FloatArray,
    thrust_n: FloatArray,
    moments_nm: FloatArray,
    params: VehicleParams,
    dt_s: float,
    method: str,
) -> FloatArray:
    """One integration step (no ground contact) with a normalised quaternion; new (13, N)."""
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    t_m, alpha = _specific_inputs(thrust_n, moments_nm, params)
    coeffs = _euler_coeffs(params)
    new = (_rk4 if method == "rk4" else _semi_implicit_euler)(state, t_m, alpha, coeffs, dt_s)
    quat = new[QUAT]
    quat /= np.sqrt(np.einsum("ij,ij->j", quat, quat))
    return new


def _rk4(
    s: FloatArray, t_m: FloatArray, alpha: FloatArray, coeffs: tuple[float, float, float], h: float
) -> FloatArray:
    """Classic fourth-order Runge-Kutta step of length ``h`` s; returns a new (13, N) array."""
    k1, k2, k3, k4 = (np.empty_like(s) for _ in range(4))
    tmp = np.empty_like(s)
    _derivative_into(k1, s, t_m, alpha, coeffs)
    np.multiply(k1, 0.5 * h, out=tmp)
    tmp += s
    _derivative_into(k2, tmp, t_m, alpha, coeffs)
    np.multiply(k2, 0.5 * h, out=tmp)
    tmp += s
    _derivative_into(k3, tmp, t_m, alpha, coeffs)
    np.multiply(k3, h, out=tmp)
    tmp += s
    _derivative_into(k4, tmp, t_m, alpha, coeffs)
    k2 += k3
    k2 += k2
    k2 += k1
    k2 += k4
    k2 *= h / 6.0
    k2 += s
    return k2


def _semi_implicit_euler(
    s: FloatArray, t_m: FloatArray, alpha: FloatArray, coeffs: tuple[float, float, float], h: float
) -> FloatArray:
    """Semi-implicit Euler: update velocity and rates, then position and attitude with them."""
    d = np.empty_like(s)
    _derivative_into(d, s, t_m, alpha, coeffs)
    new = s + h * d
    new[POS] = s[POS] + h * new[VEL]
    _quat_dot_into(d[QUAT], s[QUAT], new[10], new[11], new[12])
    new[QUAT] = s[QUAT] + h * d[QUAT]
    return new


def _ground_contact_inplace(
    new: FloatArray, prev: FloatArray, thrust_n: FloatArray, weight_n: float
) -> FloatArray | None:
    """Apply ground contact to ``new`` (13, N) in place; touchdown speeds (N,) or None if none."""
    contact = new[2] >= 0.0
    if not contact.any():
        return None
    idx = np.flatnonzero(contact)
    sub, before = new[:, idx], prev[:, idx]
    z0, vz0, vz1 = before[2], before[5], sub[5]
    # Fraction of the step at which the ground was reached (0 if it started on the ground).
    dz = sub[2] - z0
    frac = np.where(z0 < 0.0, -z0 / np.where(dz > 0.0, dz, 1.0), 0.0).clip(0.0, 1.0)
    moving_down = vz1 > 0.0
    impact = np.zeros(new.shape[1])
    impact[idx] = np.where(moving_down, np.maximum(vz0 + frac * (vz1 - vz0), 0.0), 0.0)
    resting = np.asarray(thrust_n)[idx] < weight_n
    stopped = moving_down | resting
    sub[2] = 0.0
    sub[VEL, stopped] = 0.0
    sub[RATES, stopped] = 0.0
    on_ground_before = stopped & (z0 >= 0.0)
    sub[0:2, on_ground_before] = before[0:2, on_ground_before]
    if resting.any():
        sub[QUAT, resting] = _level_quat(sub[QUAT, resting])
    new[:, idx] = sub
    return impact


def _level_quat(quat: FloatArray) -> FloatArray:
    """Quaternions (4, K) with roll and pitch removed, yaw kept."""
    w, x, y, z = quat
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    out = np.zeros_like(quat)
    out[0] = np.cos(0.5 * yaw)
    out[3] = np.sin(0.5 * yaw)
    return out
