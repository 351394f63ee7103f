"""When the plan runs: a plan that leaves the ground waits for the swarm to leave it. Pure.

The shared plan ``a_d(t)`` (protocols/model/trajectory.py) is written on the scenario's clock. The
swarm can leave the ground only once its estimates have settled (drone_agent/core/flight_phase.py,
:class:`~drone_agent.core.flight_phase.Readiness`), which takes longer on a larger or sparser radio
graph. A plan that starts climbing before then would be chased: the swarm would leave the
ground towards a plan already metres up and overshoot it. So every runner (``swarm simulate``,
every ``swarm agent``, the ground station and the report) flies the plan on one re-timed clock.

The plan is on the ground where its centre is at most :data:`GROUND_START_M` up (judged at
its knots; before its first knot it rests at its first value, after its last at its last). Each
stretch on the ground has a **departure**: the last knot where it is lowest (the end of a rest,
the start of a climb, the bottom of a landing a ``takeoff`` cut short). The plan's departure at
time ``t`` is that of the last stretch on the ground begun at or before ``t`` (None if none was:
the plan is airborne from its start).

- Before the swarm has taken off, the plan is flown as written until its departure and **held**
  there (the plan's state at that time, its rate included: a plan that moves from its start,
  as the paper's does, is held at its first value with its first rate), however long the
  swarm needs.
- From the **take-off** (the round the swarm's first agent armed, agreed by the agents over their
  consensus messages: :class:`drone_agent.core.flight_phase.TakeoffClock`) the plan runs from there:
  ``shift = max(0, t_takeoff - departure(t_takeoff))`` seconds late.
- A plan airborne from its start, or whose rest on the ground lasts past the take-off, is flown
  as written (shift 0). The operator's plans continue the plan as flown (their history re-timed),
  so they depart at the take-off or later: they are flown as written too, and a ``takeoff`` after
  a landing departs from the landed rest, not from the history before it.

Only the plan is re-timed: the scenario's other events (faults, the end time) keep their times.

A plan written **airborne from its start** (a scenario whose first waypoint is up in the air) is
given a ground start first (:func:`from_the_ground`): the swarm climbs rest to rest from the
ground below the first waypoint, taking :func:`climb_s`, and the written waypoints follow that
much later (:func:`lead_in_s`). Without it the swarm, ready after its warm-up, would leave the
ground towards a plan metres up at once: a 250-drone grid chasing a 3 m step climbed to 57 m, as
the consensus estimate of its centre lagged the climb.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from protocols.model.descriptor_vector import CENTRE, I_PITCH, I_ROLL, SHAPE
from protocols.model.trajectory import DescriptorTrajectory, Waypoint

#: A plan's centre at most this high (m, up) is on the ground: the plan waits there for the
#: swarm's take-off.
GROUND_START_M = 0.5


def climb_s(altitude_m: float) -> float:
    """How long (s) a plan takes to climb rest to rest from the ground to ``altitude_m`` (m up):
    at 0.5 m/s on average, at least 4 s (the generated scenarios' climb; a minimum-jerk climb
    peaks at 15/8 of its average rate)."""
    return max(4.0, 2.0 * abs(altitude_m))


def lead_in_s(first_up_m: float) -> float:
    """How much later (s) a plan whose first waypoint is ``first_up_m`` (m) up is flown: the
    ground start's :func:`climb_s` if it is above :data:`GROUND_START_M`, else 0."""
    return climb_s(first_up_m) if first_up_m > GROUND_START_M else 0.0


def from_the_ground(waypoints: list[Waypoint]) -> list[Waypoint]:
    """``waypoints`` as flown: unchanged if the first is on the ground (its centre at most
    :data:`GROUND_START_M` up); else (module doc) a ground waypoint first, at the first one's time
    (below its centre, level, flat: no roll, pitch or height spread), and every written waypoint
    :func:`climb_s` later, the first one at rest unless it says its own rate and acceleration
    (as it was as the plan's first)."""
    first = waypoints[0]
    late = lead_in_s(-float(first.value[2]))
    if not late:
        return waypoints
    ground = first.value.copy()
    ground[CENTRE.start + 2] = 0.0
    ground[I_ROLL] = ground[I_PITCH] = 0.0
    ground[SHAPE.stop - 1] = 0.0
    zero = np.zeros_like(ground)
    start = Waypoint(first.t_s, ground, zero, zero)
    moved = [
        Waypoint(
            first.t_s + late,
            first.value,
            zero if first.rate is None else first.rate,
            zero if first.accel is None else first.accel,
        )
    ]
    moved += [Waypoint(w.t_s + late, w.value, w.rate, w.accel) for w in waypoints[1:]]
    return [start, *moved]


