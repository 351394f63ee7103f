"""The compiled loop of :class:`sitl_sim.physics_kernel.PhysicsKernel` (numba).

:func:`advance` runs sub-steps of every vehicle in plain floating point, one vehicle after the
other (each vehicle's state stays in registers through its sub-steps; vehicles never mix): the
attitude controller (attitude_control.attitude_moments), the mixer (mixer.mix), the rotor wrench
(dynamics.wrench_from_rotor_speeds), RK4 (dynamics._rk4) and ground contact
(dynamics._ground_contact_inplace), each with the same operations in the same order as the
readable reference. Compiled on first use (protocols/compiled.py) and cached beside this file
(``__pycache__``), so that later processes load it (~0.3 s of CPU with numba's import) instead
of compiling it (~3 s).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from protocols.compiled import jit
from protocols.frames import G_M_S2, FloatArray
from sitl_sim.attitude_control import _MIN_COS_PITCH
from sitl_sim.dynamics import _euler_coeffs
from sitl_sim.vehicle_params import VehicleParams

# The constants of one fleet, packed for the compiled kernel (indices into ``_constants``).
(_H, _F_MIN, _F_MAX, _TOL, _MAX_THRUST, _HALF_ARM_INV, _YAW_SHARE, _INV_C, _C, _ARM, _YAW_K,
 _INV_MASS, _WEIGHT, _IXX, _IYY, _IZZ, _ARM_LIMIT, _YAW_LIMIT, _E0, _E1, _E2, _G,
 _MIN_COS, _N_CONSTANTS) = range(24)  # fmt: skip


def constants(params: VehicleParams, dt_s: float) -> FloatArray:
    """The fleet's constants in the order of the indices above."""
    f_min, f_max = params.rotor_force_min_n, params.rotor_force_max_n
    span = f_max - f_min
    c = np.empty(_N_CONSTANTS)
    c[_H] = dt_s
    c[_F_MIN], c[_F_MAX], c[_TOL] = f_min, f_max, 1e-9 * f_max
    c[_MAX_THRUST] = params.max_thrust_n
    c[_HALF_ARM_INV] = 0.5 / params.arm_m
    c[_YAW_SHARE] = 0.25 / params.yaw_moment_per_thrust_m
    c[_INV_C], c[_C] = 1.0 / params.thrust_coeff, params.thrust_coeff
    c[_ARM], c[_YAW_K] = params.arm_m, params.yaw_moment_per_thrust_m
    c[_INV_MASS], c[_WEIGHT] = 1.0 / params.mass_kg, params.weight_n
    c[_IXX], c[_IYY], c[_IZZ] = params.ixx, params.iyy, params.izz
    c[_ARM_LIMIT], c[_YAW_LIMIT] = span * params.arm_m, 2.0 * span * params.yaw_moment_per_thrust_m
    c[_E0], c[_E1], c[_E2] = _euler_coeffs(params)
    c[_G], c[_MIN_COS] = G_M_S2, _MIN_COS_PITCH
    return c


@jit(inline="always")
def _derivative_into(
    out: FloatArray,
    st: FloatArray,
    t_m: float,
    two_t_m: float,
    a0: float,
    a1: float,
    a2: float,
    c: FloatArray,
) -> None:  # pragma: no cover - compiled
    """The derivative (13,) of one vehicle's state ``st`` (13,) into ``out``
    (dynamics._derivative_into, the same operations)."""
    w, x, y, z, p, q, r = st[6], st[7], st[8], st[9], st[10], st[11], st[12]
    hp, hq, hr = 0.5 * p, 0.5 * q, 0.5 * r
    out[0], out[1], out[2] = st[3], st[4], st[5]
    out[3] = -two_t_m * (x * z + w * y)
    out[4] = -two_t_m * (y * z - w * x)
    out[5] = c[_G] - t_m + two_t_m * (x * x + y * y)
    out[6] = -(x * hp + y * hq + z * hr)
    out[7] = w * hp + y * hr - z * hq
    out[8] = w * hq + z * hp - x * hr
    out[9] = w * hr + x * hq - y * hp
    out[10] = c[_E0] * (q * r) + a0
    out[11] = c[_E1] * (p * r) + a1
    out[12] = c[_E2] * (p * q) + a2


@jit(inline="always")
def _room(
    base: float, share: float, f_min: float, f_max: float, tol: float
) -> float:  # pragma: no cover - compiled
    """How much of its yaw ``share`` a rotor whose other shares add up to ``base`` can take
    (mixer._yaw_scale): inf for a share within round-off of 0."""
    mag = abs(share)
    if not mag > tol:
        return math.inf
    return (f_max - base if share > 0.0 else base - f_min) / mag


