"""The plan's clock (protocols/model/plan_timing.py): a plan that starts on the ground is held until
the swarm takes off and flown from there; one that starts airborne, or rests past the take-off,
is flown as written; a scenario's plan written in the air gets a ground start first."""

from __future__ import annotations

import numpy as np
import pytest

from protocols.model.plan_timing import (
    climb_s,
    departure_s,
    flown_plan,
    flown_time_s,
    from_the_ground,
    ground_stretches,
    shift_s,
    tick_time_s,
)
from protocols.model.trajectory import DescriptorTrajectory, Waypoint


def _plan(*points: tuple[float, float]) -> DescriptorTrajectory:
    """Waypoints (t_s, altitude m) of a centre over (0, 0), spreads 1 m^2."""
    return DescriptorTrajectory.from_waypoints(
        [Waypoint(t, [0.0, 0.0, -alt, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0]) for t, alt in points]
    )


def test_a_climb_from_the_ground_waits_for_the_take_off() -> None:
    climb = _plan((0.0, 0.0), (10.0, 5.0))
    assert departure_s(climb, 0.0) == 0.0 and departure_s(climb, 7.0) == 0.0
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
    assert departure_s(rest, 0.0) == 4.0 and departure_s(rest, 6.0) == 4.0
    assert flown_time_s(rest, 2.0, None) == 2.0  # inside the rest: as written
    assert flown_time_s(rest, 6.0, None) == 4.0  # past it, not taken off: held
    assert shift_s(rest, 3.0) == 0.0  # left during the rest: on time
    assert shift_s(rest, 4.5) == 0.5
    assert flown_time_s(rest, 9.5, 4.5) == 9.0


def test_an_airborne_plan_is_flown_as_written() -> None:
    hover = _plan((0.0, 3.0), (10.0, 3.0), (20.0, 6.0))
    assert departure_s(hover, 5.0) is None and ground_stretches(hover) == []
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


def test_a_takeoff_after_a_landing_departs_from_the_landed_rest() -> None:
    """A plan that flew, landed and rests on the ground, then climbs again (an operator's
    ``takeoff`` after ``land``: the history is kept): the swarm, landed, is held at the new
    departure, not sent back to the history's first one."""
    again = _plan((0.0, 0.0), (10.0, 5.0), (30.0, 5.0), (40.0, 0.0), (60.0, 0.0), (66.0, 3.0))
    assert ground_stretches(again) == [(-np.inf, 0.0), (40.0, 60.0)]
    assert departure_s(again, 50.0) == 60.0
    assert flown_time_s(again, 50.0, None) == 50.0  # on the ground, at rest: as written
    assert flown_time_s(again, 61.0, None) == 60.0  # not left yet: held at the departure
    assert shift_s(again, 61.5) == 1.5
    # while the first flight's take-off (3 s) still holds, the plan is flown as written
    assert shift_s(flown_plan(again, 3.0), 3.0) == 0.0


def test_a_takeoff_that_cuts_a_landing_short_departs_from_its_bottom() -> None:
    """The swarm is down before its landing plan is (the autopilots land the last metre): a
    ``takeoff`` then turns the plan's final approach into a climb. It departs from that bottom,
    not from the start of the history."""
    cut = _plan((0.0, 0.0), (10.0, 5.0), (30.0, 5.0), (40.0, 0.3), (41.0, 0.05), (47.0, 3.0))
    assert ground_stretches(cut) == [(-np.inf, 0.0), (40.0, 41.0)]
    assert flown_time_s(cut, 42.0, None) == 41.0
    assert shift_s(cut, 41.2) == pytest.approx(0.2)


def test_a_plan_written_in_the_air_gets_a_ground_start() -> None:
    """from_the_ground: a plan whose first waypoint is up in the air climbs there from the
    ground below it first (level, flat), rest to rest, in climb_s; the written waypoints follow
    that much later, unchanged (the first at rest, or at its own rate); one written on the
    ground is left as it is."""
    tilted = [0.0, 0.0, -6.0, 0.1, 0.2, 0.3, 4.0, 1.0, 0.5]
    moving = Waypoint(0.0, tilted, rate=[1.0, 0, 0, 0, 0, 0, 0, 0, 0])
    later = Waypoint(10.0, [10.0, 0.0, -6.0, 0.1, 0.2, 0.3, 4.0, 1.0, 0.5])
    flown = from_the_ground([moving, later])
    assert climb_s(6.0) == 12.0 and climb_s(1.0) == 4.0
    assert [w.t_s for w in flown] == [0.0, 12.0, 22.0]
    ground = flown[0]
    assert ground.value.tolist() == [0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 4.0, 1.0, 0.0]
    assert not ground.rate.any() and not ground.accel.any()
    assert flown[1].value.tolist() == tilted and flown[1].rate.tolist()[0] == 1.0
    plan = DescriptorTrajectory.from_waypoints(flown)
    written = DescriptorTrajectory.from_waypoints([moving, later])
    for t in (0.0, 3.3, 7.0, 10.0):
        np.testing.assert_allclose(plan.evaluate(t + 12.0)[0], written.evaluate(t)[0], atol=1e-12)
    up = -plan.evaluate_many(np.linspace(0.0, 12.0, 121))[0][:, 2]
    assert up[0] == 0.0 and np.all(np.diff(up) >= 0.0) and up.max() == pytest.approx(6.0)
    on_the_ground = [Waypoint(0.0, [0, 0, -0.4, 0, 0, 0, 1, 1, 0]), later]
    assert from_the_ground(on_the_ground) is on_the_ground
