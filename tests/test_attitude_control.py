"""Attitude controller and inner loop, alone and closed with the dynamics at 500 Hz."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.model.frames import FloatArray, quat_from_zyx, zyx_from_quat
from sitl_sim.physics import dynamics as dyn
from sitl_sim.physics.attitude_control import (
    AttitudeGains,
    attitude_moments,
    euler_from_quat_batch,
    euler_rates_from_body_rates,
)
from sitl_sim.physics.inner_loop import inner_loop
from sitl_sim.physics.vehicle_params import VehicleParams

P = VehicleParams()
G = AttitudeGains()
DT = 0.002  # 500 Hz
HOVER = P.hover_thrust_n / P.max_thrust_n

angle = st.floats(-1.4, 1.4)
yaw_angle = st.floats(-3.1, 3.1)


def fly(euler_des: FloatArray, seconds: float) -> FloatArray:
    """Fly N vehicles from level hover at 50 m to ``euler_des`` (3, N) at 500 Hz, hover thrust.

    Returns the Euler angles (steps, 3, N) after each step.
    """
    n = euler_des.shape[1]
    s = dyn.initial_state(np.tile([0.0, 0.0, -50.0], (n, 1)))
    thrust = np.full(n, HOVER)
    history = []
    for _ in range(round(seconds / DT)):
        s = dyn.step(s, inner_loop(s, euler_des, thrust, P, G), P, DT)
        history.append(euler_from_quat_batch(s[dyn.QUAT]))
    return np.array(history)


def rise_time_90(trace: FloatArray, target: float) -> float:
    return (int(np.argmax(trace >= 0.9 * target)) + 1) * DT


# --- helpers against protocols.model.frames ---------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(roll=angle, pitch=angle, yaw=yaw_angle)
def test_eta_is_frames_angles_as_rows(roll: float, pitch: float, yaw: float) -> None:
    q = quat_from_zyx(np.array([yaw]), np.array([pitch]), np.array([roll]))
    eta = euler_from_quat_batch(q)
    np.testing.assert_allclose(eta[:, 0], [roll, pitch, yaw], atol=1e-9)
    assert zyx_from_quat(q[:, 0]) == pytest.approx((yaw, pitch, roll), abs=1e-9)


@settings(max_examples=50, deadline=None)
@given(
    roll=angle,
    pitch=angle,
    yaw=yaw_angle,
    rates=st.lists(st.floats(-3, 3), min_size=3, max_size=3),
)
def test_euler_rates_match_finite_difference(
    roll: float, pitch: float, yaw: float, rates: list[float]
) -> None:
    s = dyn.initial_state(np.zeros((1, 3)) - [0, 0, 10])
    s[dyn.QUAT, 0] = quat_from_zyx(yaw, pitch, roll)
    s[dyn.RATES, 0] = rates
    h = 1e-6
    after = dyn.step(s, np.zeros((4, 1)), P, h)
    before = dyn.step(s, np.zeros((4, 1)), P, -h)
    diff = euler_from_quat_batch(after[dyn.QUAT]) - euler_from_quat_batch(before[dyn.QUAT])
    diff[2] = (diff[2] + np.pi) % (2 * np.pi) - np.pi
    eta = np.array([[roll], [pitch], [yaw]])
    expected = euler_rates_from_body_rates(eta, s[dyn.RATES])
    np.testing.assert_allclose(diff / (2 * h), expected, rtol=1e-6, atol=1e-6)


@settings(max_examples=50, deadline=None)
@given(
    roll=st.floats(-1.0, 1.0),
    pitch=st.floats(-1.0, 1.0),
    yaw=yaw_angle,
    rates=st.lists(st.floats(-2, 2), min_size=3, max_size=3),
    des=st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3),
)
def test_feedback_linearisation_gives_commanded_euler_acceleration(
    roll: float, pitch: float, yaw: float, rates: list[float], des: list[float]
) -> None:
    """Closed with the dynamics, eta'' equals tau = kp (eta_d - eta) - kd eta'."""
    s = dyn.initial_state(np.zeros((1, 3)) - [0, 0, 10])
    s[dyn.QUAT, 0] = quat_from_zyx(yaw, pitch, roll)
    s[dyn.RATES, 0] = rates
    euler_des = np.array([[roll + des[0]], [pitch + des[1]], [yaw + des[2]]])
    moments = attitude_moments(s, euler_des, P, G)
    omega_dot = dyn.derivative(s, np.zeros(1), moments, P)[dyn.RATES]
    eta = np.array([[roll], [pitch], [yaw]])
    # eta'' = d/dt (W omega), by central differences along the trajectory
    h = 1e-6

    def eta_dot_at(t: float) -> FloatArray:
        q = s[dyn.QUAT] + t * dyn.derivative(s, np.zeros(1), moments, P)[dyn.QUAT]
        return euler_rates_from_body_rates(
            euler_from_quat_batch(q / np.linalg.norm(q)), s[dyn.RATES] + t * omega_dot
        )

    eta_ddot = (eta_dot_at(h) - eta_dot_at(-h)) / (2 * h)
    tau = np.array(G.kp)[:, None] * (euler_des - eta) - np.array(G.kd)[:, None] * eta_dot_at(0)
    np.testing.assert_allclose(eta_ddot, tau, rtol=1e-5, atol=1e-4)


