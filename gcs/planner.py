"""Operator commands turned into new segments of the shared descriptor trajectory. Pure.

Every command yields a new plan (``seq + 1``) that agrees with the current one up to ``now_s`` and
then moves smoothly (continuous value, rate and acceleration) to the commanded descriptors, at rest
on arrival, within the flight envelope: speed and acceleration of the centre, heading rate and
acceleration, rate of change of the variances, swarm tilt, spread, and a geofence box that the
whole formation (centre ± 2 spreads) must stay inside along the way. A command that cannot be met
raises :class:`PlanRefused` with the reason and changes nothing (plans are immutable).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocols.descriptor_vector import (
    CENTRE,
    I_PITCH,
    I_ROLL,
    I_S3,
    I_YAW,
    ORIENTATION,
    SHAPE,
)
from protocols.frames import FloatArray
from protocols.trajectory import DescriptorTrajectory, Waypoint

#: Peak speed and acceleration of a rest-to-rest minimum-jerk quintic over distance D and time T
#: are 1.875 D/T and 5.7735 D/T^2.
_PEAK_SPEED, _PEAK_ACCEL = 1.875, 5.7735
_SAMPLES = 200
_MAX_TRIES = 30


class PlanRefused(ValueError):
    """A command the envelope does not allow; ``str(exc)`` says why."""


@dataclass(frozen=True)
class Envelope:
    """Limits of what the swarm may be commanded to do (SI units, angles in degrees).

    The geofence bounds north and east (m) and altitude (m, up) of the whole formation, taken as
    the centre ± 2 spreads along each world axis. ``max_descent_m_s``: peak sink rate of the
    centre when landing.
    """

    max_speed_m_s: float = 2.0
    max_accel_m_s2: float = 1.0
    max_yaw_rate_deg_s: float = 20.0
    max_yaw_accel_deg_s2: float = 10.0
    max_variance_rate_m2_s: float = 2.0
    max_variance_accel_m2_s2: float = 1.0
    max_tilt_deg: float = 30.0
    max_spread_m: float = 15.0
    fence_north_m: tuple[float, float] = (-1000.0, 1000.0)
    fence_east_m: tuple[float, float] = (-1000.0, 1000.0)
    fence_altitude_m: tuple[float, float] = (-0.5, 60.0)
    min_duration_s: float = 1.0
    max_descent_m_s: float = 1.0
    min_separation_m: float = 1.0


def _limits(env: Envelope) -> list[tuple[slice, float, float, str]]:
    """(rows, speed limit, accel limit, name) for each group of descriptors."""
    return [
        (CENTRE, env.max_speed_m_s, env.max_accel_m_s2, "centre speed"),
        (
            ORIENTATION,
            math.radians(env.max_yaw_rate_deg_s),
            math.radians(env.max_yaw_accel_deg_s2),
            "turn rate",
        ),
        (SHAPE, env.max_variance_rate_m2_s, env.max_variance_accel_m2_s2, "shape rate"),
    ]


def check_target(a: FloatArray, env: Envelope) -> None:
    """PlanRefused unless the descriptors ``a`` (9,) are inside the envelope and the fence."""
    if not np.all(np.isfinite(a)):
        raise PlanRefused("the command has a value that is not a finite number")
    tilt = math.degrees(max(abs(float(a[I_ROLL])), abs(float(a[I_PITCH]))))
    if tilt > env.max_tilt_deg:
        raise PlanRefused(f"swarm tilt {tilt:.0f} deg exceeds the limit of {env.max_tilt_deg:g}")
    variances = a[SHAPE]
    if np.any(variances < 0):
        raise PlanRefused("a spread must not be negative")
    spread = np.sqrt(np.maximum(variances, 0.0))
    if np.any(spread > env.max_spread_m + 1e-9):
        raise PlanRefused(
            f"spread {spread.max():.1f} m exceeds the limit of {env.max_spread_m:g} m"
        )
    _check_fence(a, env)


def _check_fence(a: FloatArray, env: Envelope, when: str = "") -> None:
    reach = 2.0 * float(np.sqrt(max(float(a[SHAPE].max()), 0.0)))
    north, east, alt = float(a[0]), float(a[1]), -float(a[2])
    for name, value, (lo, hi) in (
        ("north", north, env.fence_north_m),
        ("east", east, env.fence_east_m),
    ):
        if value - reach < lo or value + reach > hi:
            raise PlanRefused(
                f"outside the geofence{when}: formation reaches {name} "
                f"{value - reach:.1f}..{value + reach:.1f} m, fence is {lo:g}..{hi:g} m"
            )
    height = 2.0 * float(np.sqrt(max(float(a[SHAPE][2]), 0.0)))
    lo, hi = env.fence_altitude_m
    if alt - height < lo or alt + height > hi:
        raise PlanRefused(
            f"outside the geofence{when}: altitude {alt:.1f} m (± {height:.1f}) "
            f"is not within {lo:g}..{hi:g} m"
        )


def _min_duration(a0: FloatArray, a1: FloatArray, env: Envelope) -> float:
    """Shortest rest-to-rest duration (s) that keeps each group within its limits."""
    t = env.min_duration_s
    for rows, v_max, acc_max, _ in _limits(env):
        d = float(np.linalg.norm(a1[rows] - a0[rows]))
        if d > 0:
            t = max(t, _PEAK_SPEED * d / v_max, math.sqrt(_PEAK_ACCEL * d / acc_max))
    return t


def _rate_violation(plan: DescriptorTrajectory, t0: float, t1: float, env: Envelope) -> str | None:
    """The first speed or acceleration limit the plan breaks on [t0, t1], or None."""
    t = np.linspace(t0, t1, _SAMPLES)
    _, rate, acc = plan.evaluate_many(t)
    for rows, v_max, acc_max, name in _limits(env):
        if np.linalg.norm(rate[:, rows], axis=1).max() > v_max * 1.001:
            return f"{name} limit"
        if np.linalg.norm(acc[:, rows], axis=1).max() > acc_max * 1.001:
            return f"{name} acceleration limit"
    return None


def _violation(plan: DescriptorTrajectory, t0: float, t1: float, env: Envelope) -> str | None:
    """The first limit the plan breaks on [t0, t1], or None."""
    broken = _rate_violation(plan, t0, t1, env)
    if broken is not None:
        return broken
    t = np.linspace(t0, t1, _SAMPLES)
    a, _, _ = plan.evaluate_many(t)
    for k in range(0, _SAMPLES, 10):
        _check_fence(a[k], env, when=f" on the way (t = {t[k]:.1f} s)")
    return None


def plan_to(
    plan: DescriptorTrajectory,
    now_s: float,
    target: FloatArray,
    env: Envelope,
    duration_s: float | None = None,
) -> DescriptorTrajectory:
    """A new plan that leaves ``plan`` at ``now_s`` and arrives at rest at ``target`` (9,).

    Without ``duration_s`` the move takes the shortest time within the envelope; with it, exactly
    that long, or PlanRefused if that is too fast. The heading turns the short way round.
    """
    a0, _, _ = plan.evaluate(now_s)
    goal = np.array(target, dtype=float)
    goal[I_YAW] = a0[I_YAW] + math.remainder(float(goal[I_YAW] - a0[I_YAW]), 2 * math.pi)
    check_target(goal, env)
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise PlanRefused("the duration must be a positive number of seconds")
    t_min = _min_duration(a0, goal, env)
    if duration_s is not None and duration_s < t_min - 1e-9:
        raise PlanRefused(
            f"too fast: this change needs at least {t_min:.1f} s within the "
            f"envelope, {duration_s:g} s was asked"
        )
    t = duration_s if duration_s is not None else t_min
    zero = np.zeros(9)
    for _ in range(_MAX_TRIES):
        candidate = plan.append([Waypoint(now_s + t, goal, zero, zero)], t_start_s=now_s)
        broken = _violation(candidate, now_s, now_s + t, env)
        if broken is None:
            return candidate
        if duration_s is not None:
            raise PlanRefused(
                f"in {duration_s:g} s the move would break the {broken}; give more time"
            )
        t *= 1.2
    raise PlanRefused(f"no duration keeps the move within the envelope ({broken})")


def goal_of(plan: DescriptorTrajectory, now_s: float) -> FloatArray:
    """Where the plan is heading: its value at its end (or now, if it has ended)."""
    return plan.evaluate(max(now_s, plan.end_s))[0].copy()


def formation_target(
    plan: DescriptorTrajectory,
    now_s: float,
    centre_ned_m: FloatArray | None = None,
    heading_deg: float | None = None,
    spread_m: FloatArray | None = None,
) -> FloatArray:
    """The plan's goal with the given parts replaced (spread in metres: variance = spread^2)."""
    goal = goal_of(plan, now_s)
    if centre_ned_m is not None:
        goal[CENTRE] = centre_ned_m
    if heading_deg is not None:
        goal[I_YAW] = math.radians(heading_deg)
    if spread_m is not None:
        spread = np.asarray(spread_m, dtype=float)
        if np.any(spread < 0):
            raise PlanRefused("a spread must not be negative")
        goal[SHAPE] = np.square(spread)
    return goal