def tick_time_s(tick: int, control_period_ms: int) -> float:
    """The simulated time (s) of control tick ``tick``, as every runner reads it (the vehicles'
    ``time_boot_ms = tick * control_period_ms``, whole milliseconds)."""
    return tick * control_period_ms / 1000.0


#: Altitudes (m) this close to a stretch's lowest count as lowest (a rest held at one value).
_LEVEL_M = 1e-3

_stretches: weakref.WeakKeyDictionary[DescriptorTrajectory, list[tuple[float, float]]] = (
    weakref.WeakKeyDictionary()
)


def ground_stretches(plan: DescriptorTrajectory) -> list[tuple[float, float]]:
    """The plan's stretches on the ground (module doc), as (begin, departure) times (s), in
    order; the first may begin at -inf."""
    found = _stretches.get(plan)
    if found is not None:
        return found
    knots = plan.t_knots_s.tolist()
    up = (-np.concatenate((plan.coeffs[:, 2, 0], plan.evaluate(plan.end_s)[0][2:3]))).tolist()
    found = []
    k = 0
    while k < len(knots):
        if up[k] > GROUND_START_M:
            k += 1
            continue
        first = k
        while k + 1 < len(knots) and up[k + 1] <= GROUND_START_M:
            k += 1
        lowest = min(up[first : k + 1])
        leaves = max(i for i in range(first, k + 1) if up[i] <= lowest + _LEVEL_M)
        found.append((-math.inf if first == 0 else knots[first], knots[leaves]))
        k += 1
    _stretches[plan] = found
    return found


def departure_s(plan: DescriptorTrajectory, t_s: float) -> float | None:
    """When the plan leaves the ground, as of time ``t_s`` (module doc): the departure of its
    last stretch on the ground begun at or before ``t_s``; None if it is airborne from its
    start."""
    last = None
    for begin, leaves in ground_stretches(plan):
        if begin > t_s:
            break
        last = leaves
    return last


def shift_s(plan: DescriptorTrajectory, takeoff_s: float | None) -> float:
    """How late (s) ``plan`` is flown for a take-off at ``takeoff_s`` (None: not yet)."""
    if takeoff_s is None:
        return 0.0
    leaves = departure_s(plan, takeoff_s)
    return 0.0 if leaves is None else max(0.0, takeoff_s - leaves)


def flown_time_s(plan: DescriptorTrajectory, t_s: float, takeoff_s: float | None) -> float:
    """The plan's own time at simulated time ``t_s``: before the take-off (``takeoff_s`` None)
    the plan is held at its departure; after it, it runs :func:`shift_s` late."""
    if takeoff_s is not None:
        return t_s - shift_s(plan, takeoff_s)
    leaves = departure_s(plan, t_s)
    return t_s if leaves is None else min(t_s, leaves)


def flown_plan(plan: DescriptorTrajectory, takeoff_s: float) -> DescriptorTrajectory:
    """``plan`` as flown with a take-off at ``takeoff_s``: re-timed (its knots moved by
    :func:`shift_s`); what trajectory.json holds and what the report measures against. Before
    the take-off, pass the current time: the plan as held so far."""
    return plan.retimed(shift_s(plan, takeoff_s))


def takeoff_metrics(takeoff_s: float | None, plan: DescriptorTrajectory) -> dict[str, float] | None:
    """The report's ``takeoff`` entry: when the swarm left the ground (s) and how late ``plan``
    is flown for it (s); None if it never left."""
    if takeoff_s is None:
        return None
    return {"t_s": round(takeoff_s, 6), "retimed_by_s": round(shift_s(plan, takeoff_s), 6)}