def test_level_attitude_error_gives_inertia_times_kp() -> None:
    s = dyn.initial_state(np.zeros((1, 3)))
    moments = attitude_moments(s, np.array([[0.1], [-0.2], [0.3]]), P, G)
    expected = P.inertia * np.array(G.kp) * [0.1, -0.2, 0.3]
    np.testing.assert_allclose(moments[:, 0], expected, rtol=1e-12)


def test_yaw_error_is_wrapped_the_short_way() -> None:
    s = dyn.initial_state(np.zeros((1, 3)), np.array([math.radians(-179.0)]))
    moments = attitude_moments(s, np.array([[0.0], [0.0], [math.radians(179.0)]]), P, G)
    assert moments[2, 0] == pytest.approx(P.izz * G.kp[2] * math.radians(-2.0), rel=1e-9)


def test_gains_validate() -> None:
    assert G.validate() is G
    with pytest.raises(ValueError, match="kd"):
        AttitudeGains(kd=(1.0, -1.0, 1.0)).validate()


# --- closed loop at 500 Hz ------------------------------------------------------------------


@pytest.mark.parametrize("axis", [0, 1])
def test_twenty_degree_roll_pitch_step(axis: int) -> None:
    target = math.radians(20.0)
    euler_des = np.zeros((3, 1))
    euler_des[axis] = target
    trace = fly(euler_des, 1.0)[:, axis, 0]
    assert rise_time_90(trace, target) <= 0.3
    assert trace.max() < 1.05 * target
    assert trace[-1] == pytest.approx(target, abs=1e-3)


def test_thirty_degree_yaw_step() -> None:
    target = math.radians(30.0)
    trace = fly(np.array([[0.0], [0.0], [target]]), 1.5)[:, 2, 0]
    assert rise_time_90(trace, target) <= 0.45
    assert trace.max() < 1.05 * target
    assert trace[-1] == pytest.approx(target, abs=1e-3)


def test_level_hover_holds_altitude() -> None:
    s = dyn.initial_state(np.array([[0.0, 0.0, -2.0]]))
    for _ in range(round(2.0 / DT)):
        s = dyn.step(s, inner_loop(s, np.zeros((3, 1)), np.array([HOVER]), P, G), P, DT)
    assert abs(s[2, 0] + 2.0) < 0.01
    assert np.max(np.abs(s[dyn.POS, 0] - [0.0, 0.0, -2.0])) < 0.01


def test_vectorised_loop_equals_single_vehicle_loops() -> None:
    euler_des = np.array([[0.3, -0.1, 0.0], [0.0, 0.2, -0.25], [1.0, -2.0, 3.0]])
    together = fly(euler_des, 0.3)
    for i in range(3):
        alone = fly(euler_des[:, i : i + 1], 0.3)
        np.testing.assert_allclose(together[:, :, i], alone[:, :, 0], rtol=0, atol=1e-12)


# --- inner loop plumbing ----------------------------------------------------------------------


def test_quaternion_and_euler_setpoints_agree() -> None:
    s = dyn.initial_state(np.zeros((2, 3)) - [0, 0, 5])
    s[dyn.RATES] = [[0.1, -0.2], [0.3, 0.0], [0.0, 0.5]]
    euler_des = np.array([[0.2, -0.3], [0.1, 0.0], [2.0, -1.0]])
    quat_des = quat_from_zyx(euler_des[2], euler_des[1], euler_des[0])
    thrust = np.array([0.4, 0.6])
    np.testing.assert_allclose(
        inner_loop(s, quat_des, thrust, P), inner_loop(s, euler_des, thrust, P), atol=1e-9
    )


def test_disarmed_vehicles_get_zero_rotor_speed() -> None:
    s = dyn.initial_state(np.zeros((3, 3)) - [0, 0, 5])
    speeds = inner_loop(s, np.zeros((3, 3)), np.full(3, HOVER), P, armed=np.array([1, 0, 1], bool))
    np.testing.assert_array_equal(speeds[:, 1], 0.0)
    np.testing.assert_allclose(speeds[:, [0, 2]], P.rotor_speed_max_rad_s / math.sqrt(2))


def test_bad_setpoint_shape_is_rejected() -> None:
    s = dyn.initial_state(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="rows"):
        inner_loop(s, np.zeros((2, 1)), np.array([HOVER]), P)
