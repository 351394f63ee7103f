"""The vehicle's offboard-loss failsafe, pure: its tunables and the vertical-speed loop it flies.

When a vehicle armed in offboard mode receives no valid setpoint for ``offboard_timeout_s`` its
autopilot (sitl_sim/vehicle/autopilot.py) levels it (roll = pitch = 0, yaw held) and holds its
altitude for ``hold_s``, then lands it at ``descent_rate_m_s``, and disarms it once it rests on the
ground; sitl_sim/vehicle/guidance.py flies the hold and the descent through
:func:`vertical_speed_hold`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocols.model.frames import G_M_S2, FloatArray


@dataclass(frozen=True)
class FailsafeConfig:
    """Timings (s), the descent rate (m/s) and the vertical-speed loop gain (1/s)."""

    offboard_timeout_s: float = 0.5
    hold_s: float = 1.0
    descent_rate_m_s: float = 0.7
    vertical_speed_gain_per_s: float = 2.0


def vertical_speed_hold(
    velocity_down_m_s: FloatArray,
    yaw_rad: FloatArray,
    target_down_m_s: FloatArray | float,
    hover_thrust_normalised: float,
    gain_per_s: float,
) -> tuple[FloatArray, FloatArray]:
    """Level attitude (3, N) ZYX rad at ``yaw_rad`` (N,) and normalised thrust (N,) in 0..1
    driving the NED vertical speed (N,) m/s (positive down) to ``target_down_m_s`` (N,) or scalar
    (0: hold altitude; > 0: descend), with a proportional loop of ``gain_per_s`` (1/s)."""
    vz = np.asarray(velocity_down_m_s, dtype=float)
    # NED: positive vz is down; more thrust when sinking faster than the target.
    accel_up = gain_per_s * (vz - target_down_m_s)
    thrust = hover_thrust_normalised * (1.0 + accel_up / G_M_S2)
    attitude = np.zeros((3, vz.shape[0]))
    attitude[2] = yaw_rad
    return attitude, np.clip(thrust, 0.0, 1.0)