def _stop(plan: DescriptorTrajectory, now_s: float, env: Envelope) -> tuple[FloatArray, float]:
    """Where the plan can come to rest from ``now_s`` as soon as the envelope allows, and how
    long that takes (s): each group brakes at its acceleration limit."""
    a0, rate, _ = plan.evaluate(now_s)
    t = env.min_duration_s
    for rows, _, acc_max, _ in _limits(env):
        t = max(t, 2.0 * float(np.linalg.norm(rate[rows])) / acc_max)
    return a0 + rate * t / 2.0, t


def hold(plan: DescriptorTrajectory, now_s: float, env: Envelope) -> DescriptorTrajectory:
    """Stop where the swarm can: come to rest as soon as the envelope allows."""
    goal, t = _stop(plan, now_s, env)
    zero = np.zeros(9)
    return plan.append([Waypoint(now_s + t, goal, zero, zero)], t_start_s=now_s)


def land(plan: DescriptorTrajectory, now_s: float, env: Envelope) -> DescriptorTrajectory:
    """The landing plan: come to rest over the ground where the swarm can stop, level (roll and
    pitch 0) and flat (height variance 0), then lower the centre straight down to altitude 0
    with a peak sink rate of ``env.max_descent_m_s``, at rest on the ground.

    Never refused: the geofence is not checked (landing is how a swarm leaves it); the durations
    are stretched until the speed and acceleration limits hold. The agents follow the formation
    down and hand each vehicle to its autopilot's LAND mode once the commanded altitude is below
    :data:`protocols.wire_plan.LAND_HANDOVER_ALTITUDE_M` (see :mod:`drone_agent.flight_phase`).
    """
    a0, _, _ = plan.evaluate(now_s)
    stop, t_stop = _stop(plan, now_s, env)
    stop[I_ROLL] = stop[I_PITCH] = 0.0
    stop[I_S3] = 0.0  # the height variance: every drone at one altitude
    t_stop = max(t_stop, _min_duration(a0, stop, env))
    ground = stop.copy()
    altitude = max(-float(stop[2]), 0.0)
    ground[2] = 0.0
    t_down = max(
        env.min_duration_s,
        _PEAK_SPEED * altitude / env.max_descent_m_s,
        math.sqrt(_PEAK_ACCEL * altitude / env.max_accel_m_s2),
    )
    zero = np.zeros(9)
    for _ in range(_MAX_TRIES):
        t1 = now_s + t_stop
        candidate = plan.append(
            [Waypoint(t1, stop, zero, zero), Waypoint(t1 + t_down, ground, zero, zero)],
            t_start_s=now_s,
        )
        if _rate_violation(candidate, now_s, t1, env) is None:
            return candidate
        t_stop *= 1.2
    return candidate  # still a smooth descent: better late than refused
