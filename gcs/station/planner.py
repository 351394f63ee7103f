"""Operator commands turned into new segments of the shared descriptor trajectory. Pure.

Every command yields a new plan (``seq + 1``) that agrees with the current one up to ``now_s`` and
then moves smoothly (continuous value, rate and acceleration) to the commanded descriptors, at rest
on arrival, within the flight envelope: speed and acceleration of the centre, heading rate and
acceleration, rate of change of the variances, swarm tilt, spread, and a geofence box that the
whole formation (centre ± 2 spreads) must stay inside along the way. A command that cannot be met
raises :class:`PlanRefused` with the reason and changes nothing (plans are immutable).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from protocols.model.descriptor_vector import (
    CENTRE,
    I_PITCH,
    I_ROLL,
    I_S3,
    I_YAW,
    ORIENTATION,
    SHAPE,
)
from protocols.model.frames import FloatArray
from protocols.model.trajectory import DescriptorTrajectory, Waypoint, quintic_hermite
from protocols.scenario.scenario_file import SafetyConfig

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


def envelope_of(safety: SafetyConfig) -> Envelope:
    """The default envelope with a scenario's ``[safety]``: minimum separation and geofence."""
    fence = (-safety.geofence_m, safety.geofence_m)
    return Envelope(
        fence_north_m=fence,
        fence_east_m=fence,
        fence_altitude_m=(-0.5, safety.ceiling_m),
        min_separation_m=safety.min_separation_m,
    )


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


#: The descriptor groups that move at their own pace: name, rows.
GROUPS: tuple[tuple[str, slice], ...] = (
    ("centre", CENTRE),
    ("orientation", ORIENTATION),
    ("shape", SHAPE),
)


@dataclass(frozen=True)
class Move:
    """A new plan and, per commanded group (``GROUPS`` names), when it arrives (s); groups left
    out of ``arrivals`` keep the course of the old plan."""

    trajectory: DescriptorTrajectory
    arrivals: dict[str, float]

    def describe(self) -> str:
        """``"orientation arrives at t = 30.2 s, shape at t = 28.1 s; centre keeps its course"``"""
        parts = [f"{name} at t = {t:.1f} s" for name, t in self.arrivals.items()]
        text = parts[0].replace(" at ", " arrives at ", 1) + "".join(", " + p for p in parts[1:])
        kept = [name for name, _ in GROUPS if name not in self.arrivals]
        if not parts:
            return "nothing to change: the plan keeps its course"
        if kept:
            text += "; " + " and ".join(kept) + (" keeps" if len(kept) == 1 else " keep")
            text += " its course" if len(kept) == 1 else " their course"
        return text


def _shift(coeffs: FloatArray, s: float) -> FloatArray:
    """Coefficients (..., 6) of ``u -> p(u + s)`` for the polynomial ``p`` of ``coeffs``."""
    n = coeffs.shape[-1]
    basis = np.zeros((n, n))
    for i in range(n):
        for m in range(i + 1):
            basis[i, m] = math.comb(i, m) * s ** (i - m)
    out: FloatArray = coeffs @ basis
    return out


def _piece(plan: DescriptorTrajectory, t_a: float, rows: slice) -> FloatArray:
    """The old plan's rows on the segment starting at ``t_a`` (no old knot inside it), as
    coefficients (rows, 6) in ``tau = t - t_a``; constant after the plan's end."""
    knots = plan.t_knots_s
    if t_a >= plan.end_s:
        out = np.zeros((len(range(9)[rows]), 6))
        out[:, 0] = plan.evaluate(plan.end_s)[0][rows]
        return out
    k = int(np.clip(np.searchsorted(knots, t_a, side="right") - 1, 0, plan.n_segments - 1))
    return _shift(plan.coeffs[k, rows], t_a - float(knots[k]))


def _group_segment(
    state: tuple[FloatArray, FloatArray, FloatArray], goal: FloatArray, t_s: float
) -> FloatArray:
    """The quintic (rows, 6) from the group's state now to rest at ``goal`` in ``t_s``."""
    p0, v0, a0 = state
    zero = np.zeros_like(goal)
    return quintic_hermite(p0, v0, a0, goal, zero, zero, t_s)


def _within(coeffs: FloatArray, t_s: float, v_max: float, acc_max: float) -> str | None:
    """'speed' or 'acceleration' if the group's quintic (rows, 6) breaks its limit, else None."""
    tau = np.linspace(0.0, t_s, _SAMPLES)
    rate = np.stack([np.polyval(np.polyder(c[::-1]), tau) for c in coeffs], axis=1)
    acc = np.stack([np.polyval(np.polyder(c[::-1], 2), tau) for c in coeffs], axis=1)
    if np.linalg.norm(rate, axis=1).max() > v_max * 1.001:
        return "speed"
    if np.linalg.norm(acc, axis=1).max() > acc_max * 1.001:
        return "acceleration"
    return None


