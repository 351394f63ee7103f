"""Operator commands as trajectory segments: smooth, within the envelope, refused with a reason."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs.station.planner import (
    Envelope,
    PlanRefused,
    formation_target,
    goal_of,
    hold,
    land,
    plan_move,
    plan_to,
)
from protocols.model.trajectory import DescriptorTrajectory, Waypoint

ENV = Envelope(fence_north_m=(-50.0, 50.0), fence_east_m=(-50.0, 50.0))
HOVER = np.array([0.0, 0.0, -5.0, 0.0, 0.0, 0.0, 9.0, 4.0, 0.0])


def _hover_plan() -> DescriptorTrajectory:
    return DescriptorTrajectory.from_waypoints([Waypoint(0.0, HOVER), Waypoint(10.0, HOVER)])


def _max_rate(plan: DescriptorTrajectory, t0: float, t1: float, rows: slice) -> tuple[float, float]:
    t = np.linspace(t0, t1, 2000)
    _, rate, acc = plan.evaluate_many(t)
    return (
        float(np.linalg.norm(rate[:, rows], axis=1).max()),
        float(np.linalg.norm(acc[:, rows], axis=1).max()),
    )


def test_move_arrives_at_rest_within_limits() -> None:
    plan = _hover_plan()
    target = formation_target(plan, 12.0, centre_ned_m=np.array([20.0, -10.0, -8.0]))
    new = plan_to(plan, 12.0, target, ENV)
    assert new.seq == plan.seq + 1
    a, rate, acc = new.evaluate(new.end_s)
    np.testing.assert_allclose(acc, 0.0, atol=1e-9)
    np.testing.assert_allclose(a, target, atol=1e-9)
    np.testing.assert_allclose(rate, 0.0, atol=1e-9)
    v, accel = _max_rate(new, 12.0, new.end_s, slice(0, 3))
    assert v <= ENV.max_speed_m_s * 1.001 and accel <= ENV.max_accel_m_s2 * 1.001
    assert v > 0.9 * ENV.max_speed_m_s  # and not needlessly slow
    # unchanged before the command
    np.testing.assert_allclose(new.evaluate(11.0)[0], plan.evaluate(11.0)[0])


def test_command_during_a_move_joins_smoothly() -> None:
    plan = plan_to(_hover_plan(), 12.0, HOVER + np.r_[20.0, 0, 0, 0, 0, 0, 0, 0, 0], ENV)
    mid = 12.0 + (plan.end_s - 12.0) / 2
    target = formation_target(plan, mid, heading_deg=90.0)
    new = plan_to(plan, mid, target, ENV)
    for k, (x, y) in enumerate(zip(plan.evaluate(mid), new.evaluate(mid + 1e-9), strict=True)):
        np.testing.assert_allclose(x, y, atol=1e-6, err_msg=f"derivative {k}")
    assert new.evaluate(new.end_s)[0][0] == pytest.approx(20.0)  # keeps the move's goal
    assert new.evaluate(new.end_s)[0][5] == pytest.approx(math.pi / 2)


def test_heading_turns_the_short_way() -> None:
    plan = plan_to(
        _hover_plan(), 12.0, formation_target(_hover_plan(), 12.0, heading_deg=170.0), ENV
    )
    new = plan_to(plan, plan.end_s, formation_target(plan, plan.end_s, heading_deg=-170.0), ENV)
    yaw = new.evaluate(new.end_s)[0][5]
    assert yaw == pytest.approx(math.radians(190.0))


@pytest.mark.parametrize(
    "kwargs,reason",
    [
        ({"centre_ned_m": np.array([48.0, 0.0, -5.0])}, "geofence"),
        ({"centre_ned_m": np.array([0.0, 0.0, -70.0])}, "altitude"),
        ({"spread_m": np.array([20.0, 2.0, 0.0])}, "spread"),
    ],
)
def test_outside_the_envelope_is_refused(kwargs: dict[str, np.ndarray], reason: str) -> None:
    plan = _hover_plan()
    with pytest.raises(PlanRefused, match=reason):
        plan_to(plan, 12.0, formation_target(plan, 12.0, **kwargs), ENV)
    np.testing.assert_allclose(goal_of(plan, 12.0), HOVER)  # nothing changed


def test_too_fast_is_refused_with_the_minimum_time() -> None:
    plan = _hover_plan()
    target = formation_target(plan, 12.0, centre_ned_m=np.array([30.0, 0.0, -5.0]))
    with pytest.raises(PlanRefused, match="at least"):
        plan_to(plan, 12.0, target, ENV, duration_s=3.0)
    slow = plan_to(plan, 12.0, target, ENV, duration_s=60.0)
    assert slow.end_s == pytest.approx(72.0)


def test_hold_comes_to_rest() -> None:
    plan = plan_to(_hover_plan(), 12.0, HOVER + np.r_[30.0, 0, 0, 0, 0, 0, 0, 0, 0], ENV)
    mid = 12.0 + (plan.end_s - 12.0) / 2
    stopped = hold(plan, mid, ENV)
    _, rate, _ = stopped.evaluate(stopped.end_s)
    np.testing.assert_allclose(rate, 0.0, atol=1e-9)
    assert stopped.evaluate(stopped.end_s)[0][0] < 30.0


def test_land_stops_levels_flattens_and_descends_gently_to_the_ground() -> None:
    tilted = HOVER + np.r_[30.0, 0, 0, 0.2, 0.1, 0, 0, 0, 1.0]  # moving north, tilted, thick
    plan = plan_to(_hover_plan(), 12.0, tilted, ENV)
    mid = 12.0 + (plan.end_s - 12.0) / 2
    landing = land(plan, mid, ENV)
    assert landing.seq == plan.seq + 1
    np.testing.assert_allclose(landing.evaluate(mid - 1.0)[0], plan.evaluate(mid - 1.0)[0])
    end, rate, acc = landing.evaluate(landing.end_s)
    assert end[2] == pytest.approx(0.0, abs=1e-9)  # on the ground
    np.testing.assert_allclose(end[[3, 4, 8]], 0.0, atol=1e-9)  # level and flat
    np.testing.assert_allclose(rate, 0.0, atol=1e-9)
    np.testing.assert_allclose(acc, 0.0, atol=1e-9)
    t = np.linspace(mid, landing.end_s, 4000)
    a, rates, accs = landing.evaluate_many(t)
    assert rates[:, 2].max() <= ENV.max_descent_m_s * 1.001  # sink rate (NED z grows)
    assert np.linalg.norm(accs[:, :3], axis=1).max() <= ENV.max_accel_m_s2 * 1.001
    # it stops before it descends: no horizontal motion below 2 m
    low = -a[:, 2] < 2.0
    assert np.abs(rates[low, :2]).max() < 1e-6
    assert -a[:, 2].min() >= -1e-9  # never below the ground


def test_land_is_never_refused_even_outside_the_fence() -> None:
    far = DescriptorTrajectory.from_waypoints(
        [Waypoint(0.0, HOVER + np.r_[80.0, 0, 0, 0, 0, 0, 0, 0, 0])]
    )
    landing = land(far, 3.0, ENV)
    assert landing.evaluate(landing.end_s)[0][2] == pytest.approx(0.0, abs=1e-9)


CRUISE_ENV = Envelope(fence_north_m=(-50.0, 250.0), fence_east_m=(-50.0, 50.0))


def _paper_like_plan() -> DescriptorTrajectory:
    """The centre cruises 1 m/s north from t = 0 to t = 200 s, the formation 4 x 3 m."""
    start = np.array([0.0, 0.0, -5.0, 0.0, 0.0, 0.0, 10.0, 8.0, 0.0])
    cruise = np.r_[1.0, 0, 0, 0, 0, 0, 0, 0, 0]
    return DescriptorTrajectory.from_waypoints(
        [Waypoint(t, start + t * cruise, cruise, np.zeros(9)) for t in (0.0, 100.0, 200.0)]
    )


def test_a_turn_and_a_stretch_arrive_at_their_own_pace_while_the_centre_keeps_its_course() -> None:
    """Found in the paper flight: ``formation --heading-deg 30 --length-m 4`` at t = 23 s was one
    rest-to-rest move of all nine descriptors to the old plan's end, 160 m away: the turn took
    166 s. Now the turn and the stretch each take the time their own limits allow, and the
    centre flies on exactly as before."""
    plan = _paper_like_plan()
    now = 23.0
    target = formation_target(plan, now, heading_deg=30.0, spread_m=np.array([4.0, 8**0.5, 0.0]))
    move = plan_move(plan, now, target, CRUISE_ENV)
    assert set(move.arrivals) == {"orientation", "shape"}
    assert move.arrivals["orientation"] - now < 15.0 and move.arrivals["shape"] - now < 15.0
    text = move.describe()
    assert "orientation arrives at t = " in text and "centre keeps its course" in text, text
    new = move.trajectory
    t = np.linspace(now, 200.0, 500)
    a_new, rate_new, _ = new.evaluate_many(t)
    a_old, rate_old, _ = plan.evaluate_many(t)
    np.testing.assert_allclose(a_new[:, :3], a_old[:, :3], atol=1e-9)  # the centre's course
    np.testing.assert_allclose(rate_new[:, :3], rate_old[:, :3], atol=1e-9)
    after = t >= max(move.arrivals.values())
    np.testing.assert_allclose(a_new[after, 5], math.radians(30.0), atol=1e-9)
    np.testing.assert_allclose(a_new[after, 6], 16.0, atol=1e-9)
    # smooth at the join and within each group's own limits
    for k, (x, y) in enumerate(zip(plan.evaluate(now), new.evaluate(now + 1e-9), strict=True)):
        np.testing.assert_allclose(x, y, atol=1e-6, err_msg=f"derivative {k}")
    turn, turn_acc = _max_rate(new, now, 200.0, slice(3, 6))
    assert turn <= math.radians(ENV.max_yaw_rate_deg_s) * 1.001
    assert turn_acc <= math.radians(ENV.max_yaw_accel_deg_s2) * 1.001
    shape, shape_acc = _max_rate(new, now, 200.0, slice(6, 9))
    assert shape <= ENV.max_variance_rate_m2_s * 1.001
    assert shape_acc <= ENV.max_variance_accel_m2_s2 * 1.001


def test_a_stretch_whose_course_leaves_the_fence_later_is_refused() -> None:
    """The centre's course is checked with the new shape: a formation that fits now but would
    cross the fence as the centre flies on is refused."""
    plan = _paper_like_plan()
    fence = Envelope(fence_north_m=(-50.0, 210.0), fence_east_m=(-50.0, 50.0))
    ok = formation_target(plan, 23.0, spread_m=np.array([4.0, 2.0, 0.0]))
    plan_move(plan, 23.0, ok, fence)
    wide = formation_target(plan, 23.0, spread_m=np.array([10.0, 2.0, 0.0]))
    with pytest.raises(PlanRefused, match="geofence"):
        plan_move(plan, 23.0, wide, fence)
