"""A closed-loop swarm of point masses for the separation layer's tests: a go-to-goal nominal
command, the filter, and the vehicle's acceleration limit (what thrust/attitude realise), at the
50 Hz control rate, with an optional neighbour-data delay and an optional first-order lag of the
realised acceleration (the attitude loop)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drone_agent.core.separation.filter import SeparationParams, filter_accelerations
from drone_agent.core.thrust_attitude import ThrustLimits, attitude_thrust
from protocols.model.frames import G_M_S2, FloatArray, rot_zyx

DT_S = 0.02
#: The paper's vehicle (Table II), thrust-to-weight 2.
LIMITS = ThrustLimits(mass_kg=0.34, max_thrust_n=2 * 0.34 * G_M_S2)

Nominal = Callable[[FloatArray, FloatArray], FloatArray]


def realised(accel_ned_m_s2: FloatArray) -> FloatArray:
    """The accelerations (K, 3) the vehicle makes for the commanded ones: through thrust/attitude
    (its limits) and back, ``g e3 - (T/m) R e3``."""
    out = np.empty_like(accel_ned_m_s2)
    for i, u in enumerate(accel_ned_m_s2):
        at = attitude_thrust(u, 0.0, LIMITS)
        r = rot_zyx(0.0, at.pitch_rad, at.roll_rad)
        out[i] = np.array([0.0, 0.0, G_M_S2]) - at.thrust_n / LIMITS.mass_kg * r[:, 2]
    return out


def go_to(goals: FloatArray, v_max: float = 3.0, kp: float = 1.0, kv: float = 2.0,
          a_max: float = 4.0) -> Nominal:  # fmt: skip
    """A nominal command: fly towards ``goals`` (K, 3) at up to ``v_max`` m/s, at most
    ``a_max`` m/s²."""

    def command(p: FloatArray, v: FloatArray) -> FloatArray:
        v_des = kp * (goals - p)
        speed = np.linalg.norm(v_des, axis=1, keepdims=True)
        v_des *= np.minimum(1.0, v_max / np.maximum(speed, 1e-12))
        u = kv * (v_des - v)
        norm = np.linalg.norm(u, axis=1, keepdims=True)
        return u * np.minimum(1.0, a_max / np.maximum(norm, 1e-12))

    return command


@dataclass(frozen=True)
class Flight:
    """``positions`` (T + 1, K, 3) at every tick; ``min_distance_m`` over all pairs and all
    physics sub-steps; ``active_ticks`` (K,); ``infeasible_ticks``."""

    positions: FloatArray
    min_distance_m: float
    active_ticks: FloatArray
    infeasible_ticks: int


def fly(
    p0: FloatArray,
    v0: FloatArray,
    nominal: Nominal,
    params: SeparationParams | None,
    duration_s: float,
    delay_ticks: int = 0,
    lag_s: float = 0.0,
    substeps: int = 5,
) -> Flight:
    """Fly K point masses from ``p0``, ``v0`` (K, 3) for ``duration_s``; every agent hears every
    other, its data ``delay_ticks`` old and extrapolated by velocity (as the neighbours helper
    does). ``params`` None: no filter."""
    p, v = p0.astype(float).copy(), v0.astype(float).copy()
    a = np.zeros_like(p)
    k = len(p)
    others = ~np.eye(k, dtype=bool)
    history = [(p.copy(), v.copy())]
    d_min, active, infeasible = np.inf, np.zeros(k), 0
    for _ in range(round(duration_s / DT_S)):
        u = nominal(p, v)
        if params is not None:
            p_old, v_old = history[max(0, len(history) - 1 - delay_ticks)]
            seen = p_old + v_old * delay_ticks * DT_S
            nb_p, nb_v = np.broadcast_to(seen, (k, k, 3)), np.broadcast_to(v_old, (k, k, 3))
            result = filter_accelerations(p, v, u, nb_p, nb_v, others, params)
            u = result.accel_ned_m_s2
            active += result.active
            infeasible += int(result.infeasible.sum())
        u = realised(u)
        h = DT_S / substeps
        for _ in range(substeps):
            a = u if lag_s == 0 else a + (u - a) * h / lag_s
            v = v + a * h
            p = p + v * h
            gap = np.linalg.norm(p[:, None] - p[None], axis=-1)[others]
            d_min = min(d_min, float(gap.min(initial=np.inf)))
        history.append((p.copy(), v.copy()))
    return Flight(np.array([h[0] for h in history]), d_min, active, infeasible)
