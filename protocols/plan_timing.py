"""When the plan runs: a plan that starts on the ground waits for the swarm to leave it. Pure.

The shared plan ``a_d(t)`` (protocols/trajectory.py) is written on the scenario's clock. The swarm
can leave the ground only once its estimates have settled (drone_agent/flight_phase.py,
:class:`~drone_agent.flight_phase.Readiness`), which takes longer on a larger or sparser radio
graph. A plan that starts climbing before then would be chased: the swarm would leave the
ground towards a plan already metres up and overshoot it. So every runner (``swarm simulate``,
every ``swarm agent``, the ground station and the report) flies the plan on one re-timed clock:

- a plan that **starts on the ground** (its centre at most :data:`GROUND_START_M` up at its first
  knot) is held at the end of its initial rest (``first_motion_s``: the plan's first value, at
  rest) until the swarm takes off;
- from the **take-off round** (the round the swarm's first agent armed, agreed by the agents
  over their consensus messages: :class:`drone_agent.flight_phase.TakeoffClock`), the plan's
  time runs from there: it is flown ``shift = max(0, t_takeoff - first_motion_s)`` seconds late;
- a plan that starts airborne, or whose initial rest lasts past the take-off, is flown as
  written (shift 0). Plans published while the swarm flies (operator commands) start after the
  take-off: they are flown as written.

Only the plan is re-timed: the scenario's other events (faults, the end time) keep their times.
"""

from __future__ import annotations

from protocols.trajectory import DescriptorTrajectory

#: A plan whose centre starts at most this high (m, up) starts on the ground: it waits for the
#: swarm's take-off.
GROUND_START_M = 0.5


def tick_time_s(tick: int, control_period_ms: int) -> float:
    """The simulated time (s) of control tick ``tick``, as every runner reads it (the vehicles'
    ``time_boot_ms = tick * control_period_ms``, whole milliseconds)."""
    return tick * control_period_ms / 1000.0


def hold_end_s(plan: DescriptorTrajectory) -> float | None:
    """Until when a plan that starts on the ground is held for the take-off (its first motion,
    s); None for a plan that starts airborne (never held)."""
    if -float(plan.coeffs[0, 2, 0]) > GROUND_START_M:
        return None
    return plan.first_motion_s


def shift_s(plan: DescriptorTrajectory, takeoff_s: float | None) -> float:
    """How late (s) ``plan`` is flown for a take-off at ``takeoff_s`` (None: not yet)."""
    hold = hold_end_s(plan)
    if hold is None or takeoff_s is None:
        return 0.0
    return max(0.0, takeoff_s - hold)


def flown_time_s(plan: DescriptorTrajectory, t_s: float, takeoff_s: float | None) -> float:
    """The plan's own time at simulated time ``t_s``: before the take-off (``takeoff_s`` None)
    a plan that starts on the ground is held at the end of its initial rest; after it, the plan
    runs :func:`shift_s` late."""
    hold = hold_end_s(plan)
    if hold is None:
        return t_s
    if takeoff_s is None:
        return min(t_s, hold)
    return t_s - max(0.0, takeoff_s - hold)


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
