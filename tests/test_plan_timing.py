"""The plan's clock (protocols/plan_timing.py): a plan that starts on the ground is held until
the swarm takes off and flown from there; one that starts airborne, or rests past the take-off,
is flown as written."""

from __future__ import annotations

import numpy as np

from protocols.plan_timing import flown_plan, flown_time_s, hold_end_s, shift_s, tick_time_s
from protocols.trajectory import DescriptorTrajectory, Waypoint


def _plan(*points: tuple[float, float]) -> DescriptorTrajectory:
    """Waypoints (t_s, altitude m) of a centre over (0, 0), spreads 1 m^2."""
    return DescriptorTrajectory.from_waypoints(
        [Waypoint(t, [0.0, 0.0, -alt, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0]) for t, alt in points]
    )


def test_a_climb_from_the_ground_waits_for_the_take_off() -> None:
    climb = _plan((0.0, 0.0), (10.0, 5.0))
    assert hold_end_s(climb) == 0.0
    # before the take-off: held at its start, whatever the time
    assert flown_time_s(climb, 7.0, None) == 0.0
    # after a take-off at 10.48 s: flown 10.48 s late
    assert shift_s(climb, 10.48) == 10.48
    assert flown_time_s(climb, 15.48, 10.48) == 5.0
    a, rate, _ = climb.evaluate(flown_time_s(climb, 10.48, 10.48))
    assert a[2] == 0.0 and not rate.any()  # it leaves the ground at rest
    # the plan as flown (trajectory.json) is the same plan, its knots moved
    late = flown_plan(climb, 10.48)
    assert late.t_knots_s.tolist() == [10.48, 20.48] and late.seq == climb.seq
    t = np.linspace(0.0, 30.0, 301)
    expected = np.array([climb.evaluate(flown_time_s(climb, x, 10.48))[0] for x in t])
    assert np.allclose(late.evaluate_many(t)[0], expected, atol=1e-12)


def test_a_rest_on_the_ground_is_held_only_past_its_end() -> None:
    rest = _plan((0.0, 0.0), (4.0, 0.0), (14.0, 5.0))
    assert rest.first_motion_s == 4.0 and hold_end_s(rest) == 4.0
    assert flown_time_s(rest, 2.0, None) == 2.0  # inside the rest: as written
    assert flown_time_s(rest, 6.0, None) == 4.0  # past it, not taken off: held
    assert shift_s(rest, 3.0) == 0.0  # left during the rest: on time
    assert shift_s(rest, 4.5) == 0.5
    assert flown_time_s(rest, 9.5, 4.5) == 9.0


def test_an_airborne_plan_is_flown_as_written() -> None:
    hover = _plan((0.0, 3.0), (10.0, 3.0), (20.0, 6.0))
    assert hold_end_s(hover) is None
    assert shift_s(hover, 12.0) == 0.0
    assert flown_time_s(hover, 7.0, None) == 7.0 and flown_time_s(hover, 7.0, 5.0) == 7.0
    assert flown_plan(hover, 12.0) is hover


def test_a_plan_published_after_the_take_off_is_flown_as_written() -> None:
    """An operator's plan continues the plan as flown (its history re-timed): it first moves at
    or after the take-off, so it is not shifted again."""
    climb = _plan((0.0, 0.0), (10.0, 5.0))
    takeoff_s = tick_time_s(524, 20)
    flown = flown_plan(climb, takeoff_s)
    later = flown.append([Waypoint(30.0, [0.0, 0.0, -6.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0])])
    assert shift_s(later, takeoff_s) == 0.0
    assert flown_time_s(later, 25.0, takeoff_s) == 25.0
