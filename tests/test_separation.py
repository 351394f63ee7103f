"""The separation safety layer: closed-loop flights of point masses at 50 Hz (head-on, through a
hovering line, a biased estimate in half the swarm) that never come closer than the minimum;
exactly inactive when everyone is far apart; symmetric; and, property-based, the filtered
acceleration meets every barrier (recomputed here from the formulas) whenever that is possible."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog, minimize

from drone_agent.core.separation.filter import (
    AccelBox,
    SeparationParams,
    filter_accelerations,
    pad_neighbours,
)
from protocols.model.frames import FloatArray
from tests.separation_sim import LIMITS, fly, go_to, realised

pytestmark = pytest.mark.timeout(120)

PARAMS = SeparationParams(accel=AccelBox.from_thrust_limits(LIMITS))
MIN_M = PARAMS.min_separation_m
ALT = -5.0


def test_default_box_lies_inside_what_the_vehicle_can_make() -> None:
    box = AccelBox.from_thrust_limits(LIMITS)
    g, b = box.rows()
    z = np.array([-box.max_up_m_s2, box.max_down_m_s2])
    r = np.array([box.horizontal_up_m_s2, box.horizontal_down_m_s2])
    angles = np.arange(8) * math.pi / 4
    corners = np.array(
        [[rk * math.cos(t), rk * math.sin(t), zk] for zk, rk in zip(z, r, strict=True)
         for t in angles]
    )  # fmt: skip
    assert np.all(corners @ g.T >= b - 1e-9)  # the corners are the frustum's
    np.testing.assert_allclose(realised(corners), corners, atol=1e-9)  # and the vehicle makes them
    assert box.inradius() >= PARAMS.brake_m_s2
    PARAMS.validate()
    with pytest.raises(ValueError, match="brake_m_s2"):
        replace(PARAMS, brake_m_s2=5.0).validate()
    with pytest.raises(ValueError, match="share"):
        replace(PARAMS, share=0.0).validate()


# --- closed loop -------------------------------------------------------------------------------


@pytest.mark.parametrize(("delay_ticks", "lag_s"), [(0, 0.0), (1, 0.0), (1, 0.1)])
def test_two_drones_head_on_at_3_m_s_pass_each_other(delay_ticks: int, lag_s: float) -> None:
    p0 = np.array([[-15.0, 0.0, ALT], [15.0, 0.0, ALT]])
    v0 = np.array([[3.0, 0.0, 0.0], [-3.0, 0.0, 0.0]])
    goals = p0[::-1].copy()
    unsafe = fly(p0, v0, go_to(goals), None, 12.0)
    assert unsafe.min_distance_m < 0.01  # the nominal commands collide
    f = fly(p0, v0, go_to(goals), PARAMS, 20.0, delay_ticks, lag_s)
    assert f.min_distance_m >= MIN_M
    np.testing.assert_allclose(f.positions[-1], goals, atol=0.05)  # both got through
    closest = np.argmin(np.linalg.norm(f.positions[:, 0] - f.positions[:, 1], axis=1))
    north, south = f.positions[closest]
    assert north[1] > 0.1 > -0.1 > south[1]  # each turned to its own right: port to port
    assert f.infeasible_ticks == 0


@pytest.mark.parametrize("aim_east_m", [0.75, 0.0])  # at the gap between two, at a drone
def test_a_drone_flies_through_a_hovering_line(aim_east_m: float) -> None:
    line = np.array([[0.0, e, ALT] for e in (-3.0, -1.5, 0.0, 1.5, 3.0)])  # 1.5 m apart
    p0 = np.vstack((line, [-15.0, aim_east_m, ALT]))
    v0 = np.zeros_like(p0)
    v0[-1] = (3.0, 0.0, 0.0)
    goals = p0.copy()
    goals[-1] = (15.0, aim_east_m, ALT)
    assert fly(p0, v0, go_to(goals), None, 10.0).min_distance_m < MIN_M
    for delay_ticks, lag_s in ((0, 0.0), (1, 0.1)):
        f = fly(p0, v0, go_to(goals), PARAMS, 25.0, delay_ticks, lag_s)
        assert f.min_distance_m >= MIN_M
        np.testing.assert_allclose(f.positions[-1], goals, atol=0.05)  # through, line re-formed


@pytest.mark.parametrize("bias", ["two columns 2 m east", "every other drone 2 m north-east"])
def test_a_biased_estimate_in_half_the_swarm(bias: str) -> None:
    """Half the drones hold a wrong centre: their nominal commands fly them into the others."""
    grid = np.array([[n, e, ALT] for n in (0.0, 2.0, 4.0, 6.0) for e in (0.0, 2.0, 4.0, 6.0)])
    goals = grid.copy()
    if bias.startswith("two"):
        goals[grid[:, 1] < 3.0, 1] += 2.0
    else:
        goals[::2] += (1.5, 1.5, 0.0)
    v0 = np.zeros_like(grid)
    assert fly(grid, v0, go_to(goals), None, 10.0).min_distance_m < MIN_M
    for delay_ticks, lag_s in ((0, 0.0), (1, 0.1)):
        f = fly(grid, v0, go_to(goals), PARAMS, 15.0, delay_ticks, lag_s)
        assert f.min_distance_m >= MIN_M
        assert f.active_ticks.max() > 0


# --- inactive, symmetric -----------------------------------------------------------------------


def _far_apart(rng: np.random.Generator, k: int) -> tuple[FloatArray, ...]:
    grid = np.array([[n, e, ALT] for n in range(k) for e in range(k)], dtype=float) * 2.5
    p = grid + rng.uniform(-0.2, 0.2, grid.shape)
    v = rng.normal(0.0, 0.3, p.shape) + np.array([1.0, 0.5, -0.2])  # moves, slowly deforms
    u = rng.normal(0.0, 0.3, p.shape) + np.array([0.8, -0.3, 0.1])
    return p, v, u


def test_inactive_when_every_pair_is_far_apart_output_is_the_input_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    for _ in range(20):
        p, v, u = _far_apart(rng, 4)
        k = len(p)
        nb_p, nb_v = np.broadcast_to(p, (k, k, 3)), np.broadcast_to(v, (k, k, 3))
        r = filter_accelerations(p, v, u, nb_p, nb_v, ~np.eye(k, dtype=bool), PARAMS)
        assert not r.active.any() and not r.infeasible.any()
        assert r.accel_ned_m_s2.tobytes() == u.tobytes()
        assert (r.n_constraints == 0).all()
        np.testing.assert_allclose(r.closest_m, np.sort(np.linalg.norm(
            p[:, None] - p[None], axis=-1), axis=1)[:, 1])  # fmt: skip


def test_a_paper_like_formation_flight_never_wakes_the_filter() -> None:
    """3 x 3 grid, 2 m apart, moving 20 m at up to 2 m/s and 1 m/s² (the envelope's limits)
    with the shape stretching by 15 %, then shrinking by 25 %: never active."""
    grid = np.array([[n, e, ALT] for n in (0.0, 2.0, 4.0) for e in (0.0, 2.0, 4.0)])
    centre = grid.mean(axis=0)
    for scale in (1.15, 0.75):
        goals = (grid - centre) * scale + centre + (20.0, 0.0, -2.0)
        f = fly(grid, np.zeros_like(grid), go_to(goals, v_max=2.0, a_max=1.0), PARAMS, 25.0)
        assert f.active_ticks.sum() == 0
        np.testing.assert_allclose(f.positions[-1], goals, atol=0.05)


def test_a_formation_accelerating_as_one_is_left_alone_given_the_common_acceleration() -> None:
    """Each agent's half of a pair constraint is conservative: it cannot know the neighbour
    accelerates alike. Measured from an acceleration both know (the plan's), it is not."""
    grid = np.array([[n, e, ALT] for n in (0.0, 1.5, 3.0) for e in (0.0, 1.5, 3.0)])
    k = len(grid)
    u = np.tile([3.9, 0.4, -0.4], (k, 1))
    args = (grid, np.zeros_like(grid), u, np.broadcast_to(grid, (k, k, 3)), np.zeros((k, k, 3)),
            ~np.eye(k, dtype=bool), PARAMS)  # fmt: skip
    assert filter_accelerations(*args).active.any()  # 3.9 m/s² towards the drone 1.5 m ahead
    r = filter_accelerations(*args, common_accel_ned_m_s2=np.array([4.0, 0.0, -0.5]))
    assert not r.active.any() and r.accel_ned_m_s2.tobytes() == u.tobytes()


def test_swapping_the_two_drones_swaps_the_results() -> None:
    p = np.array([[0.0, 0.0, ALT], [1.6, 0.3, ALT - 0.2]])
    v = np.array([[1.5, 0.2, 0.0], [-1.0, 0.1, 0.1]])
    u = np.array([[1.0, -0.5, 0.2], [-2.0, 0.3, 0.0]])
    one = filter_accelerations(p, v, u, p[::-1, None], v[::-1, None], np.ones((2, 1), bool),
                               PARAMS)  # fmt: skip
    two = filter_accelerations(p[::-1], v[::-1], u[::-1], p[:, None], v[:, None],
                               np.ones((2, 1), bool), PARAMS)  # fmt: skip
    assert one.active.all()
    np.testing.assert_array_equal(one.accel_ned_m_s2, two.accel_ned_m_s2[::-1])
    np.testing.assert_array_equal(one.closest_m, two.closest_m[::-1])


def test_mirror_image_pair_gets_mirror_image_corrections() -> None:
    """Reciprocal: in a configuration symmetric about the midpoint, the two corrections are
    opposite (each takes half), and the sideways tie-break turns both to their own right."""
    p = np.array([[-0.8, 0.0, ALT], [0.8, 0.0, ALT]])
    v = np.array([[2.0, 0.0, 0.0], [-2.0, 0.0, 0.0]])
    u = np.zeros((2, 3))
    r = filter_accelerations(p, v, u, p[::-1, None], v[::-1, None], np.ones((2, 1), bool),
                             PARAMS)  # fmt: skip
    du = r.accel_ned_m_s2 - u
    np.testing.assert_allclose(du[0], -du[1], atol=1e-12)
    assert du[0, 0] < 0 and du[0, 1] > 0  # drone 0 (flying north) brakes and turns east
    assert r.separation.all() and (r.n_constraints == 1).all()


# --- walls -------------------------------------------------------------------------------------


def test_altitude_floor_holds_and_can_be_switched_off() -> None:
    p0 = np.array([[0.0, 0.0, -3.0]])
    v0 = np.array([[0.0, 0.0, 2.0]])  # sinking at 2 m/s
    goal = go_to(np.array([[0.0, 0.0, 1.0]]))  # 1 m below ground
    f = fly(p0, v0, goal, PARAMS, 6.0)
    assert PARAMS.floor_m is not None
    assert -f.positions[:, 0, 2].max() >= PARAMS.floor_m
    assert -f.positions[-1, 0, 2] < PARAMS.floor_m + 0.1  # as low as allowed
    landing = fly(p0, v0, goal, PARAMS.without_floor(), 6.0)
    assert -landing.positions[-1, 0, 2] < 0.0


def test_floor_does_not_push_a_drone_below_it_taking_off() -> None:
    p = np.array([[0.0, 0.0, -0.1]])  # 0.1 m up, below the 0.5 m floor
    for v_z, u_z in ((-0.5, -1.0), (0.0, 0.0), (0.3, 0.5)):
        v, u = np.array([[0.0, 0.0, v_z]]), np.array([[0.0, 0.0, u_z]])
        r = filter_accelerations(p, v, u, np.zeros((1, 1, 3)), np.zeros((1, 1, 3)),
                                 np.zeros((1, 1), bool), PARAMS)  # fmt: skip
        assert not r.active[0] and r.accel_ned_m_s2.tobytes() == u.tobytes()


def test_geofence_stops_a_drone_flying_at_it() -> None:
    params = replace(PARAMS, fence_north_m=(-100.0, 10.0), fence_east_m=(-5.0, 5.0),
                     ceiling_m=20.0)  # fmt: skip
    p0 = np.array([[0.0, 0.0, ALT]])
    for v0, goal in (
        ((3.0, 0.0, 0.0), (40.0, 0.0, ALT)),
        ((0.0, -3.0, 0.0), (0.0, -40.0, ALT)),
        ((0.0, 0.0, -2.0), (0.0, 0.0, -40.0)),
    ):
        f = fly(p0, np.array([v0]), go_to(np.array([goal])), params, 12.0)
        x = f.positions[:, 0]
        assert x[:, 0].max() <= 10.0 and x[:, 1].min() >= -5.0 and -x[:, 2].max() <= 20.0
        assert np.linalg.norm(f.positions[-1, 0] - p0[0]) > 4.0  # went as far as allowed


def test_a_drone_that_does_not_avoid_is_avoided_alone_with_share_1() -> None:
    p = np.array([[-15.0, 0.0, ALT], [0.0, 0.0, ALT]])
    v = np.array([[3.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    flyer = go_to(np.array([[15.0, 0.0, ALT]]))
    pos, vel = p.copy(), v.copy()
    d_min = np.inf
    for _ in range(1000):  # the hovering drone (failed) neither avoids nor moves
        u = flyer(pos[:1], vel[:1])
        r = filter_accelerations(
            pos[:1],
            vel[:1],
            u,
            pos[None, 1:],
            vel[None, 1:],
            np.ones((1, 1), bool),
            PARAMS,
            nb_share=np.ones((1, 1)),
        )
        vel[0] += realised(r.accel_ned_m_s2)[0] * 0.02
        pos[0] += vel[0] * 0.02
        d_min = min(d_min, float(np.linalg.norm(pos[0] - pos[1])))
    assert d_min >= MIN_M and pos[0, 0] > 14.0


# --- the barrier, recomputed, holds whenever it can --------------------------------------------


def _rows(p: FloatArray, v: FloatArray, nb_p: FloatArray, nb_v: FloatArray,
          params: SeparationParams) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """The barrier constraints ``g u >= c`` of one agent, from the module docstring's formulas
    written out independently, one pair at a time (no floor or fence)."""
    g, c = [], []
    big_a = params.brake_m_s2 / params.share
    for q, w_q in zip(nb_p, nb_v, strict=True):
        r, w = p - q, v - w_q
        rho = float(np.linalg.norm(r))
        n = r / rho
        rho_dot = float(n @ w)
        s = rho - params.distance_m
        h = math.copysign(math.sqrt(2 * big_a * abs(s)), s) + rho_dot
        bound = (
            -params.gamma_1_s * h * (1 + (h / params.h_scale_m_s) ** 2)
            - big_a * rho_dot / math.sqrt(2 * big_a * max(abs(s), 0.01))
            - (w @ w - rho_dot**2) / max(rho, params.distance_m / 2)
        )
        g.append(n)
        c.append(min(params.share * bound, params.brake_m_s2))
    return np.array(g), np.array(c)


vec = st.tuples(*[st.floats(-1.0, 1.0)] * 3).map(np.array)


@settings(max_examples=300, deadline=None)
@given(
    n_nb=st.integers(1, 5),
    offsets=st.lists(vec, min_size=5, max_size=5),
    dist=st.lists(st.floats(0.5, 4.0), min_size=5, max_size=5),
    vels=st.lists(vec, min_size=6, max_size=6),
    speed=st.floats(0.0, 4.0),
    u0=vec,
    u_scale=st.floats(0.0, 6.0),
)
def test_filtered_accel_meets_every_barrier_whenever_it_can(
    n_nb: int,
    offsets: list[FloatArray],
    dist: list[float],
    vels: list[FloatArray],
    speed: float,
    u0: FloatArray,
    u_scale: float,
) -> None:
    params = replace(PARAMS, right_bias=0.0, floor_m=None)
    p = np.array([0.0, 0.0, ALT])
    nb_p = np.array([p + d * o / max(float(np.linalg.norm(o)), 1e-3)
                     for o, d in zip(offsets[:n_nb], dist, strict=False)])  # fmt: skip
    if np.linalg.norm(nb_p - p, axis=1).min() < 0.3:
        return
    v = vels[0] * speed
    nb_v = np.array([w * speed for w in vels[1 : 1 + n_nb]])
    u = u0 * u_scale
    r = filter_accelerations(p[None], v[None], u[None], nb_p[None], nb_v[None],
                             np.ones((1, n_nb), bool), params)  # fmt: skip
    out = r.accel_ned_m_s2[0]
    g, c = _rows(p, v, nb_p, nb_v, params)
    box_g, box_b = params.accel.rows()
    if np.all(g @ u >= c):  # nothing to do
        assert not r.active[0] and out.tobytes() == u.tobytes()
        return
    assert r.active[0]
    all_g, all_b = np.vstack((g, box_g)), np.concatenate((c, box_b))
    feasible = linprog(np.zeros(3), A_ub=-all_g, b_ub=-all_b, bounds=[(None, None)] * 3)
    assert np.all(box_g @ out >= box_b - 1e-7)  # always within what the vehicle can make
    if feasible.status != 0:
        assert r.infeasible[0]
        return
    assert not r.infeasible[0]
    assert np.all(g @ out >= c - 1e-7)
    np.testing.assert_allclose(realised(out[None])[0], out, atol=1e-7)
    # minimal: no acceleration meeting the constraints is closer to the command
    best = minimize(lambda x: float((x - u) @ (x - u)), feasible.x, jac=lambda x: 2 * (x - u),
                    constraints=[{"type": "ineq", "fun": lambda x: all_g @ x - all_b,
                                  "jac": lambda x: all_g}], method="SLSQP",
                    options={"ftol": 1e-12, "maxiter": 500})  # fmt: skip
    assert float((out - u) @ (out - u)) <= best.fun + 1e-6


def test_lists_of_neighbours_pad_to_the_batched_layout() -> None:
    pos, vel, mask = pad_neighbours(
        [np.zeros((2, 3)), np.zeros((0, 3)), np.ones((1, 3))],
        [np.zeros((2, 3)), np.zeros((0, 3)), np.ones((1, 3))],
    )
    assert pos.shape == (3, 2, 3) and mask.tolist() == [[True, True], [False, False],
                                                        [True, False]]  # fmt: skip
    r = filter_accelerations(np.full((3, 3), 5.0), np.zeros((3, 3)), np.zeros((3, 3)), pos, vel,
                             mask, PARAMS.without_floor())  # fmt: skip
    assert r.closest_m[1] == np.inf and math.isclose(r.closest_m[2], math.sqrt(48))


def test_the_caller_can_name_who_keeps_the_floor() -> None:
    p = np.array([[0.0, 0.0, -0.52], [0.0, 5.0, -0.52]])  # both just above the floor ...
    v = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])  # ... sinking at 1 m/s
    u = np.zeros((2, 3))
    none = (np.zeros((2, 1, 3)), np.zeros((2, 1, 3)), np.zeros((2, 1), bool), PARAMS)
    r = filter_accelerations(p, v, u, *none, floor_on=np.array([True, False]))
    assert r.active.tolist() == [True, False] and r.floor.tolist() == [True, False]
    assert r.accel_ned_m_s2[0, 2] < -1.0  # braking upwards
    assert not r.separation.any() and not r.fence.any() and r.n_constraints.tolist() == [1, 0]


def test_neighbour_entries_that_are_not_finite_are_left_out() -> None:
    p = np.array([[0.0, 0.0, ALT]])
    nb = np.array([[[0.5, 0.0, ALT], [np.nan, 0.0, ALT]]])
    vel = np.zeros((1, 2, 3))
    r = filter_accelerations(p, np.zeros((1, 3)), np.zeros((1, 3)), nb, vel,
                             np.array([[False, True]]), PARAMS)  # fmt: skip
    assert not r.active[0] and r.closest_m[0] == np.inf
    r = filter_accelerations(p, np.zeros((1, 3)), np.zeros((1, 3)), nb, vel,
                             np.array([[True, True]]), PARAMS)  # fmt: skip
    assert r.active[0] and r.closest_m[0] == 0.5 and r.accel_ned_m_s2[0, 0] < 0  # pushed away
    assert np.isfinite(r.accel_ned_m_s2).all()
