"""From a commanded acceleration to collective thrust and an attitude setpoint.

ALGORITHM.md §1 eq. 35 as corrected, and the limits of §4. Pure and I/O-free.

With ``a = g e3 - v`` the specific force the rotors must produce (NED; ``a_z > 0`` lifts)::

    T = m |a|,   pitch = atan2(-(v_x cos(yaw) + v_y sin(yaw)), g - v_z),
    roll = asin(m (v_y cos(yaw) - v_x sin(yaw)) / T)

Limits, vertical first: ``a_z`` is held in [T_min, T_max]/m, then the horizontal part is cut to the
tilt limit and to what the remaining thrust allows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from drone_agent.core.jit_math import jit, nmax, nmin
from protocols.model.frames import G_M_S2, FloatArray


@dataclass(frozen=True)
class ThrustLimits:
    """``min_thrust_ratio`` of the weight, ``max_thrust_ratio`` of the vehicle's maximum thrust."""

    mass_kg: float
    max_thrust_n: float
    min_thrust_ratio: float = 0.2
    max_thrust_ratio: float = 0.85
    max_tilt_rad: float = float(np.radians(35.0))

    @property
    def thrust_range_n(self) -> tuple[float, float]:
        return (
            self.min_thrust_ratio * self.mass_kg * G_M_S2,
            self.max_thrust_ratio * self.max_thrust_n,
        )


@dataclass(frozen=True)
class AttitudeThrust:
    """Attitude setpoint (ZYX, rad) and collective thrust (N); ``limited``: a limit was applied."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    thrust_n: float
    limited: bool


def attitude_thrust(
    accel_ned_m_s2: FloatArray, yaw_rad: float, limits: ThrustLimits
) -> AttitudeThrust:
    """Thrust and attitude that realise the commanded acceleration v (3,) at heading ``yaw_rad``."""
    roll, pitch, thrust, limited = attitude_thrust_batch(
        np.asarray(accel_ned_m_s2, dtype=float)[None], np.array([yaw_rad], dtype=float), limits
    )
    return AttitudeThrust(
        float(roll[0]), float(pitch[0]), float(yaw_rad), float(thrust[0]), bool(limited[0])
    )


def attitude_thrust_batch(
    accel_ned_m_s2: FloatArray, yaw_rad: FloatArray, limits: ThrustLimits
) -> tuple[FloatArray, FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """:func:`attitude_thrust` of K commands: accelerations (K, 3), headings (K,) ->
    ``(roll_rad, pitch_rad, thrust_n, limited)``, (K,) each (the yaw setpoint is the heading).
    One compiled loop over the commands (drone_agent/core/jit_math.py)."""
    k = accel_ned_m_s2.shape[0]
    out = np.empty((3, k))
    limited = np.empty(k, dtype=np.bool_)
    t_min, t_max = limits.thrust_range_n
    _attitude_rows(
        np.ascontiguousarray(accel_ned_m_s2, dtype=np.float64),
        np.ascontiguousarray(yaw_rad, dtype=np.float64),
        float(limits.mass_kg),
        float(t_min),
        float(t_max),
        float(np.tan(limits.max_tilt_rad)),
        out,
        limited,
    )
    return out[0], out[1], out[2], limited


@jit
def _attitude_rows(v, yaw, m, t_min, t_max, tan_tilt, out, limited):  # type: ignore[no-untyped-def]
    """Roll, pitch and thrust (rows of ``out``) and whether a limit applied, per command (the
    module doc: vertical first, then the horizontal part to the tilt and the thrust left)."""
    for r in range(v.shape[0]):
        up = G_M_S2 - v[r, 2]
        up_limited = nmin(nmax(up, t_min / m), t_max / m)
        h_max = nmin(tan_tilt * up_limited, np.sqrt(nmax((t_max / m) ** 2 - up_limited**2, 0.0)))
        hx, hy = v[r, 0], v[r, 1]
        h_norm = np.hypot(hx, hy)
        limited[r] = up_limited != up
        if h_norm > h_max:
            hx = hx * (h_max / h_norm)
            hy = hy * (h_max / h_norm)
            limited[r] = True
        thrust = m * np.sqrt(hx * hx + hy * hy + up_limited**2)
        cy, sy = np.cos(yaw[r]), np.sin(yaw[r])
        out[1, r] = np.arctan2(-(hx * cy + hy * sy), up_limited)
        lateral = m * (hy * cy - hx * sy) / thrust
        out[0, r] = np.arcsin(nmin(nmax(lateral, -1.0), 1.0))
        out[2, r] = thrust
