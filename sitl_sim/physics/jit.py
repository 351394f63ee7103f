"""The compiled loop of :class:`sitl_sim.physics.kernel.PhysicsKernel` (numba).

:func:`advance` runs sub-steps of every vehicle under an attitude setpoint (the autopilot's inner
loop, then the rigid body, its rotors lagging their commands where its motors have a time
constant), one vehicle after the other (each vehicle's state stays in registers
through its sub-steps; vehicles never mix): a loop that calls the per-vehicle rules of
:mod:`sitl_sim.physics.rules` (inlined). Compiled on first use (protocols/runtime/compiled.py) and
cached beside this file (``__pycache__``), so that later processes load it (~0.3 s of CPU with
numba's import) instead of compiling it (~3 s).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray
from protocols.runtime.compiled import jit
from sitl_sim.physics import rules as physics_rules
from sitl_sim.physics.attitude_control import MIN_COS_PITCH
from sitl_sim.physics.rules import (
    LAG,
    attitude_moments,
    collective_thrust,
    contact_column,
    mix,
    rk4_into,
    rk4_lagged_into,
    rotor_wrench,
)
from sitl_sim.physics.vehicle_params import VehicleParams

__all__ = ["advance", "constants", "fleet_constants", "ready"]


def constants(params: VehicleParams, dt_s: float) -> FloatArray:
    """One vehicle's constants (:func:`sitl_sim.physics.rules.constants` with the attitude
    controller's smallest cos(pitch))."""
    return physics_rules.constants(params, dt_s, MIN_COS_PITCH)


def fleet_constants(fleet: Sequence[VehicleParams], dt_s: float) -> FloatArray:
    """Every vehicle's constants (N, N_CONSTANTS) for :func:`advance`."""
    rows = {id(v): constants(v, dt_s) for v in fleet}  # (a nominal fleet: one row, copied)
    return np.ascontiguousarray([rows[id(v)] for v in fleet])


@jit
def advance(
    state: FloatArray,
    rotor_now: FloatArray,
    euler_des: FloatArray,
    thrust_normalised: FloatArray,
    enable: FloatArray,
    kp: FloatArray,
    kd: FloatArray,
    cs: FloatArray,
    count: int,
    new: FloatArray,
    rotor: FloatArray,
    impacts: FloatArray,
    touched: npt.NDArray[np.bool_],
    air: FloatArray,
) -> None:  # pragma: no cover - compiled (its Python body runs with NUMBA_DISABLE_JIT=1)
    """``count`` sub-steps of every vehicle under the attitude setpoint ``euler_des`` (3, N)
    and normalised thrust (N,), rotor speeds times ``enable`` (4, N), in air moving at ``air``
    (3, N) m/s NED (read only with body drag), each vehicle with its own constants ``cs[i]``
    (N, N_CONSTANTS; :func:`fleet_constants`): ``new`` (13, N) the last
    state, ``rotor`` (4, N) the last rotor speeds, ``impacts[k]`` (N,) the touchdown speeds of
    sub-step ``k`` and ``touched[k]`` whether any vehicle was on the ground after it.

    A vehicle whose motors lag (``cs[i, LAG]``) starts from its rotor speeds ``rotor_now``
    (4, N) rad/s (read for it alone) and its ``rotor`` are its rotors' speeds at the end; the
    others' rotors turn as commanded (``rotor``: the last command)."""
    s, xt = np.empty(13), np.empty(13)
    k1, k2, k3, k4 = np.empty(13), np.empty(13), np.empty(13), np.empty(13)
    for i in range(state.shape[1]):
        c = cs[i]
        s[:] = state[:, i]
        ry, py_, yy = euler_des[0, i], euler_des[1, i], euler_des[2, i]
        kp0, kp1, kp2 = kp[0, i], kp[1, i], kp[2, i]
        kd0, kd1, kd2 = kd[0, i], kd[1, i], kd[2, i]
        t_dem = collective_thrust(thrust_normalised[i], c)
        en0, en1, en2, en3 = enable[0, i], enable[1, i], enable[2, i], enable[3, i]
        air_i = air[:, i]
        lag = c[LAG] != 0.0
        r0, r1, r2, r3 = rotor_now[0, i], rotor_now[1, i], rotor_now[2, i], rotor_now[3, i]
        w0 = w1 = w2 = w3 = 0.0
        for k in range(count):
            m_l, m_m, m_n = attitude_moments(s, ry, py_, yy, kp0, kp1, kp2, kd0, kd1, kd2, c)
            w0, w1, w2, w3 = mix(t_dem, m_l, m_m, m_n, c)
            w0, w1, w2, w3 = w0 * en0, w1 * en1, w2 * en2, w3 * en3
            x0, y0, z0, vz0 = s[0], s[1], s[2], s[5]
            if lag:
                thrust, r0, r1, r2, r3 = rk4_lagged_into(
                    s, r0, r1, r2, r3, w0, w1, w2, w3, c, k1, k2, k3, k4, xt, air_i
                )
            else:
                thrust, t_m, a0, a1, a2 = rotor_wrench(w0, w1, w2, w3, c)
                rk4_into(s, t_m, a0, a1, a2, c, k1, k2, k3, k4, xt, air_i)
            if contact_column(s, x0, y0, z0, vz0, thrust, c, impacts[k], i):
                touched[k] = True
        new[:, i] = s
        if lag:
            w0, w1, w2, w3 = r0, r1, r2, r3
        rotor[0, i], rotor[1, i], rotor[2, i], rotor[3, i] = w0, w1, w2, w3


def ready() -> None:
    """Compile :func:`advance` (or load it from the cache) now, on one vehicle at rest, so that
    the first sub-step of a flight does not pay for it: a simulator calls this before it serves
    (a first compile takes seconds, longer than an agent waits for its vehicle in realtime)."""
    state = np.zeros((13, 1))
    state[6] = 1.0
    gains = np.ones((3, 1))
    advance(
        state, np.zeros((4, 1)), np.zeros((3, 1)), np.zeros(1), np.ones((4, 1)), gains, gains,
        fleet_constants([VehicleParams()], 0.002), 1, np.empty((13, 1)), np.empty((4, 1)),
        np.zeros((1, 1)), np.zeros(1, dtype=np.bool_), np.zeros((3, 1)),
    )  # fmt: skip
