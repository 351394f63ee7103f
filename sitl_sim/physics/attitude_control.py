"""Autopilot attitude controller (ALGORITHM.md §5, paper eq. 36-39 as corrected), vectorised.

Feedback linearisation plus PD on ZYX Euler angles ``eta = (roll, pitch, yaw)`` (rad):

- ``eta' = W(eta) omega`` (eq. 20) from the body rates ``omega = (p, q, r)``;
- ``tau = eta''_d + k_d (eta'_d - eta') + k_p (eta_d - eta)``, the yaw error wrapped to [-pi, pi);
- ``omega' = E tau + E' eta'`` with ``E = W^-1 = [[1,0,-sθ],[0,cφ,sφcθ],[0,-sφ,cφcθ]]``;
- moments (eq. 39): ``l = Ixx p' + (Izz-Iyy) q r``, ``m = Iyy q' + (Ixx-Izz) p r``,
  ``n = Izz r' + (Iyy-Ixx) p q``.

With the dynamics of ``sitl_sim.physics.dynamics`` this makes each Euler angle a second-order system
with natural frequency ``sqrt(k_p)`` and damping ``k_d / (2 sqrt(k_p))`` (0.95 for the default
gains). All arrays carry one column per vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocols.model.frames import FloatArray, zyx_from_quat_batch
from protocols.model.frames import (
    yaw_from_quat_batch as yaw_from_quat_batch,  # (callers' old import)
)
from sitl_sim.physics.dynamics import QUAT, RATES
from sitl_sim.physics.vehicle_params import VehicleParams

#: Smallest cos(pitch) used in ``W``: keeps the controller finite at +-90 deg pitch.
MIN_COS_PITCH = 1e-6
#: The old name, imported by sitl_sim/physics/jit.py (until it imports MIN_COS_PITCH).
_MIN_COS_PITCH = MIN_COS_PITCH


@dataclass(frozen=True)
class AttitudeGains:
    """PD gains on (roll, pitch, yaw): ``kp`` in 1/s^2, ``kd`` in 1/s (paper's k_ap, k_ad)."""

    kp: tuple[float, float, float] = (324.0, 324.0, 144.0)
    kd: tuple[float, float, float] = (34.2, 34.2, 22.8)

    def validate(self) -> AttitudeGains:
        """Raise ValueError naming the field unless every gain is finite and positive."""
        for name in ("kp", "kd"):
            values = getattr(self, name)
            if len(values) != 3 or not all(math.isfinite(v) and v > 0.0 for v in values):
                raise ValueError(f"AttitudeGains.{name} must be 3 finite positive numbers")
        return self

    def kp_col(self) -> FloatArray:
        """``kp`` as a (3, 1) column for broadcasting over vehicles."""
        return np.asarray(self.kp, dtype=np.float64)[:, None]

    def kd_col(self) -> FloatArray:
        """``kd`` as a (3, 1) column for broadcasting over vehicles."""
        return np.asarray(self.kd, dtype=np.float64)[:, None]


def euler_from_quat_batch(quat: FloatArray) -> FloatArray:
    """The controller's ``eta`` (3, N): ZYX angles as rows ``(roll, pitch, yaw)`` rad, of
    quaternions (4, N) ``(w, x, y, z)`` (:func:`protocols.model.frames.zyx_from_quat_batch`)."""
    yaw, pitch, roll = zyx_from_quat_batch(quat)
    out = np.empty((3, quat.shape[1]))
    out[0], out[1], out[2] = roll, pitch, yaw
    return out


def euler_rates_from_body_rates(euler_rad: FloatArray, rates_rad_s: FloatArray) -> FloatArray:
    """Euler-angle rates (3, N) rad/s from body rates (3, N) rad/s at angles (3, N) (eq. 20)."""
    sphi, cphi = np.sin(euler_rad[0]), np.cos(euler_rad[0])
    ctheta = np.maximum(np.cos(euler_rad[1]), MIN_COS_PITCH)
    ttheta = np.sin(euler_rad[1]) / ctheta
    p, q, r = rates_rad_s[0], rates_rad_s[1], rates_rad_s[2]
    qr_roll = sphi * q + cphi * r
    out = np.empty_like(rates_rad_s)
    out[0] = p + ttheta * qr_roll
    out[1] = cphi * q - sphi * r
    out[2] = qr_roll / ctheta
    return out


def attitude_moments(
    state: FloatArray,
    euler_des_rad: FloatArray,
    params: VehicleParams,
    gains: AttitudeGains,
    euler_rate_des_rad_s: FloatArray | None = None,
    euler_acc_des_rad_s2: FloatArray | None = None,
) -> FloatArray:
    """Body moments (3, N) N m driving the attitude of ``state`` (13, N) to ``euler_des_rad``.

    ``euler_des_rad`` (3, N) is (roll, pitch, yaw) in radians; the optional feed-forward Euler
    rates (3, N) rad/s and accelerations (3, N) rad/s^2 default to zero.
    """
    eta = euler_from_quat_batch(state[QUAT])
    rates = state[RATES]
    eta_dot = euler_rates_from_body_rates(eta, rates)
    err = np.asarray(euler_des_rad, dtype=np.float64) - eta
    err[2] = (err[2] + np.pi) % (2.0 * np.pi) - np.pi
    rate_err = -eta_dot if euler_rate_des_rad_s is None else euler_rate_des_rad_s - eta_dot
    tau = gains.kp_col() * err + gains.kd_col() * rate_err
    if euler_acc_des_rad_s2 is not None:
        tau += euler_acc_des_rad_s2
    omega_dot = _body_acc_from_euler_acc(eta, eta_dot, tau)
    return _moments_from_body_acc(rates, omega_dot, params)


def _body_acc_from_euler_acc(eta: FloatArray, eta_dot: FloatArray, tau: FloatArray) -> FloatArray:
    """``omega' = E tau + E' eta'`` (3, N): body angular acceleration for Euler acceleration tau."""
    sphi, cphi = np.sin(eta[0]), np.cos(eta[0])
    sth, cth = np.sin(eta[1]), np.cos(eta[1])
    phid, thd, psid = eta_dot[0], eta_dot[1], eta_dot[2]
    out = np.empty_like(tau)
    out[0] = tau[0] - sth * tau[2] - cth * thd * psid
    out[1] = (
        cphi * tau[1]
        + sphi * cth * tau[2]
        - sphi * phid * thd
        + (cphi * cth * phid - sphi * sth * thd) * psid
    )
    out[2] = (
        -sphi * tau[1]
        + cphi * cth * tau[2]
        - cphi * phid * thd
        - (sphi * cth * phid + cphi * sth * thd) * psid
    )
    return out


def _moments_from_body_acc(
    rates: FloatArray, omega_dot: FloatArray, params: VehicleParams
) -> FloatArray:
    """Eq. 39: moments (3, N) N m producing body acceleration (3, N) at body rates (3, N)."""
    ixx, iyy, izz = params.ixx, params.iyy, params.izz
    p, q, r = rates[0], rates[1], rates[2]
    out = np.empty_like(omega_dot)
    out[0] = ixx * omega_dot[0] + (izz - iyy) * (q * r)
    out[1] = iyy * omega_dot[1] + (ixx - izz) * (p * r)
    out[2] = izz * omega_dot[2] + (iyy - ixx) * (p * q)
    return out
