"""Offboard setpoint validation: sound setpoints are normalised and converted, the rest rejected."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocols.model.frames import wxyz_from_zyx, zyx_from_wxyz
from sitl_sim.vehicle.setpoint import (
    QUAT_NORM_TOLERANCE,
    REJECTIONS,
    AttitudeSetpoint,
    Rejection,
    validate_attitude_target,
)
from sitl_sim.vehicle.setpoint_jit import validate_attitude_targets

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
    st.floats(-math.pi + 1e-3, math.pi - 1e-3), st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)
)


@given(angles)
def test_a_valid_setpoint_flies_its_quaternions_angles(zyx: tuple[float, float, float]) -> None:
    """The angles the vehicle flies are those the sender meant (protocols.model.frames' conversion),
    in AttitudeSetpoint's (roll, pitch, yaw) layout."""
    sp = validate_attitude_target(wxyz_from_zyx(*zyx), 0.5)
    assert isinstance(sp, AttitudeSetpoint)
    yaw, pitch, roll = zyx_from_wxyz(*sp.quat_wxyz)
    assert sp.euler_rad == (roll, pitch, yaw)
    assert sp.euler_rad == pytest.approx(zyx[::-1], abs=1e-9)


def test_setpoints_checked_at_once_are_checked_one_by_one() -> None:
    """The compiled check of many setpoints (``swarm simulate``'s vehicles) gives each the
    verdict, unit quaternion and angles of :func:`validate_attitude_target`, to the last bit,
    rejections included (not finite, norm off, thrust out of range, the edges of each)."""
    rng = np.random.default_rng(7)
    n = 3000
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q *= rng.uniform(0.9, 1.1, (n, 1))
    q = q.astype(np.float32).astype(np.float64)
    thrust = rng.uniform(-0.2, 1.2, n)
    thrust[:4] = (0.0, 1.0, np.nextafter(1.0, 2.0), -0.0)
    q[4] = (1.0 + QUAT_NORM_TOLERANCE, 0.0, 0.0, 0.0)
    q[5] = (np.nextafter(1.0 + QUAT_NORM_TOLERANCE, 2.0), 0.0, 0.0, 0.0)
    q[6] = (np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0)  # pitch at the clamp
    q[7::101, 1] = np.nan
    q[8::103, 3] = -np.inf
    thrust[9::107] = np.inf
    codes, unit, euler = validate_attitude_targets(q, thrust)
    verdicts = set()
    for k in range(n):
        sp = validate_attitude_target(q[k].tolist(), float(thrust[k]))
        verdicts.add(sp if isinstance(sp, Rejection) else None)
        if isinstance(sp, AttitudeSetpoint):
            assert codes[k] == 0
            assert tuple(unit[k].tolist()) == sp.quat_wxyz
            assert tuple(euler[k].tolist()) == sp.euler_rad
        else:
            assert REJECTIONS[int(codes[k])] is sp
    assert verdicts == {None, Rejection.NOT_FINITE, Rejection.QUAT_NORM, Rejection.THRUST_RANGE}
