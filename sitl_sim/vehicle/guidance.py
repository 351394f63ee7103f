"""What each vehicle's autopilot asks of its inner loop at every physics step. Pure, vectorised.

Per vehicle, by state (see :mod:`sitl_sim.vehicle.autopilot`):

- armed in OFFBOARD: the last valid setpoint (ZYX attitude, normalised thrust);
- armed in HOLD or LAND, airborne: level at the current yaw (yaw rate damped), thrust from a
  vertical-speed loop whose target is an altitude hold (HOLD: ``v = k (z_hold - z)``, limited to
  the climb speed) or the land speed (LAND, positive down);
- armed in HOLD or LAND on the ground: idle (zero thrust, level);
- disarmed: anything (the inner loop gives disarmed vehicles zero rotor speed).

:meth:`Guidance.prepare` runs once per control period (modes only change between periods);
:meth:`Guidance.command` runs every physics step and recomputes only the vehicles whose command
depends on the state within the period (airborne HOLD/LAND). While there are none
(:attr:`Guidance.steady`) the period's command is one for all its physics steps, which the world
then takes in one kernel call.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray
from sitl_sim.physics.attitude_control import euler_from_quat_batch
from sitl_sim.physics.dynamics import QUAT
from sitl_sim.vehicle.autopilot import Autopilot, Mode
from sitl_sim.vehicle.failsafe import vertical_speed_hold


class Guidance:
    """Attitude (3, N) ZYX rad and normalised thrust (N,) commands of ``autopilot``'s vehicles.

    ``hover_thrust`` is the normalised thrust that balances the weight when level.
    """

    def __init__(self, autopilot: Autopilot, hover_thrust: float) -> None:
        self.ap = autopilot
        self.hover_thrust = hover_thrust
        n = autopilot.n
        self.euler_rad = np.zeros((3, n))
        self.thrust = np.zeros(n)
        self._auto_idx: npt.NDArray[np.intp] = np.zeros(0, dtype=np.intp)
        self._hold = np.zeros(0, dtype=bool)

    def prepare(self, state: FloatArray) -> None:
        """Set up the commands of the next control period from the modes and ``state`` (13, N)."""
        ap = self.ap
        offboard = ap.armed & (ap.mode == Mode.OFFBOARD)
        self.euler_rad[:] = ap.sp_euler_rad
        np.copyto(self.thrust, np.where(offboard, ap.sp_thrust, 0.0))
        automatic = ap.armed & ~offboard
        if not automatic.any():
            self._auto_idx = np.zeros(0, dtype=np.intp)
            return
        auto_idx = np.flatnonzero(automatic)
        yaw = euler_from_quat_batch(state[QUAT][:, auto_idx])[2]
        self.euler_rad[:, auto_idx] = 0.0
        self.euler_rad[2, auto_idx] = yaw
        unlatched = auto_idx[np.isnan(ap.hold_z_m[auto_idx])]
        ap.hold_z_m[unlatched] = state[2, unlatched]
        self._auto_idx = auto_idx[~ap.landed[auto_idx]]
        self._hold = ap.mode[self._auto_idx] == Mode.HOLD

    @property
    def steady(self) -> bool:
        """No vehicle's command depends on the state within the period (none airborne in HOLD
        or LAND): :meth:`command` gives the same command at every physics step of it."""
        return not self._auto_idx.size

    def command(self, state: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Attitude (3, N) and thrust (N,) for one physics step at ``state`` (13, N)."""
        idx = self._auto_idx
        if idx.size:
            ap = self.ap
            z = state[2, idx]
            hold_target = ap.config.altitude_gain_per_s * (ap.hold_z_m[idx] - z)
            limit = ap.config.max_climb_m_s
            target = np.where(
                self._hold, np.clip(hold_target, -limit, limit), ap.land_speed_m_s[idx]
            )
            yaw = self.euler_rad[2, idx]
            attitude, thrust = vertical_speed_hold(
                state[5, idx],
                yaw,
                target,
                self.hover_thrust,
                ap.config.failsafe.vertical_speed_gain_per_s,
            )
            self.euler_rad[:, idx] = attitude
            self.thrust[idx] = thrust
        return self.euler_rad, self.thrust
