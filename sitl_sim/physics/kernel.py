"""Physics sub-steps of N vehicles, compiled: inner loop, rotor wrench, RK4 and ground contact.

:class:`PhysicsKernel` does what ``inner_loop`` (:mod:`sitl_sim.physics.inner_loop`, with an
Euler-angle setpoint) followed by ``step_with_contact`` (:mod:`sitl_sim.physics.dynamics`, RK4) do,
with the same floating-point operations in the same order on each vehicle, so it gives the same
numbers to round-off (the transcendental functions are the C library's, not numpy's own vector
versions: they may differ in the last bit; tests/test_physics_kernel.py compares states, rotor
forces and touchdown speeds to 1e-9 over hundreds of steps with contact, saturation, NaN demands and
motor failures). Those functions stay the readable reference; this is the fast path that
:class:`sitl_sim.vehicle.world.World` (``swarm sim``) and ``swarm simulate`` step.

Why compiled: at small N a numpy call costs its overhead (~0.2 us), not its arithmetic, and the
reference makes ~700 of them per sub-step (a numpy version of this kernel with every buffer
preallocated still made ~230: ~50 us a sub-step at N = 9, ~500 us a 50 Hz tick). Here one call
of :func:`sitl_sim.physics.jit.advance` (numba, compiled once and cached beside it) runs a tick's
sub-steps for every vehicle in plain floating point: each vehicle's state stays in registers
through its sub-steps, and vehicles never mix (each vehicle's mixer, contact and integration are
its own).

Motors that lag (``VehicleParams.motor_tau_s`` > 0): each rotor's speed follows the mixer's
command as a first-order lag, exactly over each sub-step (the command is held), and the rigid
body's RK4 takes the rotors' wrench at each of its stage times. The rotor speeds are then state:
a call takes them (``rotor_rad_s``) and returns them. A vehicle whose motors do not lag runs the
arithmetic it ran before the lag existed, whatever the others do.

Pure: no I/O, no clock. The kernel keeps scratch buffers between calls but no state: every call
takes the state (and the rotor speeds) and returns new arrays.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray
from protocols.runtime.compiled import compiled
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.vehicle_params import VehicleParams

Enable = FloatArray | npt.NDArray[np.bool_] | None


class PhysicsKernel:
    """Sub-steps of N vehicles, each ``dt_s`` seconds (RK4): all of them ``params``, or each its
    own (``fleet``, N of them: vehicles that differ).

    ``gains`` are the attitude PD gains: an :class:`AttitudeGains` (one set for every vehicle) or
    a fleet whose ``kp_col()``/``kd_col()`` are (3, N); :meth:`use_gains` changes them.
    """

    def __init__(
        self,
        params: VehicleParams,
        n: int,
        dt_s: float,
        gains: AttitudeGains | None = None,
        fleet: Sequence[VehicleParams] | None = None,
    ) -> None:
        if fleet is not None and len(fleet) != n:
            raise ValueError(f"fleet: {len(fleet)} vehicles' parameters for {n} vehicles")
        self.params = params
        #: each vehicle's parameters
        self.fleet = list(fleet) if fleet is not None else [params] * n
        self.n = n
        self.dt_s = dt_s
        # numba is imported here, not with this module: processes that import the simulator's
        # modules without stepping vehicles (the ground station, `swarm` commands) skip it
        from sitl_sim.physics import jit as physics_jit

        physics_jit.ready()
        self._advance = compiled(physics_jit.advance)
        self._constants = physics_jit.fleet_constants(self.fleet, dt_s)
        self._kp = np.empty((3, n))
        self._kd = np.empty((3, n))
        self._gains: list[FloatArray] = [self._kp, self._kd]
        self._all_on = np.ones((4, n))
        self._enable = np.empty((4, n))
        self._rotors_at_rest = np.zeros((4, n))
        #: the air's velocity (3, N) m/s NED the next sub-steps fly in (:meth:`use_air`)
        self.air = np.zeros((3, n))
        g = gains if gains is not None else AttitudeGains()
        self.use_gains(g.kp_col(), g.kd_col())

    def use_gains(self, kp: FloatArray, kd: FloatArray) -> None:
        """Attitude gains for the next sub-steps: (3, N) arrays are used as they are (so a fleet's
        live gain matrices stay live), (3, 1) or (3,) ones are spread over the N vehicles."""
        for slot, value in enumerate((kp, kd)):
            arr = np.asarray(value, dtype=np.float64)
            if arr.shape == (3, self.n):
                self._gains[slot] = arr
            else:
                own = self._kp if slot == 0 else self._kd
                own[...] = arr.reshape(3, -1)
                self._gains[slot] = own

    def use_air(self, air_ned_m_s: FloatArray | None) -> None:
        """The air's velocity (3, N) m/s NED for the next sub-steps, held over them (None:
        still air). Felt through the vehicles' body drag only."""
        if air_ned_m_s is None:
            self.air[...] = 0.0
        else:
            self.air[...] = np.asarray(air_ned_m_s, dtype=np.float64).reshape(3, self.n)

    def substep(
        self,
        state: FloatArray,
        euler_des: FloatArray,
        thrust_normalised: FloatArray,
        enable: Enable = None,
        rotor_rad_s: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Advance ``state`` (13, N) by one sub-step under an attitude setpoint.

        Args:
            state: vehicle states (13, N), layout of :mod:`sitl_sim.physics.dynamics`.
            euler_des: ZYX attitude setpoint (3, N) rad.
            thrust_normalised: collective thrust (N,) as a fraction of the maximum.
            enable: rotor speeds are multiplied by it: (N,) (armed) or (4, N) (armed and motor
                working) booleans or 0/1 floats; None: all rotors run.
            rotor_rad_s: the rotors' speeds (4, N) rad/s at the start, read for the vehicles
                whose motors lag (the last call's rotor speeds); None: at rest.

        Returns:
            The new state (13, N) (a new array), the rotor speeds (4, N) rad/s (a new array:
            those of :func:`sitl_sim.physics.inner_loop.inner_loop`, with disabled rotors at
            0; where the motors lag, the rotors' speeds at the end, which follow them), and each
            vehicle's touchdown speed (N,) m/s, or None if no vehicle touched the ground.
        """
        new, rotor, impacts, touched = self._run(
            state, euler_des, thrust_normalised, enable, 1, rotor_rad_s
        )
        return new, rotor, impacts[0] if touched[0] else None

    def substeps(
        self,
        state: FloatArray,
        euler_des: FloatArray,
        thrust_normalised: FloatArray,
        enable: Enable,
        count: int,
        rotor_rad_s: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
        """``count`` (>= 1) sub-steps under the same setpoint and ``enable``: the same numbers
        as ``count`` calls of :meth:`substep` (each given the last one's rotor speeds), in one
        call. Returns the last state and rotor speeds, and the touchdown speeds (N,) of each
        sub-step in which a vehicle touched the ground, in order."""
        if count < 1:
            raise ValueError(f"count must be at least 1, got {count}")
        new, rotor, impacts, touched = self._run(
            state, euler_des, thrust_normalised, enable, count, rotor_rad_s
        )
        return new, rotor, [impacts[k] for k in np.flatnonzero(touched)]

    def _run(
        self,
        state: FloatArray,
        euler_des: FloatArray,
        thrust_normalised: FloatArray,
        enable: Enable,
        count: int,
        rotor_rad_s: FloatArray | None,
    ) -> tuple[FloatArray, FloatArray, FloatArray, npt.NDArray[np.bool_]]:
        n = self.n
        if enable is None:
            on = self._all_on
        else:
            on = self._enable
            on[...] = enable
        new, rotor = np.empty((13, n)), np.empty((4, n))
        impacts, touched = np.zeros((count, n)), np.zeros(count, dtype=np.bool_)
        rotor_now = (
            self._rotors_at_rest
            if rotor_rad_s is None
            else np.ascontiguousarray(rotor_rad_s, dtype=np.float64).reshape(4, n)
        )
        self._advance(
            np.ascontiguousarray(state, dtype=np.float64),
            rotor_now,
            np.ascontiguousarray(euler_des, dtype=np.float64),
            np.ascontiguousarray(thrust_normalised, dtype=np.float64).reshape(n),
            on,
            np.ascontiguousarray(self._gains[0]),
            np.ascontiguousarray(self._gains[1]),
            self._constants,
            count,
            new,
            rotor,
            impacts,
            touched,
            self.air,
        )
        return new, rotor, impacts, touched