def plan_move(
    plan: DescriptorTrajectory,
    now_s: float,
    target: FloatArray,
    env: Envelope,
    duration_s: float | None = None,
) -> Move:
    """A new plan that leaves ``plan`` at ``now_s`` and brings each group of descriptors the
    target changes (centre, orientation, shape: those where ``target`` (9,) differs from where
    the plan is heading) to rest at its target, each in the shortest time its own limits allow
    (a turn or a stretch completes in seconds while the centre keeps the course of ``plan``).

    With ``duration_s`` every changed group takes exactly that long, or PlanRefused if that is
    too fast. The heading turns the short way round. The whole formation must stay in the
    geofence along the new plan (PlanRefused otherwise).
    """
    a0, v0, acc0 = plan.evaluate(now_s)
    goal = np.array(target, dtype=float)
    goal[I_YAW] = a0[I_YAW] + math.remainder(float(goal[I_YAW] - a0[I_YAW]), 2 * math.pi)
    check_target(goal, env)
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise PlanRefused("the duration must be a positive number of seconds")
    heading_to = goal_of(plan, now_s)
    heading_to[I_YAW] = a0[I_YAW] + math.remainder(
        float(heading_to[I_YAW] - a0[I_YAW]), 2 * math.pi
    )
    segments: dict[str, tuple[slice, float, FloatArray]] = {}
    for (name, rows), (_, v_max, acc_max, what) in zip(GROUPS, _limits(env), strict=True):
        if np.allclose(goal[rows], heading_to[rows], rtol=0.0, atol=1e-12):
            continue
        d = float(np.linalg.norm(goal[rows] - a0[rows]))
        t_min = max(
            env.min_duration_s, _PEAK_SPEED * d / v_max, math.sqrt(_PEAK_ACCEL * d / acc_max)
        )
        if duration_s is not None and duration_s < t_min - 1e-9:
            raise PlanRefused(
                f"too fast: this change needs at least {t_min:.1f} s within the "
                f"envelope, {duration_s:g} s was asked"
            )
        t = duration_s if duration_s is not None else t_min
        state = (a0[rows], v0[rows], acc0[rows])
        for _ in range(_MAX_TRIES):
            coeffs = _group_segment(state, goal[rows], t)
            broken = _within(coeffs, t, v_max, acc_max)
            if broken is None:
                break
            if duration_s is not None:
                raise PlanRefused(
                    f"in {duration_s:g} s the move would break the {what} {broken} limit; "
                    "give more time"
                )
            t *= 1.2
        else:
            raise PlanRefused(f"no duration keeps the {name} within the envelope")
        segments[name] = (rows, t, coeffs)
    trajectory = _compose(plan, now_s, goal, segments)
    horizon = max([trajectory.end_s, now_s + env.min_duration_s])
    times = np.linspace(now_s, horizon, _SAMPLES)
    a, _, _ = trajectory.evaluate_many(times)
    for k in (*range(0, _SAMPLES, 10), _SAMPLES - 1):
        _check_fence(a[k], env, when=f" on the way (t = {times[k]:.1f} s)")
    arrivals = {name: now_s + seg[1] for name, seg in segments.items()}
    return Move(trajectory, arrivals)


def _compose(
    plan: DescriptorTrajectory,
    now_s: float,
    goal: FloatArray,
    segments: dict[str, tuple[slice, float, FloatArray]],
) -> DescriptorTrajectory:
    """``plan`` up to ``now_s``; then each changed group on its own quintic (and at rest at its
    goal after it), every other row on the old plan's course."""
    ends = [now_s + t for _, t, _ in segments.values()]
    later = [float(k) for k in plan.t_knots_s if k > now_s + 1e-9]
    knots = sorted({now_s, *ends, *later})
    if len(knots) == 1:
        knots.append(now_s + 1.0)  # nothing left to change: one constant segment
    coeffs = np.zeros((len(knots) - 1, 9, 6))
    for i, (t_a, t_b) in enumerate(itertools.pairwise(knots)):
        for name, rows in GROUPS:
            if name in segments:
                _, t_g, c = segments[name]
                if t_b <= now_s + t_g + 1e-9:
                    coeffs[i, rows] = _shift(c, t_a - now_s)
                else:
                    coeffs[i, rows, 0] = goal[rows]
            else:
                coeffs[i, rows] = _piece(plan, t_a, rows)
    head_knots, head_coeffs = plan._head(now_s)
    return DescriptorTrajectory(
        plan.seq + 1,
        np.concatenate([head_knots, knots]),
        np.concatenate([head_coeffs, coeffs]),
    )


def plan_to(
    plan: DescriptorTrajectory,
    now_s: float,
    target: FloatArray,
    env: Envelope,
    duration_s: float | None = None,
) -> DescriptorTrajectory:
    """The trajectory of :func:`plan_move`."""
    return plan_move(plan, now_s, target, env, duration_s).trajectory


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
    :data:`protocols.wire.plan.LAND_HANDOVER_ALTITUDE_M` (see :mod:`drone_agent.core.flight_phase`).
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
