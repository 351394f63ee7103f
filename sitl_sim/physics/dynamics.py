"""Vectorised 6-DOF rigid-body dynamics of N quadcopters (ALGORITHM.md §1, paper eq. 3-6).

Pure, no I/O and no clock: ``step(state, rotor_speeds, params, dt_s) -> state``. The rules are
written once, for one vehicle, in :mod:`sitl_sim.physics.rules` (compiled); this module is
their interface over N vehicles, with the state layout.

State layout, a (13, N) float64 array, one column per vehicle:

- ``POS``   rows 0:3   position in world NED (m), ground at ``z = 0``, airborne means ``z < 0``;
- ``VEL``   rows 3:6   velocity in world NED (m/s);
- ``QUAT``  rows 6:10  attitude quaternion ``(w, x, y, z)``, body FRD -> world NED;
- ``RATES`` rows 10:13 body rates ``(p, q, r)`` about body FRD axes (rad/s).

Translation: ``a = g e3 - (T/m) R_b e3``. Rotation (Euler's equations, corrected eq. 6):
``p' = qr(Iyy-Izz)/Ixx + l/Ixx``, ``q' = pr(Izz-Ixx)/Iyy + m/Iyy``,
``r' = pq(Ixx-Iyy)/Izz + n/Izz``.
Rotor speeds are held constant over a step (zero-order hold); classic RK4, the quaternion
re-normalised after it. (Motors that lag, ``VehicleParams.motor_tau_s``, are the simulator's
kernel's: sitl_sim/physics/kernel.py; here the rotor speeds given are those of the step.)

Ground contact (after each step): a vehicle at or below the ground moving down is put on the
ground with zero velocity and body rates (inelastic, with friction); while its thrust is below
its weight it stays put and is levelled (roll = pitch = 0, yaw kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocols.model.frames import FloatArray
from protocols.runtime.compiled import compiled
from sitl_sim.physics import rules as physics_rules
from sitl_sim.physics.rules import constants
from sitl_sim.physics.vehicle_params import VehicleParams

POS = slice(0, 3)
VEL = slice(3, 6)
QUAT = slice(6, 10)
RATES = slice(10, 13)
STATE_ROWS = 13

_METHODS = ("rk4",)


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
    state: FloatArray,
    thrust_n: FloatArray,
    moments_nm: FloatArray,
    params: VehicleParams,
    air_ned_m_s: FloatArray | None = None,
) -> FloatArray:
    """Time derivative (13, N) of ``state`` (13, N) under thrust (N,) N and moments (3, N) N m,
    in air moving at ``air_ned_m_s`` (3, N) m/s NED (None: still air; read only with body
    drag)."""
    s = np.ascontiguousarray(state, dtype=np.float64)
    t_m = np.asarray(thrust_n, dtype=np.float64).reshape(-1) * (1.0 / params.mass_kg)
    alpha = np.asarray(moments_nm, dtype=np.float64).reshape(3, -1) / params.inertia[:, None]
    out = np.empty_like(s)
    compiled(physics_rules.derivative_rows)(
        s, t_m, np.ascontiguousarray(alpha), constants(params, 0.0), out, _air(air_ned_m_s, s)
    )
    return out


def _air(air_ned_m_s: FloatArray | None, state: FloatArray) -> FloatArray:
    if air_ned_m_s is None:
        return np.zeros((3, state.shape[1]))
    return np.ascontiguousarray(air_ned_m_s, dtype=np.float64).reshape(3, -1)


def step(
    state: FloatArray,
    rotor_speed_rad_s: FloatArray,
    params: VehicleParams,
    dt_s: float,
    method: str = "rk4",
    air_ned_m_s: FloatArray | None = None,
) -> FloatArray:
    """Advance ``state`` (13, N) by ``dt_s`` seconds under rotor speeds (4, N) rad/s, in air
    moving at ``air_ned_m_s`` (3, N) m/s NED (None: still air).

    ``method`` is ``"rk4"`` (classic Runge-Kutta, the only one). The quaternion is re-normalised,
    then ground contact is applied. Returns a new (13, N) array.
    """
    return step_with_contact(state, rotor_speed_rad_s, params, dt_s, method, air_ned_m_s).state


def step_with_contact(
    state: FloatArray,
    rotor_speed_rad_s: FloatArray,
    params: VehicleParams,
    dt_s: float,
    method: str = "rk4",
    air_ned_m_s: FloatArray | None = None,
) -> StepResult:
    """As :func:`step`, also reporting each vehicle's touchdown speed (N,) m/s for this step."""
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    s = np.ascontiguousarray(state, dtype=np.float64)
    new, impact = np.empty_like(s), np.zeros(s.shape[1])
    rotor = np.ascontiguousarray(rotor_speed_rad_s, dtype=np.float64).reshape(4, -1)
    air = _air(air_ned_m_s, s)
    compiled(physics_rules.advance_rotors)(s, rotor, constants(params, dt_s), new, impact, air)
    return StepResult(state=new, impact_speed_m_s=impact)


def ground_contact(
    state: FloatArray, prev_state: FloatArray, thrust_n: FloatArray, params: VehicleParams
) -> tuple[FloatArray, FloatArray]:
    """Apply ground contact to ``state`` (13, N) reached from ``prev_state`` (13, N).

    ``thrust_n`` (N,) is the collective thrust (N) over the step. Returns the corrected state
    (a copy) and the touchdown speed (N,) m/s of each vehicle (0 if it did not touch down).
    """
    new = np.array(state, dtype=np.float64, order="C")
    impact = np.zeros(new.shape[1])
    prev = np.ascontiguousarray(prev_state, dtype=np.float64)
    thrust = np.ascontiguousarray(thrust_n, dtype=np.float64).reshape(-1)
    compiled(physics_rules.contact_rows)(new, prev, thrust, constants(params, 0.0), impact)
    return new, impact
