"""Rigid-body dynamics against closed-form answers and invariants (sitl_sim.physics.dynamics)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.model.frames import G_M_S2, FloatArray, quat_from_zyx, rot_zyx, zyx_from_quat
from sitl_sim.physics import dynamics as dyn
from sitl_sim.physics.vehicle_params import VehicleParams
from tests import physics_oracle as oracle

P = VehicleParams()
DT = 0.002


def speeds_for_forces(forces_n: FloatArray) -> FloatArray:
    """Rotor speeds (4, N) giving per-rotor forces (4, N)."""
    return np.sqrt(np.asarray(forces_n, dtype=np.float64) / P.thrust_coeff)


def hover_speeds(n: int = 1) -> FloatArray:
    return speeds_for_forces(np.full((4, n), P.hover_thrust_n / 4))


def run(state: FloatArray, speeds: FloatArray, seconds: float, method: str = "rk4") -> FloatArray:
    for _ in range(round(seconds / DT)):
        state = dyn.step(state, speeds, P, DT, method)
    return state


def airborne(n: int = 1, z_m: float = -100.0) -> FloatArray:
    return dyn.initial_state(np.tile([0.0, 0.0, z_m], (n, 1)))


# --- parameters ---------------------------------------------------------------------------


def test_default_params_give_thrust_to_weight_two_and_yaw_ratio() -> None:
    assert P.validate() is P
    assert P.max_thrust_n == pytest.approx(2 * 0.34 * G_M_S2, rel=1e-12)
    assert P.max_thrust_n == pytest.approx(6.67, abs=0.01)
    assert P.hover_thrust_n == pytest.approx(P.weight_n)
    assert P.drag_coeff * P.arm_m / P.thrust_coeff == pytest.approx(0.016, rel=1e-12)
    np.testing.assert_array_equal(P.inertia, [3.22e-4, 3.06e-4, 5.78e-4])


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("mass_kg", 0.0),
        ("ixx", -1.0),
        ("izz", math.nan),
        ("arm_m", math.inf),
        ("thrust_coeff", 0.0),
        ("rotor_speed_min_rad_s", -1.0),
        ("rotor_speed_max_rad_s", 0.0),
    ],
)
def test_validate_names_the_bad_field(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        VehicleParams(**{field: value}).validate()


# --- layout and wrench --------------------------------------------------------------------


def test_initial_state_layout() -> None:
    s = dyn.initial_state(np.array([[1.0, 2.0, -3.0], [4.0, 5.0, 0.0]]), np.array([0.0, 1.0]))
    assert s.shape == (13, 2)
    np.testing.assert_array_equal(s[dyn.POS, 0], [1.0, 2.0, -3.0])
    np.testing.assert_array_equal(s[dyn.VEL], 0.0)
    np.testing.assert_array_equal(s[dyn.RATES], 0.0)
    np.testing.assert_allclose(s[dyn.QUAT, 1], quat_from_zyx(1.0, 0.0, 0.0), atol=1e-15)


def test_wrench_follows_paper_eq3() -> None:
    forces = np.array([[1.0], [0.7], [0.4], [0.2]])
    thrust, moments = dyn.wrench_from_rotor_speeds(speeds_for_forces(forces), P)
    k = 0.016
    assert thrust[0] == pytest.approx(2.3, rel=1e-12)
    np.testing.assert_allclose(
        moments[:, 0], [P.arm_m * 0.6, P.arm_m * 0.5, k * (1.0 - 0.7 + 0.4 - 0.2)], rtol=1e-12
    )


# --- free motion --------------------------------------------------------------------------


def test_free_fall_matches_half_g_t_squared() -> None:
    s = run(airborne(), np.zeros((4, 1)), 1.0)
    assert s[2, 0] == pytest.approx(-100.0 + 0.5 * G_M_S2, abs=1e-9)
    assert s[5, 0] == pytest.approx(G_M_S2, abs=1e-9)


def test_hover_thrust_stays_put() -> None:
    s0 = airborne(z_m=-10.0)
    s = run(s0, hover_speeds(), 1.0)
    assert np.max(np.abs(s[dyn.POS] - s0[dyn.POS])) < 1e-6
    np.testing.assert_allclose(s[dyn.QUAT], s0[dyn.QUAT], atol=1e-12)


def test_constant_tilted_thrust_matches_analytic_parabola() -> None:
    yaw, pitch, roll = 0.7, 0.3, -0.2
    s0 = airborne()
    s0[dyn.QUAT, 0] = quat_from_zyx(yaw, pitch, roll)
    s0[dyn.VEL, 0] = [1.0, -2.0, 0.5]
    thrust = 0.8 * P.max_thrust_n
    acc = G_M_S2 * np.array([0, 0, 1.0]) - thrust / P.mass_kg * rot_zyx(yaw, pitch, roll)[:, 2]
    t = 1.0
    s = run(s0, speeds_for_forces(np.full((4, 1), thrust / 4)), t)
    expected = s0[dyn.POS, 0] + s0[dyn.VEL, 0] * t + 0.5 * acc * t**2
    np.testing.assert_allclose(s[dyn.POS, 0], expected, atol=1e-9)
    np.testing.assert_allclose(s[dyn.VEL, 0], s0[dyn.VEL, 0] + acc * t, atol=1e-9)


# --- rotation -----------------------------------------------------------------------------


def test_pure_yaw_moment_gives_r_dot_n_over_izz() -> None:
    n = 1e-3
    d = dyn.derivative(airborne(), np.array([P.weight_n]), np.array([[0.0], [0.0], [n]]), P)
    np.testing.assert_allclose(d[dyn.RATES, 0], [0.0, 0.0, n / P.izz], rtol=1e-12)
    assert d[5, 0] == pytest.approx(0.0, abs=1e-12)


def test_euler_equations_gyroscopic_terms() -> None:
    s = airborne()
    s[dyn.RATES, 0] = [1.0, 2.0, 3.0]
    d = dyn.derivative(s, np.zeros(1), np.zeros((3, 1)), P)
    ixx, iyy, izz = P.ixx, P.iyy, P.izz
    expected = [6 * (iyy - izz) / ixx, 3 * (izz - ixx) / iyy, 2 * (ixx - iyy) / izz]
    np.testing.assert_allclose(d[dyn.RATES, 0], expected, rtol=1e-12)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_torque_free_spin_about_principal_axis_is_conserved(axis: int) -> None:
    rate = 2.0
    s0 = airborne()
    s0[10 + axis, 0] = rate
    s = run(s0, np.zeros((4, 1)), 1.0)
    expected_rates = np.zeros(3)
    expected_rates[axis] = rate
    np.testing.assert_allclose(s[dyn.RATES, 0], expected_rates, atol=1e-12)
    expected_quat = np.zeros(4)
    expected_quat[0] = math.cos(rate / 2)
    expected_quat[1 + axis] = math.sin(rate / 2)
    np.testing.assert_allclose(s[dyn.QUAT, 0], expected_quat, atol=1e-9)


def _angular_momentum_world(s: FloatArray) -> FloatArray:
    yaw, pitch, roll = zyx_from_quat(s[dyn.QUAT, 0])
    return rot_zyx(yaw, pitch, roll) @ (P.inertia * s[dyn.RATES, 0])


def test_torque_free_tumble_conserves_energy_and_angular_momentum() -> None:
    s0 = airborne()
    s0[dyn.RATES, 0] = [3.0, -1.0, 2.0]
    s = run(s0, np.zeros((4, 1)), 1.0)
    energy = [0.5 * P.inertia @ x[dyn.RATES, 0] ** 2 for x in (s0, s)]
    assert energy[1] == pytest.approx(energy[0], rel=1e-9)
    np.testing.assert_allclose(_angular_momentum_world(s), _angular_momentum_world(s0), atol=1e-10)


@settings(max_examples=30, deadline=None)
@given(
    rates=st.lists(st.floats(-20, 20), min_size=3, max_size=3),
    forces=st.lists(st.floats(0.0, P.rotor_force_max_n), min_size=4, max_size=4),
)
def test_quaternion_stays_unit(rates: list[float], forces: list[float]) -> None:
    s = airborne(z_m=-1e4)
    s[dyn.RATES, 0] = rates
    for _ in range(20):
        s = dyn.step(s, speeds_for_forces(np.array(forces)[:, None]), P, DT)
    assert np.linalg.norm(s[dyn.QUAT, 0]) == pytest.approx(1.0, abs=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 6))
def test_vectorised_step_equals_single_vehicle_steps(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    s = dyn.initial_state(rng.uniform(-5, 5, (n, 3)) - [0, 0, 10], rng.uniform(-3, 3, n))
    s[dyn.VEL] = rng.normal(size=(3, n))
    s[dyn.RATES] = rng.normal(size=(3, n))
    speeds = rng.uniform(0, P.rotor_speed_max_rad_s, (4, n))
    together = dyn.step(s, speeds, P, DT)
    for i in range(n):
        alone = dyn.step(s[:, i : i + 1], speeds[:, i : i + 1], P, DT)
        np.testing.assert_allclose(together[:, i : i + 1], alone, rtol=0, atol=1e-14)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 8))
def test_step_is_the_numpy_oracle(seed: int, n: int) -> None:
    """The compiled rules (sitl_sim/physics/rules.py) against the array code they replaced
    (tests/physics_oracle.py), near and on the ground (touchdowns, resting, take-off), and the
    derivative and ground contact alone."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-5, 5, (n, 3))
    pos[:, 2] = -rng.uniform(0.0, 0.05, n)
    pos[::2, 2] = 0.0
    s = dyn.initial_state(pos, rng.uniform(-3, 3, n))
    s[dyn.VEL] = rng.normal(size=(3, n))
    s[dyn.RATES] = rng.normal(size=(3, n))
    s[7:10] += rng.normal(0.0, 0.3, (3, n)) * s[6]
    s[dyn.QUAT] /= np.linalg.norm(s[dyn.QUAT], axis=0)
    speeds = rng.uniform(0, P.rotor_speed_max_rad_s, (4, n))
    speeds[:, ::3] = 0.0
    got, want = dyn.step_with_contact(s, speeds, P, DT), oracle.step_with_contact(s, speeds, P, DT)
    np.testing.assert_allclose(got.state, want.state, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.impact_speed_m_s, want.impact_speed_m_s, rtol=0, atol=1e-12)
    thrust, moments = dyn.wrench_from_rotor_speeds(speeds, P)
    np.testing.assert_allclose(
        dyn.derivative(s, thrust, moments, P),
        oracle.derivative(s, thrust, moments, P),
        rtol=1e-12,
        atol=1e-12,
    )
    moved = s + rng.normal(0.0, 0.05, s.shape)
    for a, b in zip(
        dyn.ground_contact(moved, s, thrust, P),
        oracle.ground_contact(moved, s, thrust, P),
        strict=True,
    ):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_unknown_method_is_rejected() -> None:
    with pytest.raises(ValueError, match="method"):
        dyn.step(airborne(), hover_speeds(), P, DT, method="midpoint")


