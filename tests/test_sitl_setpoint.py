"""Offboard setpoint validation: sound setpoints are normalised and converted, the rest rejected."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sitl_sim.attitude_control import euler_from_quat_batch, quat_from_euler_batch
from sitl_sim.setpoint import (
    AttitudeSetpoint,
    Rejection,
    euler_from_quat,
    quat_from_euler,
    validate_attitude_target,
)

NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize(
    "q,thrust,mask,reason",
    [
        ((NAN, 0, 0, 0), 0.5, 7, Rejection.NOT_FINITE),
        ((1, 0, INF, 0), 0.5, 7, Rejection.NOT_FINITE),
        ((1, 0, 0, 0), NAN, 7, Rejection.NOT_FINITE),
        ((1, 0, 0, 0), -INF, 7, Rejection.NOT_FINITE),
        ((0, 0, 0, 0), 0.5, 7, Rejection.QUAT_NORM),
        ((2, 0, 0, 0), 0.5, 7, Rejection.QUAT_NORM),
        ((0.9, 0, 0, 0), 0.5, 7, Rejection.QUAT_NORM),
        ((1, 0, 0), 0.5, 7, Rejection.QUAT_NORM),
        ((1, 0, 0, 0), 1.0001, 7, Rejection.THRUST_RANGE),
        ((1, 0, 0, 0), -0.01, 7, Rejection.THRUST_RANGE),
        ((1, 0, 0, 0), 0.5, 7 | 128, Rejection.UNSUPPORTED_MASK),
        ((1, 0, 0, 0), 0.5, 7 | 64, Rejection.UNSUPPORTED_MASK),
    ],
)
def test_unsound_setpoints_are_rejected_with_the_reason(
    q: tuple[float, ...], thrust: float, mask: int, reason: Rejection
) -> None:
    assert validate_attitude_target(list(q), thrust, mask) is reason


@pytest.mark.parametrize("thrust", [0.0, 0.5, 1.0])
def test_thrust_limits_are_inclusive(thrust: float) -> None:
    sp = validate_attitude_target((1.0, 0.0, 0.0, 0.0), thrust, 7)
    assert isinstance(sp, AttitudeSetpoint) and sp.thrust == thrust


def test_slightly_off_quaternion_is_normalised() -> None:
    sp = validate_attitude_target((1.02, 0.0, 0.0, 0.0), 0.5, 0)
    assert isinstance(sp, AttitudeSetpoint)
    assert sp.quat_wxyz == pytest.approx((1.0, 0.0, 0.0, 0.0))
    assert sp.euler_rad == pytest.approx((0.0, 0.0, 0.0))


def test_a_pure_roll_converts_to_euler() -> None:
    roll = math.radians(20)
    q = (math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0)
    sp = validate_attitude_target(q, 0.6, 7)
    assert isinstance(sp, AttitudeSetpoint)
    assert sp.euler_rad == pytest.approx((roll, 0.0, 0.0))


angles = st.tuples(
    st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.floats(-math.pi + 1e-3, math.pi - 1e-3)
)


@given(angles)
def test_scalar_conversions_match_the_vectorised_ones(euler: tuple[float, float, float]) -> None:
    q = quat_from_euler(*euler)
    batch_q = quat_from_euler_batch(np.array(euler)[:, None])[:, 0]
    assert q == pytest.approx(tuple(batch_q), abs=1e-12)
    back = euler_from_quat(q)
    assert back == pytest.approx(tuple(euler_from_quat_batch(batch_q[:, None])[:, 0]), abs=1e-9)
    assert back == pytest.approx(euler, abs=1e-9)
