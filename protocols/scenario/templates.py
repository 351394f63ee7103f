"""The manoeuvre templates of ``swarm scenario new``: waypoints of the scenario file's own fields
(centre NED m, yaw deg, spreads m) for a swarm laid out on the ground. Pure, I/O-free.

Every plan starts the same way: the swarm rests on the ground for the consensus warm-up (the
agents agree on the descriptors before arming, ALGORITHM.md §3 rule 7), then climbs rest to rest
to the altitude. The formation is the layout itself: the start's centre and spreads along north
and east, flat (height spread 0), yaw 0. Where length and width tie (a square grid, a ring: the
heading would be undefined, protocols/model/descriptors.py) the length is commanded 10 % longer, so
that the heading is defined and nobody comes closer than on the ground. After the climb:

- ``hover``: hold the take-off formation;
- ``paper``: the paper's flight style: forward along north at 1 m/s while the width breathes
  (variance +-30 %, one sine period over the flight);
- ``survey``: a lawnmower sweep of the centre: legs of 20 m (or the swarm's length if longer)
  along north, lanes one swarm width (plus a spacing) apart along east, rest at each corner;
- ``turn-and-stretch``: hold 5 s; then in 20 s a 20 m move north with a 30 deg turn and a 15 %
  stretch of the length spread; hold (issue 10's large-swarm flight).

:data:`SESSION_TEMPLATE` (``ground``, not offered by ``swarm scenario new``) is the plan of an
operator session (``swarm up --drones N``): the swarm rests on the ground in its layout and does
not climb; the ground station publishes it as a GROUND plan and the operator's ``swarm takeoff``
starts the flight.

The last waypoint is held to the end. Waypoints carry no rates: the plan through them is
shape-preserving (protocols/model/trajectory.py), so corners are rests and holds are holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from protocols.model.descriptors import covariance
from protocols.model.frames import FloatArray
from protocols.model.plan_timing import climb_s

TEMPLATES = ("hover", "paper", "survey", "turn-and-stretch")
#: The operator session's plan: on the ground, in the layout (``swarm up --drones N``).
SESSION_TEMPLATE = "ground"
#: How long (s) the session's plan lasts; it is held on the ground after it, for ever.
SESSION_PLAN_S = 10.0
#: Length and width spreads closer than this ratio count as a tie (heading undefined).
_TIE_RATIO = 0.1
_TIE_STRETCH = 1.1
_FINAL_HOLD_S = 5.0
_CRUISE_M_S = 0.8  # survey legs: mean speed (peak 1.875x on a rest-to-rest segment)
Vec3 = tuple[float, float, float]


class GeneratorError(ValueError):
    """Options the generator cannot meet; the message starts with the option's name."""


@dataclass(frozen=True)
class PlanRequest:
    """Which template, at what altitude (m; None: the template's default) and for how long (s;
    None: what the template needs plus a hold)."""

    template: str
    altitude_m: float | None = None
    duration_s: float | None = None


@dataclass(frozen=True)
class PlanPoint:
    """One waypoint: time (s), centre (NED m), yaw (deg), spreads (m), and what it is for."""

    t_s: float
    centre_ned_m: Vec3
    yaw_deg: float
    spread_m: Vec3
    note: str = ""


@dataclass(frozen=True)
class Plan:
    """A template's waypoints and when its faults go off: after the climb (``airborne_s``) and in
    the middle of the manoeuvre (``manoeuvre_mid_s``)."""

    points: tuple[PlanPoint, ...]
    duration_s: float
    airborne_s: float
    manoeuvre_mid_s: float
    summary: str


def _start(positions: FloatArray) -> tuple[Vec3, Vec3]:
    """The start's centre (on the ground) and the spreads (m) to fly: the layout's own along
    north and east, the length 10 % longer where they tie, flat."""
    centre, sigma = covariance(positions)
    s_north, s_east = math.sqrt(max(sigma[0, 0], 0.0)), math.sqrt(max(sigma[1, 1], 0.0))
    if abs(s_north - s_east) < _TIE_RATIO * (s_north + s_east):
        s_north = max(s_north, s_east) * _TIE_STRETCH
    return (float(centre[0]), float(centre[1]), 0.0), (s_north, s_east, 0.0)


def build_plan(o: PlanRequest, positions: FloatArray, spacing_m: float, warmup_s: float) -> Plan:
    """The plan of template ``o.template`` for drones starting at ``positions`` (N, 3) NED m,
    ``spacing_m`` apart, after a consensus warm-up of ``warmup_s`` (s) on the ground."""
    if o.template == SESSION_TEMPLATE:
        return _ground(positions, warmup_s)
    default_alt = 5.0 if o.template == "paper" else 3.0
    alt = default_alt if o.altitude_m is None else o.altitude_m
    (n0, e0, _), spread = _start(positions)
    up = warmup_s + climb_s(alt)
    ground = (n0, e0, 0.0)
    head = [
        PlanPoint(0.0, ground, 0.0, spread, "on the ground: consensus warm-up before arming"),
        PlanPoint(warmup_s, ground, 0.0, spread, "warm-up over: arm and climb"),
        PlanPoint(up, (n0, e0, -alt), 0.0, spread, f"at {alt:g} m: take-off done"),
    ]
    builder = {
        "hover": _hover,
        "paper": _paper,
        "survey": _survey,
        "turn-and-stretch": _turn_and_stretch,
    }[o.template]
    return builder(o, head, spread, extent_m=_extent(positions, spacing_m))


