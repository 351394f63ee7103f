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

from protocols.frames import G_M_S2, FloatArray


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
    v = np.asarray(accel_ned_m_s2, dtype=float)
    m = limits.mass_kg
    t_min, t_max = limits.thrust_range_n
    up = G_M_S2 - float(v[2])
    up_limited = min(max(up, t_min / m), t_max / m)
    horiz = v[:2].copy()
    h_max = min(
        np.tan(limits.max_tilt_rad) * up_limited,
        np.sqrt(max((t_max / m) ** 2 - up_limited**2, 0.0)),
    )
    h_norm = float(np.hypot(horiz[0], horiz[1]))
    limited = up_limited != up
    if h_norm > h_max:
        horiz *= h_max / h_norm
        limited = True
    thrust = m * float(np.sqrt(horiz @ horiz + up_limited**2))
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    pitch = float(np.arctan2(-(horiz[0] * cy + horiz[1] * sy), up_limited))
    roll = float(np.arcsin(np.clip(m * (horiz[1] * cy - horiz[0] * sy) / thrust, -1.0, 1.0)))
    return AttitudeThrust(roll, pitch, float(yaw_rad), thrust, limited)
