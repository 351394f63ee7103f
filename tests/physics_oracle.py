"""The simulator's physics in numpy, vectorised over vehicles: the readable implementation that
sitl_sim/physics/rules.py replaced (one vehicle's plain floats, compiled), kept here as the
oracle the compiled rules are checked against (tests/test_physics_kernel.py, test_dynamics.py,
test_mixer.py). The same maths (sitl_sim/physics/dynamics.py's and mixer.py's docs), written as
array operations over the (13, N) state: a second, independent writing of the rules.

``inner_loop`` is the simulator's inner loop (the numpy attitude controller of
sitl_sim/physics/attitude_control.py) with :func:`mix`; ``step_with_contact`` integrates with RK4
(or semi-implicit Euler) and applies ground contact; ``step_with_lag`` does it with motors that lag
(each rotor's speed a first-order lag of its command, exact over the step; RK4's stages take the
rotors' wrench at their times).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocols.model.frames import G_M_S2, FloatArray
from protocols.runtime.same_code import same_code
from sitl_sim.physics import inner_loop as _simulator
from sitl_sim.physics.dynamics import POS, QUAT, RATES, VEL, wrench_from_rotor_speeds
from sitl_sim.physics.rules import euler_coeffs as _euler_coeffs
from sitl_sim.physics.vehicle_params import VehicleParams

_METHODS = ("rk4", "euler")
#: Sign of the yaw share ``y`` in each rotor's force (paper eq. 3: n = M1 - M2 + M3 - M4).
_YAW_SIGN = np.array([1.0, -1.0, 1.0, -1.0])[:, None]


@dataclass(frozen=True)
class StepResult:
    """The new state (13, N) and each vehicle's touchdown speed (N,) m/s."""

    state: FloatArray
    impact_speed_m_s: FloatArray


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


def lagged_rotor_speeds(
    rotor_rad_s: FloatArray, command_rad_s: FloatArray, motor_tau_s: float, t_s: float
) -> FloatArray:
    """Rotor speeds (4, N) rad/s ``t_s`` after ``rotor_rad_s`` (4, N) under the command (4, N)
    held, ``d w / dt = (w_cmd - w) / tau``: ``w_cmd + (w - w_cmd) exp(-t / tau)``."""
    decay = np.exp(-t_s / motor_tau_s)
    return command_rad_s + (rotor_rad_s - command_rad_s) * decay


def step_with_lag(
    state: FloatArray,
    rotor_rad_s: FloatArray,
    command_rad_s: FloatArray,
    params: VehicleParams,
    dt_s: float,
) -> tuple[StepResult, FloatArray]:
    """One RK4 step with contact of ``state`` (13, N) whose rotors at ``rotor_rad_s`` (4, N)
    follow ``command_rad_s`` (4, N) with ``params.motor_tau_s`` > 0; the stages take the wrench
    of the rotors' speeds at their times (start, middle, end). Returns the step's result (the
    contact judged on the thrust at the end) and the rotor speeds (4, N) at the end."""
    stages = [
        lagged_rotor_speeds(rotor_rad_s, command_rad_s, params.motor_tau_s, t)
        for t in (0.0, 0.5 * dt_s, dt_s)
    ]
    wrenches = [wrench_from_rotor_speeds(w, params) for w in stages]
    inputs = [_specific_inputs(thrust, moments, params) for thrust, moments in wrenches]
    coeffs = _euler_coeffs(params)
    k = [np.empty_like(state) for _ in range(4)]
    _derivative_into(k[0], state, *inputs[0], coeffs)
    _derivative_into(k[1], state + 0.5 * dt_s * k[0], *inputs[1], coeffs)
    _derivative_into(k[2], state + 0.5 * dt_s * k[1], *inputs[1], coeffs)
    _derivative_into(k[3], state + dt_s * k[2], *inputs[2], coeffs)
    new = state + (dt_s / 6.0) * (k[0] + 2.0 * (k[1] + k[2]) + k[3])
    new[QUAT] /= np.sqrt(np.einsum("ij,ij->j", new[QUAT], new[QUAT]))
    impact = _ground_contact_inplace(new, state, wrenches[2][0], params.weight_n)
    if impact is None:
        impact = np.zeros(state.shape[1])
    return StepResult(state=new, impact_speed_m_s=impact), stages[2]


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


def mix(thrust_n: FloatArray, moments_nm: FloatArray, params: VehicleParams) -> FloatArray:
    """Rotor speeds (4, N) rad/s realising thrust (N,) N and moments (3, N) N m where possible."""
    f_min, f_max = params.rotor_force_min_n, params.rotor_force_max_n
    base, yaw = _shares(*_limited_demands(thrust_n, moments_nm, params), params)
    forces = base + _yaw_scale(base, yaw, f_min, f_max) * yaw
    np.clip(forces, f_min, f_max, out=forces)
    return np.sqrt(forces * (1.0 / params.thrust_coeff))


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


#: Rotor speeds (4, N) rad/s tracking an attitude setpoint with a collective thrust: the
#: simulator's own inner loop (sitl_sim/physics/inner_loop.py: setpoint, the numpy attitude
#: controller, thrust clipping, disarmed vehicles) with this module's :func:`mix` in place of the
#: compiled mixer.
inner_loop = same_code(_simulator.inner_loop, mix=mix)