def _ground(positions: FloatArray, warmup_s: float) -> Plan:
    """The session's plan: the layout's formation resting on the ground (no climb, no end)."""
    (n0, e0, _), spread = _start(positions)
    ground = (n0, e0, 0.0)
    d = max(SESSION_PLAN_S, warmup_s + 6.0)
    points = (
        PlanPoint(0.0, ground, 0.0, spread, "on the ground: consensus warm-up"),
        PlanPoint(d, ground, 0.0, spread, "on the ground until the operator's swarm takeoff"),
    )
    return Plan(points, d, warmup_s, d, "on the ground, waiting for the operator")


def _extent(positions: FloatArray, spacing_m: float) -> tuple[float, float]:
    """Footprint (m) of the swarm along north and east: its span plus one spacing."""
    span = positions.max(axis=0) - positions.min(axis=0)
    return float(span[0]) + spacing_m, float(span[1]) + spacing_m


def _duration(o: PlanRequest, needed_s: float, default_s: float) -> float:
    if o.duration_s is None:
        return max(needed_s, default_s)
    if o.duration_s < needed_s:
        raise GeneratorError(
            f"duration_s: the {o.template} template needs at least {needed_s:g} s "
            f"with these options, got {o.duration_s:g}"
        )
    return o.duration_s


def _hover(
    o: PlanRequest, head: list[PlanPoint], spread: Vec3, extent_m: tuple[float, float]
) -> Plan:
    up = head[-1].t_s
    d = _duration(o, up + 10.0, up + 20.0)
    top = head[-1]
    end = PlanPoint(d, top.centre_ned_m, 0.0, spread, "hold to the end")
    return Plan((*head, end), d, up, 0.5 * (up + d), "take off and hover")


def _turn_and_stretch(
    o: PlanRequest, head: list[PlanPoint], spread: Vec3, extent_m: tuple[float, float]
) -> Plan:
    up = head[-1].t_s
    n0, e0, z = head[-1].centre_ned_m
    go, there = up + 5.0, up + 25.0
    d = _duration(o, there + _FINAL_HOLD_S, there + 10.0)
    stretched = (spread[0] * 1.15, spread[1], spread[2])
    points = (
        *head,
        PlanPoint(go, (n0, e0, z), 0.0, spread, "hold 5 s, then move"),
        PlanPoint(
            there, (n0 + 20.0, e0, z), 30.0, stretched,
            "20 m north in 20 s, turned 30 deg, length spread +15 %",
        ),
        PlanPoint(d, (n0 + 20.0, e0, z), 30.0, stretched, "hold to the end"),
    )  # fmt: skip
    return Plan(points, d, up, 0.5 * (go + there), "take off, move 20 m with a turn and stretch")


def _paper(
    o: PlanRequest, head: list[PlanPoint], spread: Vec3, extent_m: tuple[float, float]
) -> Plan:
    up = head[-1].t_s
    n0, e0, z = head[-1].centre_ned_m
    d = _duration(o, up + 20.0, 120.0)
    cruise_end = d - _FINAL_HOLD_S
    span = cruise_end - up
    points = list(head)
    steps = max(2, math.ceil(span / 5.0))
    for k in range(1, steps + 1):
        t = up + span * k / steps
        phase = math.sin(2.0 * math.pi * (t - up) / span)
        width = spread[1] * math.sqrt(1.0 + 0.3 * phase)
        note = "forward at 1 m/s, width breathing" if k == 1 else ""
        points.append(PlanPoint(t, (n0 + (t - up), e0, z), 0.0, (spread[0], width, 0.0), note))
    points.append(PlanPoint(d, points[-1].centre_ned_m, 0.0, points[-1].spread_m, "hold"))
    return Plan(tuple(points), d, up, 0.5 * (up + cruise_end), "paper-style forward flight")


def _survey(
    o: PlanRequest, head: list[PlanPoint], spread: Vec3, extent_m: tuple[float, float]
) -> Plan:
    up = head[-1].t_s
    n0, e0, z = head[-1].centre_ned_m
    leg = max(20.0, math.ceil(extent_m[0]))
    lane = round(extent_m[1], 1)
    t_leg = float(max(8, math.ceil(leg / _CRUISE_M_S)))
    t_lane = float(max(5, math.ceil(lane / _CRUISE_M_S)))
    needed = up + 2 * t_leg + t_lane + _FINAL_HOLD_S
    d = _duration(o, needed, up + 4 * t_leg + 3 * t_lane + _FINAL_HOLD_S)
    legs = 1 + int((d - _FINAL_HOLD_S - up - t_leg) // (t_leg + t_lane))
    points = list(head)
    t, north, east = up, n0, e0
    for k in range(legs):
        if k:
            t, east = t + t_lane, east + lane
            points.append(PlanPoint(t, (north, east, z), 0.0, spread, f"next lane, {lane:.1f} m"))
        t, north = t + t_leg, (n0 + leg if k % 2 == 0 else n0)
        points.append(PlanPoint(t, (north, east, z), 0.0, spread, f"leg {k + 1}: {leg:.0f} m"))
    points.append(PlanPoint(d, (north, east, z), 0.0, spread, "hold to the end"))
    mid = 0.5 * (up + points[-2].t_s)
    return Plan(tuple(points), d, up, mid, f"lawnmower survey, {legs} legs")
