"""Mixer: inverse of paper eq. 3-4 with rotor-speed saturation (sitl_sim.physics.mixer)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sitl_sim.physics.dynamics import wrench_from_rotor_speeds
from sitl_sim.physics.mixer import mix, rotor_forces_from_wrench
from sitl_sim.physics.vehicle_params import VehicleParams
from tests import physics_oracle

P = VehicleParams()
F_MAX = P.rotor_force_max_n

rotor_force = st.floats(0.0, F_MAX)


@settings(max_examples=200, deadline=None)
@given(forces=st.lists(st.lists(rotor_force, min_size=4, max_size=4), min_size=1, max_size=8))
def test_mix_round_trips_feasible_wrench(forces: list[list[float]]) -> None:
    speeds = np.sqrt(np.array(forces).T / P.thrust_coeff)
    thrust, moments = wrench_from_rotor_speeds(speeds, P)
    back_thrust, back_moments = wrench_from_rotor_speeds(mix(thrust, moments, P), P)
    np.testing.assert_allclose(back_thrust, thrust, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back_moments, moments, rtol=0, atol=1e-9)


def test_hover_gives_equal_rotor_speeds() -> None:
    speeds = mix(np.array([P.hover_thrust_n]), np.zeros((3, 1)), P)
    expected = math.sqrt(P.hover_thrust_n / 4 / P.thrust_coeff)
    np.testing.assert_allclose(speeds[:, 0], expected, rtol=1e-12)
    assert expected == pytest.approx(P.rotor_speed_max_rad_s / math.sqrt(2), rel=1e-12)


def test_rotor_forces_from_wrench_inverts_eq3() -> None:
    forces = np.array([[1.0], [0.7], [0.4], [0.2]])
    thrust, moments = wrench_from_rotor_speeds(np.sqrt(forces / P.thrust_coeff), P)
    np.testing.assert_allclose(rotor_forces_from_wrench(thrust, moments, P), forces, atol=1e-12)


absurd = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-1e6, 1e6),
    st.sampled_from([0.0, math.nan, math.inf, -math.inf]),
)


@settings(max_examples=300, deadline=None)
@given(thrust=absurd, l=absurd, m=absurd, n=absurd)
def test_saturated_speeds_are_finite_and_within_limits(
    thrust: float, l: float, m: float, n: float
) -> None:
    speeds = mix(np.array([thrust]), np.array([[l], [m], [n]]), P)
    assert speeds.shape == (4, 1)
    assert np.all(np.isfinite(speeds))
    assert np.all(speeds >= P.rotor_speed_min_rad_s)
    assert np.all(speeds <= P.rotor_speed_max_rad_s * (1 + 1e-12))


def test_minimum_rotor_speed_is_respected() -> None:
    params = VehicleParams(rotor_speed_min_rad_s=200.0)
    speeds = mix(np.array([0.0, 100.0]), np.zeros((3, 2)), params)
    np.testing.assert_allclose(speeds[:, 0], 200.0)
    np.testing.assert_allclose(speeds[:, 1], 1000.0)


def test_yaw_is_given_up_before_roll_and_pitch() -> None:
    thrust = np.array([P.hover_thrust_n])
    demand = np.array([[0.02], [-0.01], [10.0]])  # feasible roll/pitch, absurd yaw
    got_thrust, got = wrench_from_rotor_speeds(mix(thrust, demand, P), P)
    assert got_thrust[0] == pytest.approx(thrust[0], rel=1e-12)
    np.testing.assert_allclose(got[:2, 0], demand[:2, 0], rtol=1e-12)
    assert 0.0 < got[2, 0] < 10.0
    # the yaw actually delivered is the most the rotors allow with that roll/pitch
    forces = rotor_forces_from_wrench(got_thrust, got, P)
    assert np.isclose(forces, F_MAX).any() or np.isclose(forces, 0.0, atol=1e-12).any()


def test_partial_yaw_keeps_its_sign() -> None:
    for sign in (1.0, -1.0):
        demand = np.array([[0.0], [0.0], [sign * 1.0]])
        _, got = wrench_from_rotor_speeds(mix(np.array([P.hover_thrust_n]), demand, P), P)
        assert np.sign(got[2, 0]) == sign
        # all of the hover thrust can be moved to one rotor pair: n = k * T
        assert abs(got[2, 0]) == pytest.approx(P.yaw_moment_per_thrust_m * P.hover_thrust_n)


def test_vectorised_mix_equals_single_vehicle_mix() -> None:
    rng = np.random.default_rng(7)
    thrust = rng.uniform(-1, 8, 50)
    moments = rng.normal(scale=[[0.05], [0.05], [0.05]], size=(3, 50))
    together = mix(thrust, moments, P)
    for i in range(50):
        np.testing.assert_array_equal(
            together[:, i], mix(thrust[i : i + 1], moments[:, i : i + 1], P)[:, 0]
        )


def test_mix_is_the_numpy_oracle() -> None:
    """The compiled rule (sitl_sim/physics_rules.mix) against the array code it replaced
    (tests/physics_oracle.py): feasible, saturated, NaN and infinite demands."""
    rng = np.random.default_rng(11)
    thrust = rng.uniform(-1, 8, 400)
    moments = rng.normal(scale=[[0.05], [0.05], [0.05]], size=(3, 400))
    thrust[::17], moments[1, ::19], moments[2, ::23] = np.nan, np.nan, np.inf
    thrust[::29] = np.inf
    for params in (P, VehicleParams(rotor_speed_min_rad_s=150.0)):
        got, want = mix(thrust, moments, params), physics_oracle.mix(thrust, moments, params)
        np.testing.assert_allclose(
            params.thrust_coeff * got**2, params.thrust_coeff * want**2, rtol=0, atol=1e-12
        )