@jit
def advance(
    state: FloatArray,
    euler_des: FloatArray,
    thrust_normalised: FloatArray,
    enable: FloatArray,
    kp: FloatArray,
    kd: FloatArray,
    c: FloatArray,
    count: int,
    new: FloatArray,
    rotor: FloatArray,
    impacts: FloatArray,
    touched: npt.NDArray[np.bool_],
) -> None:  # pragma: no cover - compiled (its Python body runs with NUMBA_DISABLE_JIT=1)
    """``count`` sub-steps of every vehicle: ``new`` (13, N) the last state, ``rotor`` (4, N)
    the last rotor speeds, ``impacts[k]`` (N,) the touchdown speeds of sub-step ``k`` and
    ``touched[k]`` whether any vehicle was on the ground after it."""
    h = c[_H]
    f_min, f_max, tol = c[_F_MIN], c[_F_MAX], c[_TOL]
    fit_lo, fit_hi = f_min - tol, f_max + tol
    arm_lim, yaw_lim = c[_ARM_LIMIT], c[_YAW_LIMIT]
    ixx, iyy, izz = c[_IXX], c[_IYY], c[_IZZ]
    half_h, sixth_h = 0.5 * h, h / 6.0
    pi, two_pi = math.pi, 2.0 * math.pi
    s, xt = np.empty(13), np.empty(13)
    k1, k2, k3, k4 = np.empty(13), np.empty(13), np.empty(13), np.empty(13)
    for i in range(state.shape[1]):
        s[:] = state[:, i]
        ry, py_, yy = euler_des[0, i], euler_des[1, i], euler_des[2, i]
        kp0, kp1, kp2 = kp[0, i], kp[1, i], kp[2, i]
        kd0, kd1, kd2 = kd[0, i], kd[1, i], kd[2, i]
        # collective thrust (inner_loop + mixer._limited_demands): NaN counts as 0
        t_dem = min(max(thrust_normalised[i], 0.0), 1.0) * c[_MAX_THRUST]
        if t_dem != t_dem:
            t_dem = 0.0
        t_dem = min(max(t_dem, 4.0 * f_min), 4.0 * f_max)
        en0, en1, en2, en3 = enable[0, i], enable[1, i], enable[2, i], enable[3, i]
        w0 = w1 = w2 = w3 = 0.0
        for k in range(count):
            w, x, y, z = s[6], s[7], s[8], s[9]
            p, q, r = s[10], s[11], s[12]
            # --- attitude controller (attitude_control.attitude_moments) -------------------
            roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
            pitch = math.asin(min(max(2.0 * (w * y - z * x), -1.0), 1.0))
            yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
            sphi, cphi = math.sin(roll), math.cos(roll)
            sth, cth = math.sin(pitch), math.cos(pitch)
            ctheta = max(cth, c[_MIN_COS])
            ttheta = sth / ctheta
            qr_roll = sphi * q + cphi * r
            phid = p + ttheta * qr_roll
            thd = cphi * q - sphi * r
            psid = qr_roll / ctheta
            e0, e1 = ry - roll, py_ - pitch
            e2 = (yy - yaw + pi) % two_pi - pi
            tau0 = kp0 * e0 + kd0 * -phid
            tau1 = kp1 * e1 + kd1 * -thd
            tau2 = kp2 * e2 + kd2 * -psid
            od0 = tau0 - sth * tau2 - cth * thd * psid
            od1 = (
                cphi * tau1
                + sphi * cth * tau2
                - sphi * phid * thd
                + (cphi * cth * phid - sphi * sth * thd) * psid
            )
            od2 = (
                -sphi * tau1
                + cphi * cth * tau2
                - cphi * phid * thd
                - (sphi * cth * phid + cphi * sth * thd) * psid
            )
            m_l = ixx * od0 + (izz - iyy) * (q * r)
            m_m = iyy * od1 + (ixx - izz) * (p * r)
            m_n = izz * od2 + (iyy - ixx) * (p * q)
            # --- mixer (mixer.mix): NaN moments count as 0, then limited ------------------
            m_l = 0.0 if m_l != m_l else min(max(m_l, -arm_lim), arm_lim)
            m_m = 0.0 if m_m != m_m else min(max(m_m, -arm_lim), arm_lim)
            m_n = 0.0 if m_n != m_n else min(max(m_n, -yaw_lim), yaw_lim)
            quarter_t = 0.25 * t_dem
            b0 = quarter_t + c[_HALF_ARM_INV] * m_l
            b1 = quarter_t + c[_HALF_ARM_INV] * m_m
            b2 = quarter_t - c[_HALF_ARM_INV] * m_l
            b3 = quarter_t - c[_HALF_ARM_INV] * m_m
            ys = m_n * c[_YAW_SHARE]
            t0, t1, t2, t3 = b0 + ys, b1 - ys, b2 + ys, b3 - ys
            if not (
                fit_lo <= t0 <= fit_hi
                and fit_lo <= t1 <= fit_hi
                and fit_lo <= t2 <= fit_hi
                and fit_lo <= t3 <= fit_hi
            ):  # scale the yaw share down (mixer._yaw_scale)
                scale = min(
                    _room(b0, ys, f_min, f_max, tol),
                    _room(b1, -ys, f_min, f_max, tol),
                    _room(b2, ys, f_min, f_max, tol),
                    _room(b3, -ys, f_min, f_max, tol),
                )
                scale = min(max(scale, 0.0), 1.0)
                t0, t1 = b0 + scale * ys, b1 + scale * -ys
                t2, t3 = b2 + scale * ys, b3 + scale * -ys
            inv_c = c[_INV_C]
            w0 = math.sqrt(min(max(t0, f_min), f_max) * inv_c) * en0
            w1 = math.sqrt(min(max(t1, f_min), f_max) * inv_c) * en1
            w2 = math.sqrt(min(max(t2, f_min), f_max) * inv_c) * en2
            w3 = math.sqrt(min(max(t3, f_min), f_max) * inv_c) * en3
            # --- rotor wrench (dynamics.wrench_from_rotor_speeds, _specific_inputs) ----------
            cf = c[_C]
            f0, f1, f2, f3 = cf * (w0 * w0), cf * (w1 * w1), cf * (w2 * w2), cf * (w3 * w3)
            thrust = f0 + f1 + f2 + f3
            t_m = thrust * c[_INV_MASS]
            two_t_m = t_m + t_m
            a0 = ((f0 - f2) * c[_ARM]) / ixx
            a1 = ((f1 - f3) * c[_ARM]) / iyy
            a2 = ((f0 - f1 + f2 - f3) * c[_YAW_K]) / izz
            # --- RK4 (dynamics._rk4) ---------------------------------------------------------
            _derivative_into(k1, s, t_m, two_t_m, a0, a1, a2, c)
            for j in range(13):
                xt[j] = k1[j] * half_h + s[j]
            _derivative_into(k2, xt, t_m, two_t_m, a0, a1, a2, c)
            for j in range(13):
                xt[j] = k2[j] * half_h + s[j]
            _derivative_into(k3, xt, t_m, two_t_m, a0, a1, a2, c)
            for j in range(13):
                xt[j] = k3[j] * h + s[j]
            _derivative_into(k4, xt, t_m, two_t_m, a0, a1, a2, c)
            z0, vz0 = s[2], s[5]
            prev_x, prev_y = s[0], s[1]
            for j in range(13):
                acc = k2[j] + k3[j]
                acc = acc + acc
                acc = acc + k1[j]
                acc = acc + k4[j]
                s[j] = acc * sixth_h + s[j]
            norm = math.sqrt(s[6] * s[6] + s[7] * s[7] + s[8] * s[8] + s[9] * s[9])
            s[6], s[7], s[8], s[9] = s[6] / norm, s[7] / norm, s[8] / norm, s[9] / norm
            # --- ground contact (dynamics._ground_contact_inplace) -----------------------------
            z1, vz1 = s[2], s[5]
            if z1 >= 0.0:
                touched[k] = True
                frac = 0.0
                if z0 < 0.0:
                    dz = z1 - z0
                    frac = min(max(-z0 / (dz if dz > 0.0 else 1.0), 0.0), 1.0)
                moving_down = vz1 > 0.0
                if moving_down:
                    impacts[k, i] = max(vz0 + frac * (vz1 - vz0), 0.0)
                resting = thrust < c[_WEIGHT]
                s[2] = 0.0
                if moving_down or resting:
                    s[3] = s[4] = s[5] = 0.0
                    s[10] = s[11] = s[12] = 0.0
                    if z0 >= 0.0:
                        s[0], s[1] = prev_x, prev_y
                if resting:  # level, keeping the yaw (dynamics._level_quat)
                    qw, qx, qy, qz = s[6], s[7], s[8], s[9]
                    yaw_l = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
                    s[6], s[7], s[8], s[9] = math.cos(0.5 * yaw_l), 0.0, 0.0, math.sin(0.5 * yaw_l)
        new[:, i] = s
        rotor[0, i], rotor[1, i], rotor[2, i], rotor[3, i] = w0, w1, w2, w3


def ready() -> None:
    """Compile :func:`advance` (or load it from the cache) now, on one vehicle at rest, so that
    the first sub-step of a flight does not pay for it: a simulator calls this before it serves
    (a first compile takes seconds, longer than an agent waits for its vehicle in realtime)."""
    state = np.zeros((13, 1))
    state[6] = 1.0
    gains = np.ones((3, 1))
    advance(
        state, np.zeros((3, 1)), np.zeros(1), np.ones((4, 1)), gains, gains,
        constants(VehicleParams(), 0.002), 1, np.empty((13, 1)), np.empty((4, 1)),
        np.zeros((1, 1)), np.zeros(1, dtype=np.bool_),
    )  # fmt: skip
