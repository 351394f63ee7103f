"""The descriptor trajectory: quintic Hermite segments, holds, validation and append."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.model.trajectory import (
    DescriptorTrajectory,
    Waypoint,
    quintic_hermite,
    rest_to_rest_segment,
)

ZERO = np.zeros(9)


def _left_limit(traj: DescriptorTrajectory, t: float) -> tuple[np.ndarray, ...]:
    """State just before ``t`` (one ulp), i.e. the end of the segment that ends at ``t``."""
    return traj.evaluate(float(np.nextafter(t, -math.inf)))


def _close(x: np.ndarray, y: np.ndarray, rel: float = 1e-7) -> None:
    scale = max(1.0, float(np.abs(x).max()), float(np.abs(y).max()))
    np.testing.assert_allclose(x, y, rtol=0, atol=rel * scale)


@st.composite
def waypoint_lists(draw: st.DrawFn, min_size: int = 1) -> list[Waypoint]:
    n = draw(st.integers(min_size, 6))
    gaps = draw(st.lists(st.floats(0.2, 10.0), min_size=n, max_size=n))
    t0 = draw(st.floats(-5.0, 50.0))
    times = t0 + np.cumsum(gaps)
    vec = st.lists(st.floats(-100.0, 100.0), min_size=9, max_size=9).map(np.array)
    small = st.lists(st.floats(-10.0, 10.0), min_size=9, max_size=9).map(np.array)
    return [
        Waypoint(float(t), draw(vec), draw(st.none() | small), draw(st.none() | small))
        for t in times
    ]


def test_quintic_hermite_matches_both_ends() -> None:
    rng = np.random.default_rng(1)
    p0, v0, a0, p1, v1, a1 = rng.normal(size=(6, 9))
    h = 1.7
    c = quintic_hermite(p0, v0, a0, p1, v1, a1, h)
    n = np.arange(6)
    at_h = c @ h**n
    rate_h = c[:, 1:] @ (n[1:] * h ** (n[1:] - 1))
    acc_h = c[:, 2:] @ (n[2:] * (n[2:] - 1) * h ** (n[2:] - 2))
    np.testing.assert_allclose(c[:, 0], p0)
    np.testing.assert_allclose(c[:, 1], v0)
    np.testing.assert_allclose(2 * c[:, 2], a0)
    np.testing.assert_allclose(at_h, p1, atol=1e-12)
    np.testing.assert_allclose(rate_h, v1, atol=1e-12)
    np.testing.assert_allclose(acc_h, a1, atol=1e-12)


def test_rest_to_rest_is_minimum_jerk() -> None:
    a0 = np.arange(9.0)
    a1 = a0 + np.linspace(-3.0, 5.0, 9)
    traj = rest_to_rest_segment(2.0, a0, 6.0, a1)
    t = np.linspace(2.0, 6.0, 41)
    u = ((t - 2.0) / 4.0)[:, None]
    d = a1 - a0
    a, a_dot, a_ddot = traj.evaluate_many(t)
    np.testing.assert_allclose(a, a0 + d * (10 * u**3 - 15 * u**4 + 6 * u**5), atol=1e-12)
    np.testing.assert_allclose(a_dot, d * (30 * u**2 - 60 * u**3 + 30 * u**4) / 4.0, atol=1e-12)
    np.testing.assert_allclose(a_ddot, d * (60 * u - 180 * u**2 + 120 * u**3) / 16.0, atol=1e-12)


def test_two_bare_waypoints_are_rest_to_rest() -> None:
    a1 = np.linspace(1.0, 9.0, 9)
    bare = DescriptorTrajectory.from_waypoints([Waypoint(0.0, ZERO), Waypoint(3.0, a1)])
    explicit = rest_to_rest_segment(0.0, ZERO, 3.0, a1)
    np.testing.assert_allclose(bare.coeffs, explicit.coeffs, atol=1e-12)


def test_reproduces_a_quintic_exactly() -> None:
    rng = np.random.default_rng(7)
    c = rng.normal(size=(9, 6))
    n = np.arange(6)

    def poly(t: float, k: int) -> np.ndarray:
        factor = np.array([math.perm(int(m), k) if m >= k else 0 for m in n], dtype=float)
        return c @ (factor * t ** np.maximum(n - k, 0))

    knots = [0.0, 0.7, 1.1, 2.5, 4.0]
    traj = DescriptorTrajectory.from_waypoints(
        [Waypoint(t, poly(t, 0), poly(t, 1), poly(t, 2)) for t in knots]
    )
    for t in np.linspace(0.0, 4.0, 57):
        a, a_dot, a_ddot = traj.evaluate(t)
        np.testing.assert_allclose(a, poly(t, 0), atol=1e-9)
        np.testing.assert_allclose(a_dot, poly(t, 1), atol=1e-9)
        np.testing.assert_allclose(a_ddot, poly(t, 2), atol=1e-8)


def test_holds_before_start_and_after_end() -> None:
    first, last = np.full(9, 1.0), np.full(9, -2.0)
    traj = DescriptorTrajectory.from_waypoints(
        [Waypoint(1.0, first, np.full(9, 0.5)), Waypoint(4.0, last, np.full(9, 0.3))]
    )
    for t, value in ((-10.0, first), (0.999, first), (4.001, last), (1e6, last)):
        a, a_dot, a_ddot = traj.evaluate(t)
        np.testing.assert_allclose(a, value, atol=1e-12)
        assert not a_dot.any() and not a_ddot.any()
    # At the knots themselves the segment's own rate applies.
    np.testing.assert_allclose(traj.evaluate(1.0)[1], 0.5)
    np.testing.assert_allclose(traj.evaluate(4.0)[1], 0.3, atol=1e-12)
    assert (traj.start_s, traj.end_s, traj.n_segments) == (1.0, 4.0, 1)


def test_single_waypoint_is_a_constant_hold() -> None:
    value = np.arange(9.0)
    traj = DescriptorTrajectory.from_waypoints([Waypoint(5.0, value, np.ones(9))], seq=3)
    a, a_dot, a_ddot = traj.evaluate_many(np.array([0.0, 5.0, 5.5, 100.0]))
    np.testing.assert_array_equal(a, np.tile(value, (4, 1)))
    assert not a_dot.any() and not a_ddot.any()
    assert traj.seq == 3 and traj.start_s == 5.0


def test_rate_is_the_derivative_of_the_value() -> None:
    rng = np.random.default_rng(3)
    wps = [Waypoint(t, rng.normal(size=9)) for t in (0.0, 1.0, 2.5, 3.0, 6.0)]
    traj = DescriptorTrajectory.from_waypoints(wps)
    t = np.linspace(0.01, 5.99, 300)
    eps = 1e-5
    a_plus, rate_plus, _ = traj.evaluate_many(t + eps)
    a_minus, rate_minus, _ = traj.evaluate_many(t - eps)
    _, rate, accel = traj.evaluate_many(t)
    np.testing.assert_allclose((a_plus - a_minus) / (2 * eps), rate, atol=1e-6)
    np.testing.assert_allclose((rate_plus - rate_minus) / (2 * eps), accel, atol=1e-5)


@settings(max_examples=60, deadline=None)
@given(waypoint_lists())
def test_passes_through_waypoints_and_is_c2_at_knots(wps: list[Waypoint]) -> None:
    traj = DescriptorTrajectory.from_waypoints(wps)
    for k, wp in enumerate(wps):
        a, a_dot, a_ddot = traj.evaluate(wp.t_s)
        _close(a, wp.value, 1e-12)
        if wp.rate is not None and len(wps) > 1:
            _close(a_dot, wp.rate, 1e-9)
        if wp.accel is not None and len(wps) > 1:
            _close(a_ddot, wp.accel, 1e-9)
        if 0 < k < len(wps) - 1:
            for left, right in zip(_left_limit(traj, wp.t_s), (a, a_dot, a_ddot), strict=True):
                _close(left, right)


@settings(max_examples=40, deadline=None)
@given(waypoint_lists(), st.data())
def test_evaluate_many_matches_evaluate(wps: list[Waypoint], data: st.DataObject) -> None:
    traj = DescriptorTrajectory.from_waypoints(wps)
    t = np.array(data.draw(st.lists(st.floats(-20.0, 150.0), min_size=1, max_size=20)))
    many = traj.evaluate_many(t)
    for n, ti in enumerate(t):
        for x, y in zip(traj.evaluate(ti), many, strict=True):
            _close(x, y[n], 1e-12)


@pytest.mark.parametrize(
    ("waypoints", "message"),
    [
        ([], "at least one waypoint"),
        ([Waypoint(1.0, ZERO), Waypoint(1.0, ZERO)], r"waypoints\[1\].t_s = 1.0 is not after"),
        ([Waypoint(2.0, ZERO), Waypoint(1.0, ZERO)], "strictly increasing"),
    ],
)
def test_from_waypoints_rejects(waypoints: list[Waypoint], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        DescriptorTrajectory.from_waypoints(waypoints)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"t_s": math.nan, "value": ZERO}, "t_s must be finite"),
        ({"t_s": 0.0, "value": np.full(9, math.inf)}, "value must be finite"),
        ({"t_s": 0.0, "value": np.zeros(3)}, r"value must have shape \(9,\)"),
        ({"t_s": 0.0, "value": ZERO, "rate": np.array([math.nan] * 9)}, "rate must be finite"),
        ({"t_s": 0.0, "value": ZERO, "accel": np.zeros((9, 1))}, "accel must have shape"),
    ],
)
def test_waypoint_rejects(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Waypoint(**kwargs)  # type: ignore[arg-type]


def test_trajectory_validates_its_arrays_and_is_read_only() -> None:
    with pytest.raises(ValueError, match="strictly increasing"):
        DescriptorTrajectory(0, np.array([0.0, 0.0]), np.zeros((1, 9, 6)))
    with pytest.raises(ValueError, match=r"coeffs must have shape \(2, 9, 6\)"):
        DescriptorTrajectory(0, np.array([0.0, 1.0, 2.0]), np.zeros((1, 9, 6)))
    with pytest.raises(ValueError, match="at least 2 knots"):
        DescriptorTrajectory(0, np.array([0.0]), np.zeros((0, 9, 6)))
    with pytest.raises(ValueError, match="seq"):
        DescriptorTrajectory(-1, np.array([0.0, 1.0]), np.zeros((1, 9, 6)))
    coeffs = np.zeros((1, 9, 6))
    traj = DescriptorTrajectory(0, np.array([0.0, 1.0]), coeffs)
    coeffs[0, 0, 0] = 5.0  # the trajectory holds its own copy
    assert traj.evaluate(0.5)[0][0] == 0.0
    with pytest.raises(ValueError, match="read-only"):
        traj.coeffs[0, 0, 0] = 1.0


def _plan() -> DescriptorTrajectory:
    rng = np.random.default_rng(11)
    return DescriptorTrajectory.from_waypoints(
        [Waypoint(t, rng.normal(size=9)) for t in (0.0, 2.0, 5.0, 9.0)], seq=4
    )


@pytest.mark.parametrize("t_start", [-3.0, 0.0, 1.3, 2.0, 7.5, 9.0, 12.0])
def test_append_waypoints_joins_smoothly(t_start: float) -> None:
    old = _plan()
    target = np.linspace(-1.0, 1.0, 9)
    new = old.append([Waypoint(t_start + 4.0, target)], t_start_s=t_start)
    assert new.seq == old.seq + 1
    # Unchanged before the join, C2 across it, at rest on the target at the end.
    t_before = np.linspace(min(old.start_s, t_start) - 1.0, t_start, 50)
    for x, y in zip(old.evaluate_many(t_before), new.evaluate_many(t_before), strict=True):
        np.testing.assert_allclose(x, y, atol=1e-9)
    for left, right in zip(_left_limit(new, t_start), new.evaluate(t_start), strict=True):
        _close(left, right)
    a, a_dot, a_ddot = new.evaluate(t_start + 4.0)
    np.testing.assert_allclose(a, target, atol=1e-9)
    np.testing.assert_allclose(a_dot, 0.0, atol=1e-9)
    np.testing.assert_allclose(a_ddot, 0.0, atol=1e-9)
    assert new.end_s == t_start + 4.0


@settings(max_examples=40, deadline=None)
@given(waypoint_lists(min_size=2), st.floats(0.0, 1.0), waypoint_lists())
def test_append_is_c2_for_random_plans(
    old_wps: list[Waypoint], frac: float, new_wps: list[Waypoint]
) -> None:
    old = DescriptorTrajectory.from_waypoints(old_wps)
    t_start = old.start_s + frac * (old.end_s - old.start_s)
    shift = t_start + 0.1 - new_wps[0].t_s
    moved = [Waypoint(w.t_s + shift, w.value, w.rate, w.accel) for w in new_wps]
    new = old.append(moved, t_start_s=t_start)
    for left, right in zip(old.evaluate(t_start), new.evaluate(t_start), strict=True):
        _close(left, right)
    if t_start > old.start_s:
        for left, right in zip(_left_limit(new, t_start), new.evaluate(t_start), strict=True):
            _close(left, right)


def test_append_defaults_to_the_end_of_the_plan() -> None:
    old = _plan()
    new = old.append([Waypoint(old.end_s + 2.0, np.ones(9))])
    assert new.n_segments == old.n_segments + 1
    np.testing.assert_array_equal(new.t_knots_s[:-1], old.t_knots_s)


def test_append_after_the_end_bridges_with_a_hold() -> None:
    old = rest_to_rest_segment(0.0, ZERO, 2.0, np.ones(9))
    new = old.append([Waypoint(8.0, np.full(9, 3.0))], t_start_s=5.0)
    np.testing.assert_array_equal(new.t_knots_s, [0.0, 2.0, 5.0, 8.0])
    a, a_dot, _ = new.evaluate(3.5)
    np.testing.assert_allclose(a, 1.0)
    assert not a_dot.any()


def test_append_segment_must_join_the_plan() -> None:
    old = rest_to_rest_segment(0.0, ZERO, 2.0, np.ones(9), seq=2)
    new = old.append(rest_to_rest_segment(3.0, np.ones(9), 5.0, np.full(9, 2.0)))
    assert new.seq == 3
    np.testing.assert_array_equal(new.t_knots_s, [0.0, 2.0, 3.0, 5.0])
    np.testing.assert_allclose(new.evaluate(5.0)[0], 2.0)
    with pytest.raises(ValueError, match=r"does not join the plan at t = 1\.0 s"):
        old.append(rest_to_rest_segment(1.0, np.ones(9), 5.0, ZERO))
    with pytest.raises(ValueError, match="differs"):
        old.append(rest_to_rest_segment(3.0, np.ones(9), 5.0, ZERO), t_start_s=4.0)


def test_append_rejects_waypoints_not_after_the_join() -> None:
    old = _plan()
    with pytest.raises(ValueError, match="after t_start_s"):
        old.append([Waypoint(3.0, ZERO)], t_start_s=3.0)
    with pytest.raises(ValueError, match="at least one waypoint"):
        old.append([], t_start_s=3.0)


def test_a_heading_and_altitude_held_at_two_waypoints_stay_there() -> None:
    """The case that flew 65 deg: yaw 45 deg and 5 m at t = 50 s and again at t = 120 s."""
    up = np.array([0, 0, -5.0, 0, 0, math.radians(45), 9.0, 4.0, 0])
    wps = [
        Waypoint(0.0, np.array([0, 0, 0.0, 0, 0, 0, 9.0, 4.0, 0])),
        Waypoint(50.0, up),
        Waypoint(120.0, up),
        Waypoint(150.0, np.array([0, 0, -5.0, 0, 0, 0, 9.0, 4.0, 0])),
    ]
    plan = DescriptorTrajectory.from_waypoints(wps)
    a, rate, _ = plan.evaluate_many(np.linspace(50.0, 120.0, 701))
    np.testing.assert_allclose(a[:, 5], math.radians(45), atol=1e-12)
    np.testing.assert_allclose(a[:, 2], -5.0, atol=1e-12)
    np.testing.assert_allclose(rate, 0.0, atol=1e-12)
    b, _, _ = plan.evaluate_many(np.linspace(0.0, 50.0, 501))
    assert b[:, 5].max() <= math.radians(45) + 1e-12 and b[:, 2].min() >= -5.0 - 1e-12


_values = st.lists(
    st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False), min_size=2, max_size=7
)


@settings(max_examples=200, deadline=None)
@given(values=_values, gaps=st.lists(st.floats(0.5, 30.0), min_size=6, max_size=6))
def test_bare_waypoints_never_overshoot(values: list[float], gaps: list[float]) -> None:
    """Between two consecutive bare waypoints every descriptor stays between their values (so it
    is monotone where they differ and constant where they are equal)."""
    t = np.concatenate([[0.0], np.cumsum(gaps[: len(values) - 1])])
    rows = [np.full(9, v) for v in values]
    plan = DescriptorTrajectory.from_waypoints(
        [Waypoint(ti, r) for ti, r in zip(t, rows, strict=True)]
    )
    for k in range(len(values) - 1):
        lo, hi = sorted((values[k], values[k + 1]))
        a, rate, _ = plan.evaluate_many(np.linspace(t[k], t[k + 1], 200))
        assert a[:, 0].min() >= lo - 1e-9 * (1 + abs(lo)) and a[:, 0].max() <= hi + 1e-9 * (
            1 + abs(hi)
        )
        if values[k] == values[k + 1]:
            np.testing.assert_allclose(a[:, 0], values[k], atol=1e-12)
        else:  # monotone: the rate never changes sign
            sign = np.sign(values[k + 1] - values[k])
            assert (sign * rate[:, 0]).min() >= -1e-9 * (1 + abs(values[k + 1] - values[k]))


@settings(max_examples=50, deadline=None)
@given(values=_values, rate=st.floats(-3.0, 3.0), accel=st.floats(-1.0, 1.0))
def test_given_rates_and_accelerations_are_still_honoured(
    values: list[float], rate: float, accel: float
) -> None:
    wps = [Waypoint(10.0 * k, np.full(9, v)) for k, v in enumerate(values)]
    k = len(wps) // 2
    wps[k] = Waypoint(wps[k].t_s, wps[k].value, np.full(9, rate), np.full(9, accel))
    plan = DescriptorTrajectory.from_waypoints(wps)
    a, r, acc = plan.evaluate(wps[k].t_s)
    np.testing.assert_allclose(a, values[k], atol=1e-9)
    np.testing.assert_allclose(r, rate, atol=1e-9)
    np.testing.assert_allclose(acc, accel, atol=1e-9)