# --- ground contact -----------------------------------------------------------------------


def test_resting_with_zero_thrust_stays_on_ground() -> None:
    s0 = dyn.initial_state(np.array([[3.0, -2.0, 0.0]]), np.array([0.5]))
    s = run(s0, np.zeros((4, 1)), 1.0)
    np.testing.assert_allclose(s, s0, atol=1e-12)


def test_drop_from_one_metre_lands_stops_and_reports_impact_speed() -> None:
    s = dyn.initial_state(np.array([[0.0, 0.0, -1.0]]))
    impacts = []
    for _ in range(round(1.0 / DT)):
        result = dyn.step_with_contact(s, np.zeros((4, 1)), P, DT)
        s = result.state
        impacts.append(result.impact_speed_m_s[0])
    assert s[2, 0] == 0.0
    np.testing.assert_array_equal(s[dyn.VEL], 0.0)
    hits = np.flatnonzero(impacts)
    assert len(hits) == 1
    assert impacts[hits[0]] == pytest.approx(math.sqrt(2 * G_M_S2 * 1.0), rel=1e-3)


def test_resting_tilted_vehicle_is_levelled_keeping_yaw() -> None:
    s0 = dyn.initial_state(np.zeros((1, 3)))
    s0[dyn.QUAT, 0] = quat_from_zyx(1.2, 0.3, -0.4)
    s = dyn.step(s0, hover_speeds() * 0.5, P, DT)
    yaw, pitch, roll = zyx_from_quat(s[dyn.QUAT, 0])
    assert (yaw, pitch, roll) == pytest.approx((1.2, 0.0, 0.0), abs=1e-12)
    np.testing.assert_array_equal(s[dyn.RATES], 0.0)
    np.testing.assert_array_equal(s[dyn.POS], 0.0)


def test_thrust_above_weight_takes_off_from_ground() -> None:
    s = run(dyn.initial_state(np.zeros((1, 3))), hover_speeds() * 1.2, 0.5)
    assert s[2, 0] < -0.1
    assert s[5, 0] < 0.0


def test_ground_contact_function_reports_per_vehicle() -> None:
    prev = dyn.initial_state(np.array([[0.0, 0.0, -0.01], [0.0, 0.0, -5.0]]))
    prev[5] = [2.0, 2.0]
    new = prev.copy()
    new[2] = [0.01, -4.98]
    new[5] = [2.2, 2.2]
    fixed, impact = dyn.ground_contact(new, prev, np.zeros(2), P)
    assert impact[0] == pytest.approx(2.1)
    assert impact[1] == 0.0
    assert fixed[2, 0] == 0.0
    assert fixed[5, 0] == 0.0
    np.testing.assert_array_equal(fixed[:, 1], new[:, 1])
    assert new[2, 0] == 0.01  # input untouched
